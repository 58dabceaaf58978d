"""Hydra entry point ``spidermatch-match`` (the only spidermatch module besides config that uses Hydra).

Outputs in the Hydra run directory: ``matches.csv``, ``result.json`` and
``correspondence.png``. ``result.json`` is written even when a stage fails, with the
reason. Exit codes: 0 certified (or time-limited with incumbent), 2 bad input,
3 infeasible, 4 no solution in time, 5 solver failure.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spidermatch.costs import RobustLoss
from spidermatch.datasets import DatasetError, SyntheticShapes
from spidermatch.evaluate import sparse_map_errors
from spidermatch.io import load_mesh, read_vts
from spidermatch.mesh import Mesh, MeshError
from spidermatch.pipeline import MatchError, MatchResult, MatchSettings, match
from spidermatch.solve.highs import SolverOptions

logger = logging.getLogger("spidermatch.match")

EXIT_BAD_INPUT = 2


@dataclass(frozen=True)
class MatchInputs:
    """Two full-resolution meshes, their names and optional ground truth (K,) each."""

    source: Mesh
    target: Mesh
    source_corr: np.ndarray | None
    target_corr: np.ndarray | None
    resolution: int
    description: str


def load_inputs(cfg) -> MatchInputs:
    """Meshes named by ``source=``/``target=``, or the built-in synthetic pair."""
    if (cfg.source is None) != (cfg.target is None):
        raise DatasetError("give both source=PATH and target=PATH (or neither, for the built-in demo)")
    if cfg.source is not None:
        source, target = load_mesh(cfg.source), load_mesh(cfg.target)
        source_corr = read_vts(cfg.source_corr, source.n_verts) if cfg.source_corr else None
        target_corr = read_vts(cfg.target_corr, target.n_verts) if cfg.target_corr else None
        if (source_corr is None) != (target_corr is None):
            raise DatasetError("give both source_corr= and target_corr= to evaluate against ground truth")
        resolution = cfg.resolution or 1000
        return MatchInputs(
            source, target, source_corr, target_corr, resolution, f"{cfg.source} -> {cfg.target}"
        )
    data = cfg.data
    shapes = SyntheticShapes(n_shapes=1, n_verts=data.n_verts, seed=data.source_seed)
    other = SyntheticShapes(n_shapes=1, n_verts=data.n_verts, seed=data.target_seed)
    x, y = shapes.load(shapes.names[0]), other.load(other.names[0])
    resolution = cfg.resolution or data.resolution
    return MatchInputs(
        x.mesh, y.mesh, x.corr, y.corr, resolution, f"built-in synthetic pair {x.name} -> {y.name}"
    )


def settings_from_config(cfg, resolution: int) -> MatchSettings:
    """Plain-value :class:`MatchSettings` from the composed config."""
    solver = cfg.solver
    return MatchSettings(
        resolution=int(resolution),
        decimation=cfg.curve.decimation,
        curve_augmented=bool(cfg.curve.augmented),
        target_augmented=bool(cfg.costs.target_augmented),
        curve_seed=int(cfg.curve.seed),
        curve_matching=str(cfg.curve.matching),
        loss=RobustLoss(float(cfg.costs.alpha), float(cfg.costs.scale), float(cfg.costs.bowl_exponent)),
        constraints=tuple(cfg.costs.constraints),
        solver=SolverOptions(
            time_limit=float(solver.time_limit),
            mip_rel_gap=float(solver.mip_rel_gap),
            threads=int(solver.threads),
            presolve=str(solver.presolve),
            log=bool(solver.log),
        ),
        strategy=str(solver.strategy),
    )


def make_extractor(cfg):
    """Instantiate ``cfg.features``; a learned extractor without a checkpoint is a clear error."""
    from hydra.utils import instantiate

    if "checkpoint" in cfg.features and cfg.features.checkpoint is None:
        raise ValueError(
            "features=learned needs a trained network: give checkpoint=PATH (see spidermatch-train)"
        )
    from hydra.errors import InstantiationException

    try:
        return instantiate(cfg.features)
    except InstantiationException as error:
        # Hydra wraps the extractor's own error; a bad checkpoint is the user's input problem.
        if isinstance(error.__cause__, (ValueError, OSError)):
            raise error.__cause__ from None
        raise


def compute_features(cfg, inputs: MatchInputs) -> tuple[np.ndarray, np.ndarray, str]:
    """Per-vertex features of both full-resolution (centred) meshes, and the extractor's name."""
    extractor = make_extractor(cfg)
    name = getattr(extractor, "name", type(extractor).__name__)
    if name == "wks":
        logger.info(
            "features: WKS (no trained checkpoint given; use features=learned features.checkpoint=PATH)"
        )
    source, target = inputs.source.centred(), inputs.target.centred()
    if hasattr(extractor, "pair_features"):
        feat_x, feat_y = extractor.pair_features(source, target)
    else:
        feat_x, feat_y = extractor(source), extractor(target)
    return np.asarray(feat_x), np.asarray(feat_y), name


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file, so that no half file is ever left."""
    with tempfile.NamedTemporaryFile("w", dir=path.parent, delete=False, suffix=".tmp") as handle:
        handle.write(text)
    os.replace(handle.name, path)


def write_matches(path: Path, pairs: np.ndarray) -> None:
    """``source_vertex,target_vertex`` rows (0-based indices into the original meshes)."""
    lines = ["source_vertex,target_vertex"] + [f"{a},{b}" for a, b in pairs.tolist()]
    write_atomic(path, "\n".join(lines) + "\n")


def result_summary(result: MatchResult, inputs: MatchInputs, feature_name: str) -> dict:
    """The solver figures, problem size and timings of a match, JSON-ready."""
    summary = result.solve.summary()
    summary.update(
        {
            "resolution": inputs.resolution,
            "features": feature_name,
            "source_low_res": {"vertices": result.source.mesh.n_verts, "faces": result.source.mesh.n_faces},
            "target_low_res": {"vertices": result.target.mesh.n_verts, "faces": result.target.mesh.n_faces},
            "curve_length": result.curve.length,
            "curve_self_intersections": int(result.curve.intersections.size),
            "check": {"ok": bool(result.check.ok), "problems": list(result.check.problems)}
            if result.check
            else None,
            "timings_s": {name: round(seconds, 3) for name, seconds in result.timings.items()},
        }
    )
    return summary


def run_match(cfg, output_dir: Path) -> int:
    """Run one match and write its outputs into ``output_dir``; return the exit code."""
    return run_pair(cfg, output_dir, lambda: load_inputs(cfg), lambda inputs: compute_features(cfg, inputs))


def run_pair(cfg, output_dir: Path, get_inputs, get_features) -> int:
    """Load a pair, match it and write its outputs; ``result.json`` is written whatever happens.

    Parameters
    ----------
    cfg : DictConfig
        Needs the groups curve, costs, solver and output.
    output_dir : Path
    get_inputs : callable () -> MatchInputs
    get_features : callable (MatchInputs) -> (features_x (V_X, D), features_y (V_Y, D), name)

    Returns
    -------
    int
        The exit code (0 on success).
    """
    output_dir.mkdir(parents=True, exist_ok=True)
    report: dict = {"status": "started", "output_dir": str(output_dir)}
    started = time.perf_counter()
    try:
        return _run_stages(cfg, output_dir, report, get_inputs, get_features)
    except (MeshError, DatasetError, ValueError, FileNotFoundError) as error:
        logger.error("%s", error)
        report.update(status="input_error", error=str(error), exit_code=EXIT_BAD_INPUT)
        return EXIT_BAD_INPUT
    finally:
        report["total_time_s"] = round(time.perf_counter() - started, 3)
        if cfg.output.result_json:
            write_atomic(output_dir / "result.json", json.dumps(report, indent=2) + "\n")
            logger.info("wrote %s", output_dir / "result.json")


def _run_stages(cfg, output_dir: Path, report: dict, get_inputs, get_features) -> int:
    inputs = get_inputs()
    report.update(input=inputs.description, resolution=inputs.resolution)
    logger.info("matching %s at %d faces", inputs.description, inputs.resolution)
    start = time.perf_counter()
    feat_x, feat_y, feature_name = get_features(inputs)
    feature_time = time.perf_counter() - start
    report["features"] = feature_name
    logger.info("features (%s) done in %.2f s", feature_name, feature_time)
    result = match(inputs.source, inputs.target, feat_x, feat_y, settings_from_config(cfg, inputs.resolution))
    report.update(result_summary(result, inputs, feature_name))
    report["timings_s"] = {"features": round(feature_time, 3), **report["timings_s"]}
    try:
        result.raise_for_status()
    except MatchError as error:
        logger.error("%s", error)
        report.update(error=str(error), exit_code=error.exit_code)
        return error.exit_code
    _write_matching(cfg, output_dir, result, inputs, report)
    report["exit_code"] = 0
    return 0


def _write_matching(cfg, output_dir: Path, result: MatchResult, inputs: MatchInputs, report: dict) -> None:
    pairs = result.full_pairs
    if cfg.output.matches_csv:
        write_matches(output_dir / "matches.csv", pairs)
        logger.info("wrote %s (%d matches)", output_dir / "matches.csv", len(pairs))
    if inputs.source_corr is not None:
        evaluation = sparse_map_errors(
            pairs[:, 0], pairs[:, 1], inputs.source, inputs.source_corr, inputs.target_corr, inputs.target
        )
        report["geodesic_error"] = {"mean": evaluation.mean, "n_points": int(evaluation.errors.size)}
        np.save(output_dir / "geodesic_errors.npy", evaluation.errors)
        logger.info("mean geodesic error against ground truth: %.4f", evaluation.mean)
    if cfg.output.png:
        _write_pngs(output_dir, result, inputs, pairs, report)
    if not result.solve.proven_optimal:
        logger.warning(
            "the solver stopped early: this matching is NOT proven optimal (gap %.2e)", result.solve.gap
        )


def _write_pngs(
    output_dir: Path, result: MatchResult, inputs: MatchInputs, pairs: np.ndarray, report: dict
) -> None:
    """``correspondence.png`` (colour transferred source -> target) and ``spider_curve.png``.

    ``pairs`` (N, 2) are the full-resolution (source, target) matches of ``result``.
    """
    from spidermatch.plot import save_correspondence_png, save_curve_png

    title = f"{inputs.description} | {report['status']}, gap {report.get('gap') or 0:.1e}"
    paths = (
        save_correspondence_png(
            inputs.source.centred(),
            inputs.target.centred(),
            pairs[:, 0],
            pairs[:, 1],
            output_dir / "correspondence.png",
            title,
        ),
        save_curve_png(result.source.mesh, result.curve.vertices, output_dir / "spider_curve.png"),
    )
    for path in paths:
        logger.info("wrote %s", path)


class FeatureMemo:
    """Per-shape feature cache for a dataset run: each shape's features are computed once."""

    def __init__(self, cfg) -> None:
        self.extractor = make_extractor(cfg)
        self.name = getattr(self.extractor, "name", type(self.extractor).__name__)
        self._cache: dict[str, np.ndarray] = {}

    def of(self, key: str, mesh: Mesh) -> np.ndarray:
        """Features (V, D) of ``mesh`` (centred), computed on first use of ``key``."""
        if key not in self._cache:
            self._cache[key] = np.asarray(self.extractor(mesh.centred()))
        return self._cache[key]

    def pair(self, inputs: MatchInputs, names: tuple[str, str]) -> tuple[np.ndarray, np.ndarray, str]:
        """Features of a pair; adaptive extractors (``pair_features``) are never cached."""
        if hasattr(self.extractor, "pair_features"):
            feat_x, feat_y = self.extractor.pair_features(inputs.source.centred(), inputs.target.centred())
            return np.asarray(feat_x), np.asarray(feat_y), self.name
        return self.of(names[0], inputs.source), self.of(names[1], inputs.target), self.name


