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
        return MatchInputs(source, target, source_corr, target_corr, resolution, f"{cfg.source} -> {cfg.target}")
    data = cfg.data
    shapes = SyntheticShapes(n_shapes=1, n_verts=data.n_verts, seed=data.source_seed)
    other = SyntheticShapes(n_shapes=1, n_verts=data.n_verts, seed=data.target_seed)
    x, y = shapes.load(shapes.names[0]), other.load(other.names[0])
    resolution = cfg.resolution or data.resolution
    return MatchInputs(x.mesh, y.mesh, x.corr, y.corr, resolution, f"built-in synthetic pair {x.name} -> {y.name}")


def settings_from_config(cfg, resolution: int) -> MatchSettings:
    """Plain-value :class:`MatchSettings` from the composed config."""
    solver = cfg.solver
    return MatchSettings(
        resolution=int(resolution),
        decimation=cfg.curve.decimation,
        curve_augmented=bool(cfg.curve.augmented),
        target_augmented=bool(cfg.costs.target_augmented),
        curve_seed=int(cfg.curve.seed),
        loss=RobustLoss(float(cfg.costs.alpha), float(cfg.costs.scale), float(cfg.costs.bowl_exponent)),
        constraints=tuple(cfg.costs.constraints),
        solver=SolverOptions(
            time_limit=float(solver.time_limit), mip_rel_gap=float(solver.mip_rel_gap),
            threads=int(solver.threads), presolve=str(solver.presolve), log=bool(solver.log),
        ),
        strategy=str(solver.strategy),
    )


def compute_features(cfg, inputs: MatchInputs) -> tuple[np.ndarray, np.ndarray, str]:
    """Per-vertex features of both full-resolution (centred) meshes, and the extractor's name."""
    from hydra.utils import instantiate

    extractor = instantiate(cfg.features)
    name = getattr(extractor, "name", type(extractor).__name__)
    if name == "wks":
        logger.info("features: WKS (no trained checkpoint given; use features=learned features.checkpoint=PATH)")
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
    summary.update({
        "resolution": inputs.resolution, "features": feature_name,
        "source_low_res": {"vertices": result.source.mesh.n_verts, "faces": result.source.mesh.n_faces},
        "target_low_res": {"vertices": result.target.mesh.n_verts, "faces": result.target.mesh.n_faces},
        "curve_length": result.curve.length,
        "curve_self_intersections": int(result.curve.intersections.size),
        "check": {"ok": bool(result.check.ok), "problems": list(result.check.problems)} if result.check else None,
        "timings_s": {name: round(seconds, 3) for name, seconds in result.timings.items()},
    })
    return summary


def run_match(cfg, output_dir: Path) -> int:
    """Run one match and write its outputs into ``output_dir``; return the exit code."""
    output_dir.mkdir(parents=True, exist_ok=True)
    report: dict = {"status": "started", "output_dir": str(output_dir)}
    started = time.perf_counter()
    try:
        return _run_stages(cfg, output_dir, report)
    except (MeshError, DatasetError, ValueError, FileNotFoundError) as error:
        logger.error("%s", error)
        report.update(status="input_error", error=str(error), exit_code=EXIT_BAD_INPUT)
        return EXIT_BAD_INPUT
    finally:
        report["total_time_s"] = round(time.perf_counter() - started, 3)
        if cfg.output.result_json:
            write_atomic(output_dir / "result.json", json.dumps(report, indent=2) + "\n")
            logger.info("wrote %s", output_dir / "result.json")


def _run_stages(cfg, output_dir: Path, report: dict) -> int:
    inputs = load_inputs(cfg)
    report["input"] = inputs.description
    logger.info("matching %s at %d faces", inputs.description, inputs.resolution)
    start = time.perf_counter()
    feat_x, feat_y, feature_name = compute_features(cfg, inputs)
    feature_time = time.perf_counter() - start
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
        logger.info("mean geodesic error against ground truth: %.4f", evaluation.mean)
    if cfg.output.png:
        from spidermatch.plot import save_correspondence_png

        title = f"{inputs.description} | {report['status']}, gap {report.get('gap') or 0:.1e}"
        path = save_correspondence_png(
            inputs.source.centred(), inputs.target.centred(), pairs[:, 0], pairs[:, 1],
            output_dir / "correspondence.png", title,
        )
        logger.info("wrote %s", path)
    if not result.solve.proven_optimal:
        logger.warning("the solver stopped early: this matching is NOT proven optimal (gap %.2e)", result.solve.gap)


def _configure_logging(level: str) -> None:
    logging.getLogger("spidermatch").setLevel(level)
    logging.getLogger("features").setLevel(level)


def _hydra_app():
    import hydra
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    @hydra.main(config_path="pkg://conf", config_name="match", version_base="1.3")
    def app(cfg) -> None:
        _configure_logging(cfg.log_level)
        hydra_cfg = HydraConfig.get()
        code = run_match(cfg, Path(hydra_cfg.runtime.output_dir))
        if code and hydra_cfg.mode != RunMode.MULTIRUN:
            sys.exit(code)

    return app


def match_main() -> None:
    """Console entry point of ``spidermatch-match``."""
    _hydra_app()()


if __name__ == "__main__":
    match_main()