def run_eval(cfg, run_dir: Path) -> int:
    """Match every selected pair of a dataset into ``run_dir``, resuming finished pairs."""
    from tqdm.auto import tqdm

    from spidermatch.batch import finished_result, pair_dir, select_pairs, summary_row, write_summary
    from spidermatch.datasets import open_dataset

    run_dir.mkdir(parents=True, exist_ok=True)
    try:
        options = dict(cfg.synthetic) if cfg.dataset in (None, "", "synthetic") else {}
        dataset = open_dataset(cfg.dataset, **options)
        pairs = select_pairs(dataset.names, dataset.pairs(cfg.pairs_file), cfg.n_pairs, cfg.pair_seed)
        memo = FeatureMemo(cfg)
    except (DatasetError, MeshError, ValueError) as error:
        logger.error("%s", error)
        return EXIT_BAD_INPUT
    settings = {
        "dataset": str(cfg.dataset),
        "resolution": cfg.resolution,
        "features": memo.name,
        "strategy": cfg.solver.strategy,
        "pairs": len(pairs),
    }
    rows = []
    for source, target in tqdm(pairs, desc="pairs", unit="pair"):
        folder = pair_dir(run_dir, source, target)
        result = finished_result(folder)
        if result is None:
            run_pair(
                cfg,
                folder,
                lambda s=source, t=target: _dataset_inputs(dataset, s, t, cfg.resolution),
                lambda inputs, s=source, t=target: memo.pair(inputs, (s, t)),
            )
            result = finished_result(folder) or {"status": "error", "error": "no result.json written"}
        else:
            logger.info("skipping finished pair %s -> %s (%s)", source, target, result["status"])
        rows.append(summary_row(source, target, result))
        summary = write_summary(run_dir, rows, len(pairs), settings)
    _plot_run(run_dir, memo.name)
    logger.info("summary: %s", json.dumps({k: summary[k] for k in ("statuses", "geodesic_error")}))
    logger.info("wrote %s and %s", run_dir / "summary.csv", run_dir / "summary.json")
    return 0


def _dataset_inputs(dataset, source: str, target: str, resolution: int) -> MatchInputs:
    x, y = dataset.load(source), dataset.load(target)
    return MatchInputs(x.mesh, y.mesh, x.corr, y.corr, int(resolution), f"{source} -> {target}")


def _plot_run(run_dir: Path, label: str) -> None:
    from spidermatch.batch import collect_errors
    from spidermatch.plot import save_error_curves

    errors = collect_errors(run_dir)
    if errors.size:
        save_error_curves({label: errors}, run_dir / "errors.png")


def _configure_logging(level: str) -> None:
    logging.getLogger("spidermatch").setLevel(level)
    logging.getLogger("features").setLevel(level)


def _hydra_app(run, config_name: str):
    import hydra
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    @hydra.main(config_path="pkg://conf", config_name=config_name, version_base="1.3")
    def app(cfg) -> None:
        _configure_logging(cfg.log_level)
        hydra_cfg = HydraConfig.get()
        code = run(cfg, Path(hydra_cfg.runtime.output_dir))
        if code and hydra_cfg.mode != RunMode.MULTIRUN:
            sys.exit(code)

    return app


def match_main() -> None:
    """Console entry point of ``spidermatch-match``."""
    _hydra_app(run_match, "match")()


def eval_main() -> None:
    """Console entry point of ``spidermatch-eval``."""
    _hydra_app(run_eval, "eval")()


if __name__ == "__main__":
    match_main()
