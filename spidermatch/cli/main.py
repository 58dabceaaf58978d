"""Hydra entry point ``spidermatch-match`` (the only spidermatch module besides config that uses Hydra).

Outputs in the Hydra run directory: ``matches.csv``, ``result.json`` and
``correspondence.png``. ``result.json`` is written even when a stage fails, with the
reason. Exit codes: 0 certified (or time-limited with incumbent), 2 bad input,
3 infeasible, 4 no solution in time, 5 solver failure, 6 an output not written,
130/143 interrupted by SIGINT/SIGTERM (see :mod:`spidermatch.shutdown`).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spidermatch import shutdown
from spidermatch.api import BETTER_FEATURES_HINT
from spidermatch.data.datasets import DatasetError, SyntheticShapes
from spidermatch.dense.densify import DenseSettings
from spidermatch.eval.errors import sparse_map_errors
from spidermatch.feature_transfer import MAX_FEATURE_VERTICES, mesh_features, pair_features
from spidermatch.geometry.io import load_mesh, read_vts
from spidermatch.geometry.mesh import Mesh, MeshError
from spidermatch.geometry.partial import PairKind, announce_pair, overlap_summary, pair_kind
from spidermatch.model.costs import RobustLoss
from spidermatch.model_size import check_meshes_fit
from spidermatch.pipeline import MatchError, MatchResult, MatchSettings, add_dense_map, match
from spidermatch.solve.strategies import strategy_for
from spidermatch.solve.types import SolverOptions
from spidermatch.validate import (
    OptionError,
    check_ground_truth,
    check_options,
    coarseness_warnings,
)

logger = logging.getLogger("spidermatch.match")

EXIT_BAD_INPUT = shutdown.EXIT_BAD_INPUT
INPUT_ERRORS = (MeshError, DatasetError, ValueError, FileNotFoundError)


@dataclass(frozen=True)
class MatchInputs:
    """Two full-resolution meshes, their names and optional ground truth (K,) each."""

    source: Mesh
    target: Mesh
    source_corr: np.ndarray | None
    target_corr: np.ndarray | None
    resolution: int
    description: str
    partial: bool = False


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
        check_ground_truth(source_corr, target_corr, cfg.source_corr, cfg.target_corr)
        return MatchInputs(
            source, target, source_corr, target_corr, int(cfg.resolution), f"{cfg.source} -> {cfg.target}"
        )
    data = cfg.data
    shapes = SyntheticShapes(n_shapes=1, n_verts=data.n_verts, seed=data.source_seed)
    other = SyntheticShapes(n_shapes=1, n_verts=data.n_verts, seed=data.target_seed)
    x, y = shapes.load(shapes.names[0]), other.load(other.names[0])
    return MatchInputs(
        x.mesh, y.mesh, x.corr, y.corr, int(cfg.resolution), f"built-in synthetic pair {x.name} -> {y.name}"
    )


def settings_from_config(cfg, resolution: int, feature_name: str) -> MatchSettings:
    """Plain-value :class:`MatchSettings` from the composed config.

    ``feature_name`` (the extractor's name) decides ``solver.strategy=auto`` (:func:`strategy_for`).
    """
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
        strategy=strategy_for(str(solver.strategy), feature_name),
        isolate_solver=bool(solver.get("isolate", True)),
        dense=dense_settings(cfg),
    )


def dense_settings(cfg) -> DenseSettings | None:
    """:class:`DenseSettings` from the ``dense`` group, or None when ``dense.enabled=false`` (or no group)."""
    group = cfg.get("dense")
    if group is None or not group.enabled:
        return None
    return DenseSettings(**{key: value for key, value in group.items() if key != "enabled"})


def make_extractor(cfg):
    """Instantiate ``cfg.features``; a learned extractor without a checkpoint is a clear error."""
    from hydra.utils import instantiate

    if "checkpoint" in cfg.features and cfg.features.checkpoint is None:
        raise ValueError(
            "features=learned needs a trained network: give checkpoint=PATH (see spidermatch-train)"
        )
    from hydra.errors import InstantiationException

    try:
        extractor = instantiate(cfg.features)
    except InstantiationException as error:
        # Hydra wraps the extractor's own error; a bad checkpoint is the user's input problem.
        if isinstance(error.__cause__, (ValueError, OSError)):
            raise error.__cause__ from None
        raise
    if "torch" in sys.modules:
        use_free_cores(sys.modules["torch"])
    return extractor


def free_cores() -> int:
    """Cores this process may use that other processes keep free, at least 1.

    Busy cores: the larger of the 1-minute load average and the processes running right now
    besides this one (``/proc/loadavg``; two matches started together see each other only there).
    """
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    busy = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
    try:
        running = int(Path("/proc/loadavg").read_text().split()[3].split("/")[0])
        busy = max(busy, running - 1)
    except (OSError, ValueError, IndexError):
        pass
    return max(1, min(cores, round(cores - busy)))


def use_free_cores(torch) -> None:
    """Give PyTorch only the free cores, unless ``OMP_NUM_THREADS`` says how many.

    PyTorch takes every core by default; two matches at once on two cores then run four
    spinning threads. Measured with the TOSCA label-free network and 20 adaptation steps on
    cat0 -> cat1: alone 9.6 s (2 threads) or 11.1 s (1); two at once 32 s each with 2
    threads, 12 s each with 1.
    """
    if os.environ.get("OMP_NUM_THREADS"):
        return
    default = torch.get_num_threads()
    threads = min(free_cores(), default)
    if threads < default:
        logger.info(
            "PyTorch uses %d of %d threads: other processes keep the other cores busy", threads, default
        )
        torch.set_num_threads(threads)


def compute_features(cfg, inputs: MatchInputs) -> tuple[np.ndarray, np.ndarray, str, dict]:
    """Features of both full-resolution (centred) meshes, the extractor's name, and how they were made.

    The last item (for ``result.json``) names the meshes whose features were computed on a
    capped copy (``computed_on_vertices``) and how an orientation search presented each mesh.
    """
    extractor = make_extractor(cfg)
    name = getattr(extractor, "name", type(extractor).__name__)
    if name == "wks":
        logger.info("features: WKS (no trained checkpoint given). %s", BETTER_FEATURES_HINT)
    capped = {}
    feat_x, feat_y = pair_features(
        extractor, inputs.source, inputs.target, feature_cap(cfg), capped, inputs.partial
    )
    return feat_x, feat_y, name, feature_details(extractor, capped)


def feature_details(extractor, capped: dict) -> dict:
    """``computed_on_vertices`` and ``orientation`` of a features stage (empty ones left out).

    Logs the orientations and forgets them, so that the next pair reports its own.
    """
    details = {"computed_on_vertices": dict(capped)} if capped else {}
    orientations = getattr(extractor, "orientations", None)
    if orientations:
        details["orientation"] = {key: value.describe() for key, value in orientations.items()}
        logger.info(
            "orientation search: %s",
            "; ".join(f"{key} {text}" for key, text in details["orientation"].items()),
        )
        orientations.clear()
    return details


def feature_cap(cfg) -> int | None:
    """``features_max_vertices`` of the run (None: no cap)."""
    return cfg.get("features_max_vertices", MAX_FEATURE_VERTICES) or None


write_atomic = shutdown.write_atomic  # atomic, umask-derived mode; OutputError names the path


def write_matches(path: Path, pairs: np.ndarray) -> None:
    """``source_vertex,target_vertex`` rows (0-based indices into the original meshes)."""
    lines = ["source_vertex,target_vertex"] + [f"{a},{b}" for a, b in pairs.tolist()]
    write_atomic(path, "\n".join(lines) + "\n")


def result_summary(result: MatchResult, inputs: MatchInputs, feature_name: str) -> dict:
    """The solver figures, problem size and timings of a match, JSON-ready."""
    summary = result.solve.summary()
    solved_model = {key: summary.pop(key) for key in ("rows", "nonzeros")}
    summary.pop("variables")
    summary.update(
        {
            # the ILP as built (the log's "problem:" line) vs the last model HiGHS solved (for rcfix:
            # the surviving columns only, plus the connectivity cuts added on the way)
            "full_model": dict(result.model_size),
            "solved_model": solved_model,
            "resolution": inputs.resolution,
            "features": feature_name,
            "source_low_res": {"vertices": result.source.mesh.n_verts, "faces": result.source.mesh.n_faces},
            "target_low_res": {"vertices": result.target.mesh.n_verts, "faces": result.target.mesh.n_faces},
            "normalisation": {
                "lengths": "in units of each mesh's sqrt(surface area); outputs in the input coordinates",
                "source_area": inputs.source.area,
                "target_area": inputs.target.area,
            },
            "quality": result.quality,
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


def run_pair(cfg, output_dir: Path, get_inputs, get_features, record: dict | None = None) -> int:
    """Load a pair, match it and write its outputs; ``result.json`` is written whatever happens.

    Options are validated first (:func:`spidermatch.validate.check_options`). A signal,
    bad input or an unwritable output ends the run with a final ``result.json`` (status
    ``interrupted``, ``input_error`` or ``output_error``; see :mod:`spidermatch.shutdown`).

    Parameters
    ----------
    cfg : DictConfig
        Needs the groups curve, costs, solver and output.
    output_dir : Path
    get_inputs : callable () -> MatchInputs
    get_features : callable (MatchInputs) -> (features_x (V_X, D), features_y (V_Y, D), name, details)
    record : dict, optional
        Extra entries for ``result.json`` (e.g. the eval's settings hash).

    Returns
    -------
    int
        The exit code (0 on success).
    """
    report: dict = {"status": "started", "output_dir": str(output_dir), **(record or {})}
    result_path = output_dir / "result.json" if cfg.output.result_json else None
    started = time.perf_counter()
    with shutdown.signals_handled():
        try:
            _start_run(output_dir, result_path, report)
            check_options(cfg)
            code = _run_stages(cfg, output_dir, report, get_inputs, get_features)
        except (shutdown.RunInterrupted, OSError, *INPUT_ERRORS) as error:
            status, code, message, known = shutdown.final_status(error, INPUT_ERRORS)
            (logger.warning if status == "interrupted" else logger.error)("%s", message)
            report.update(known)
            report.update(status=status, proven_optimal=False, error=message, exit_code=code)
        with shutdown.signals_held():
            report["total_time_s"] = round(time.perf_counter() - started, 3)
            if result_path is not None:
                if shutdown.write_result(result_path, report):
                    logger.info("wrote %s", result_path)
                elif code == 0:
                    code = shutdown.EXIT_OUTPUT_ERROR
            logger.log(logging.INFO if code == 0 else logging.ERROR, "%s", final_line(report, code))
    return code


def final_line(report: dict, code: int) -> str:
    """One line that ends every run: status, gap, quality verdict, error against ground truth, outputs."""
    parts = [f"result: {report.get('status')}"]
    if report.get("gap") is not None:
        parts.append(f"gap {report['gap']:.1e}")
    quality = report.get("quality")
    if quality:
        parts.append(
            f"quality {quality['verdict']}" + (f" ({quality['reasons'][0]})" if quality["reasons"] else "")
        )
    if report.get("geodesic_error"):
        error = f"mean geodesic error {report['geodesic_error']['mean']:.4f}"
        dense = (report.get("dense") or {}).get("dense", {}).get("geodesic_error")
        parts.append(error + (f" (dense {dense:.4f})" if dense is not None else ""))
    if report.get("error") and code:
        parts.append(f"error: {report['error']}")
    parts.append(f"exit {code}; outputs in {report.get('output_dir')}")
    return ", ".join(parts)


RUN_OUTPUTS = (
    "matches.csv",
    "geodesic_errors.npy",
    "dense_matches.csv",
    "dense_map.npz",
    "dense_geodesic_errors.npy",
    "correspondence.png",
    "spider_curve.png",
    "error.png",
    "viewer.html",
)
"""Files a match may write into its run folder; an earlier run's copies are removed at the start."""


def _start_run(output_dir: Path, result_path: Path | None, report: dict) -> None:
    """Create the run folder, remove an earlier run's outputs and write a 'started' ``result.json``.

    Every output a run leaves is then its own: a run that writes fewer files (e.g.
    ``dense.enabled=false``) never leaves another pair's dense map beside its result.
    """
    try:
        output_dir.mkdir(parents=True, exist_ok=True)
        stale = [output_dir / name for name in RUN_OUTPUTS if (output_dir / name).exists()]
        for path in stale:
            path.unlink()
    except OSError as error:
        message = f"{output_dir}: the run folder cannot be prepared ({error.strerror})"
        raise shutdown.OutputError(message) from error
    if stale:
        logger.info("removed %d outputs of an earlier run in %s", len(stale), output_dir)
    if result_path is not None:
        write_atomic(result_path, json.dumps(report, indent=2) + "\n")


def check_inputs(cfg, inputs: MatchInputs, report: dict) -> MatchInputs:
    """Pair checks before any work: topology, meshes far below the resolution, memory for their size.

    What was repaired on reading the meshes (re-oriented faces, split polygons) joins the
    report's warnings. Returns ``inputs``, marked ``partial`` when the source is a part of
    the target (``report["pair"]`` says how the pair is matched and why).
    """
    repairs = [*inputs.source.notes, *inputs.target.notes]
    if repairs:
        report.setdefault("warnings", []).extend(repairs)
    kind = checked_pair_kind(cfg, inputs, report)
    report["pair"] = {"mode": kind.mode, "reason": kind.reason, "area_ratio": round(kind.area_ratio, 4)}
    announce_pair(kind)
    if kind.caution:
        report.setdefault("warnings", []).append(kind.caution)
    warnings = coarseness_warnings((inputs.source, inputs.target), inputs.resolution)
    if warnings:
        report.setdefault("warnings", []).extend(warnings)
    check_meshes_fit((inputs.source.n_verts, inputs.target.n_verts), dense_settings(cfg) is not None)
    return dataclasses.replace(inputs, partial=kind.mode == "partial")


PARTIAL_OPTIONS = ("auto", "off")


def checked_pair_kind(cfg, inputs: MatchInputs, report: dict) -> PairKind:
    """How the pair is matched (``partial=auto|off``); a refused pair raises, unless forced.

    ``allow_topology_mismatch=true`` matches a refused pair as two whole shapes, with the
    refusal as a warning.
    """
    option = cfg.get("partial", "auto")
    if option not in PARTIAL_OPTIONS:
        raise OptionError(f"partial={option!r}: choose from {', '.join(PARTIAL_OPTIONS)}")
    try:
        return pair_kind(inputs.source, inputs.target, partial=option == "auto")
    except MeshError as error:
        if not cfg.get("allow_topology_mismatch", False):
            raise
        logger.warning("%s (allow_topology_mismatch=true: matching anyway)", error)
        report.setdefault("warnings", []).append(str(error))
        ratio = inputs.source.area / inputs.target.area
        return PairKind("whole", "allow_topology_mismatch=true: matched as two whole shapes", ratio)


def resolution_text(inputs: MatchInputs) -> str:
    """'500 faces', or what each mesh is matched at when one has fewer faces than the resolution."""
    faces = [min(inputs.resolution, mesh.n_faces) for mesh in (inputs.source, inputs.target)]
    if faces == [inputs.resolution] * 2:
        return f"{inputs.resolution} faces"
    return (
        f"{faces[0]} x {faces[1]} faces (resolution={inputs.resolution}; a coarser mesh is matched as it is)"
    )


def _run_stages(cfg, output_dir: Path, report: dict, get_inputs, get_features) -> int:
    inputs = get_inputs()
    report.update(input=inputs.description, resolution=inputs.resolution)
    inputs = check_inputs(cfg, inputs, report)
    logger.info("matching %s at %s", inputs.description, resolution_text(inputs))
    start = time.perf_counter()
    feat_x, feat_y, feature_name, details = get_features(inputs)
    feature_time = time.perf_counter() - start
    report["features"] = feature_name
    if details:
        report["feature_inputs"] = details
    logger.info("features (%s) done in %.2f s", feature_name, feature_time)
    settings = dataclasses.replace(
        settings_from_config(cfg, inputs.resolution, feature_name), partial=inputs.partial
    )
    logger.info("solving strategy: %s", settings.strategy)
    result = match(inputs.source, inputs.target, feat_x, feat_y, dataclasses.replace(settings, dense=None))
    report.update(result_summary(result, inputs, feature_name))
    report["timings_s"] = {"features": round(feature_time, 3), **report["timings_s"]}
    try:
        result.raise_for_status()
    except MatchError as error:
        logger.error("%s", error)
        if report["status"] not in ("infeasible", "no_solution"):
            # e.g. a solution that fails the checker: never 'optimal' next to a failure
            report.update(solver_status=report["status"], status="solver_failure", proven_optimal=False)
        report.update(error=str(error), exit_code=error.exit_code)
        return error.exit_code
    status = report["status"]
    report.update(status="writing", solver_status=status)  # 'optimal' only once every output is written
    picture_errors = _write_matching(cfg, output_dir, result, inputs, report)
    _write_interim_result(cfg, output_dir, report)
    stage = "dense"
    try:
        if settings.dense is not None:
            add_dense_map(
                result, inputs.source, inputs.target, (feat_x, feat_y), settings.dense, settings.partial
            )
            report["timings_s"]["dense"] = round(result.timings["dense"], 3)
            stage = "dense outputs"
            dense_errors = _write_dense(output_dir, result, inputs, (feat_x, feat_y), report)
            picture_errors = None if dense_errors is None else (inputs.source_corr, dense_errors)
        if cfg.output.png:
            stage = "pictures"
            viewer = bool(cfg.output.get("viewer", True))
            _write_pngs(output_dir, result, inputs, {**report, "status": status}, viewer, picture_errors)
    except (MemoryError, shutdown.OutputError) as error:
        return _stage_failed(report, stage, error)
    except Exception as error:  # a later stage's bug must not throw the certified matching away
        logger.debug("the %s stage failed", stage, exc_info=True)
        return _stage_failed(report, stage, error)
    if not result.solve.proven_optimal:
        logger.warning(
            "the solver stopped early: this matching is NOT proven optimal (gap %.2e)", result.solve.gap
        )
    report.pop("solver_status")
    report.update(status=status, exit_code=0)
    return 0


def _write_interim_result(cfg, output_dir: Path, report: dict) -> None:
    """``result.json`` as soon as the matching is written: status ``writing`` with the solver's figures.

    A process killed in a later stage (e.g. by the kernel's OOM killer) leaves this file.
    """
    if cfg.output.result_json:
        write_atomic(output_dir / "result.json", json.dumps(report, indent=2) + "\n")


def _stage_failed(report: dict, stage: str, error: BaseException) -> int:
    """Record a stage after the solve that failed; the certified matching's files are kept."""
    what = (
        "ran out of memory" if isinstance(error, MemoryError) else f"failed ({type(error).__name__}: {error})"
    )
    message = f"the {stage} stage {what}; matches.csv and the solver's figures are kept"
    logger.error("%s", message)
    report.update(
        status="output_error",
        failed_stage=stage,
        error=message,
        proven_optimal=False,
        exit_code=shutdown.EXIT_OUTPUT_ERROR,
    )
    return shutdown.EXIT_OUTPUT_ERROR


def _write_matching(
    cfg, output_dir: Path, result: MatchResult, inputs: MatchInputs, report: dict
) -> tuple[np.ndarray, np.ndarray] | None:
    """``matches.csv`` and, with ground truth, the sparse map's errors; returns (vertices, errors) or None."""
    pairs = result.full_pairs
    if cfg.output.matches_csv:
        write_matches(output_dir / "matches.csv", pairs)
        logger.info("wrote %s (%d matches)", output_dir / "matches.csv", len(pairs))
    if inputs.source_corr is None:
        return None
    evaluation = sparse_map_errors(
        pairs[:, 0], pairs[:, 1], inputs.source, inputs.source_corr, inputs.target_corr, inputs.target
    )
    report["geodesic_error"] = {"mean": evaluation.mean, "n_points": int(evaluation.errors.size)}
    with shutdown.atomic_path(output_dir / "geodesic_errors.npy") as tmp:
        np.save(tmp, evaluation.errors)
    logger.info("mean geodesic error against ground truth: %.4f", evaluation.mean)
    return pairs[:, 0], evaluation.errors


def _write_dense(
    output_dir: Path, result: MatchResult, inputs: MatchInputs, features: tuple, report: dict
) -> np.ndarray | None:
    """``dense_matches.csv``, ``dense_map.npz`` and the dense figures in ``report`` (see dense_report).

    Returns the dense map's geodesic errors (K,) at the reference points, or None without ground truth.
    """
    from spidermatch.dense.densify import certified_agreement
    from spidermatch.report.dense_report import dense_figures, write_dense_outputs

    for path in write_dense_outputs(output_dir, result.dense):
        logger.info("wrote %s", path)
    certified = certified_agreement(result.dense, inputs.target, result.source, result.target, result.low_map)
    figures, errors = dense_figures(
        result.dense,
        inputs.source,
        inputs.target,
        *features,
        inputs.source_corr,
        inputs.target_corr,
        certified,
    )
    report["dense"] = figures
    if result.dense.covered is not None:
        report["overlap"] = overlap_summary(inputs.target, result.dense.covered)
        logger.info(
            "partial map: covers %.0f %% of the target's area", 100 * report["overlap"]["target_covered_area"]
        )
    if errors is not None:
        with shutdown.atomic_path(output_dir / "dense_geodesic_errors.npy") as tmp:
            np.save(tmp, errors)
        logger.info(
            "dense map: mean geodesic error %.4f over %d reference points", errors.mean(), errors.size
        )
    return errors


def _write_pngs(
    output_dir: Path,
    result: MatchResult,
    inputs: MatchInputs,
    report: dict,
    viewer: bool = True,
    errors: tuple[np.ndarray, np.ndarray] | None = None,
) -> None:
    """``correspondence.png``, ``spider_curve.png``, ``error.png`` (with ground truth), ``viewer.html``.

    The pictures use ``result.dense_map`` (V_src,) when the result has one, else the
    full-resolution (source, target) matches (N, 2). ``errors`` (source vertices (N,), geodesic
    errors (N,)) of that map are computed here when not given. ``report`` gives the title's status.
    """
    from spidermatch.report.figures import MatchPictures, map_errors, status_line, write_match_pictures

    dense_map = result.dense_map
    pictures = MatchPictures(
        inputs.source.centred(),
        inputs.target.centred(),
        result.source.mesh,
        result.curve.vertices,
        result.full_pairs if dense_map is None else dense_map,
        inputs.description,
        status_line(report),
        None if dense_map is None else result.dense.covered,
    )
    if errors is None and inputs.source_corr is not None:
        errors = map_errors(pictures, inputs.source_corr, inputs.target_corr)
    write_match_pictures(output_dir, pictures, errors, viewer)


class FeatureMemo:
    """Per-shape feature cache for a dataset run: each shape's features are computed once."""

    def __init__(self, cfg) -> None:
        self.extractor = make_extractor(cfg)
        self.name = getattr(self.extractor, "name", type(self.extractor).__name__)
        self.max_vertices = feature_cap(cfg)
        self._cache: dict[str, tuple[np.ndarray, dict]] = {}

    def of(self, key: str, mesh: Mesh) -> tuple[np.ndarray, dict]:
        """Features (V, D) of ``mesh`` (centred), computed on first use of ``key``, and their details."""
        if key not in self._cache:
            capped = {}
            features = mesh_features(self.extractor, mesh, self.max_vertices, capped)
            self._cache[key] = (features, feature_details(self.extractor, capped))
        return self._cache[key]

    def pair(self, inputs: MatchInputs, names: tuple[str, str]) -> tuple[np.ndarray, np.ndarray, str, dict]:
        """Features of a pair and how they were made; adaptive extractors and parts are never cached."""
        depends_on_pair = hasattr(self.extractor, "pair_features") or inputs.partial  # a part's: on its whole
        if depends_on_pair:
            capped = {}
            features = pair_features(
                self.extractor, inputs.source, inputs.target, self.max_vertices, capped, inputs.partial
            )
            return *features, self.name, feature_details(self.extractor, capped)
        (feat_x, details_x), (feat_y, details_y) = (
            self.of(names[0], inputs.source),
            self.of(names[1], inputs.target),
        )
        details = {}
        for part in (details_x, details_y):
            for kind, entries in part.items():
                details.setdefault(kind, {}).update(entries)
        return feat_x, feat_y, self.name, details


def _eval_settings_hash(cfg) -> str:
    """Hash of the settings that decide an eval's pair results (see :mod:`spidermatch.cli.resume`)."""
    from omegaconf import OmegaConf

    from spidermatch.cli.resume import deciding_settings, settings_hash

    plain = OmegaConf.to_container(cfg, resolve=True)
    checkpoint = cfg.features.get("checkpoint") if "checkpoint" in cfg.features else None
    return settings_hash(deciding_settings(plain, checkpoint))


def _pair_input_files(dataset, source: str, target: str) -> list:
    """Identities (size, mtime) of a pair's mesh and ground-truth files; [] for generated data."""
    from spidermatch.cli.resume import file_identity

    if not hasattr(dataset, "mesh_path"):
        return []
    return [
        file_identity(path)
        for name in (source, target)
        for path in (dataset.mesh_path(name), dataset.corr_path(name))
    ]


def _open_eval(cfg):
    """Options, dataset, pairs and features of an eval run (bad ones raise an input error)."""
    from spidermatch.cli.batch import select_pairs
    from spidermatch.data.datasets import open_dataset

    check_options(cfg)
    if cfg.resolution is None:
        raise OptionError("bad option: resolution=null: an eval needs a face count")
    options = dict(cfg.synthetic) if cfg.dataset in (None, "", "synthetic") else {}
    dataset = open_dataset(cfg.dataset, **options)
    pairs = select_pairs(dataset.names, dataset.pairs(cfg.pairs_file), cfg.n_pairs, cfg.pair_seed)
    return dataset, pairs, FeatureMemo(cfg), _eval_settings_hash(cfg)


def _eval_pair(cfg, run_dir: Path, dataset, memo: FeatureMemo, key: str, pair: tuple) -> tuple[dict, int]:
    """Reuse or (re)compute one pair of an eval run; return its result record and exit code."""
    from spidermatch.cli.batch import finished_result, pair_dir
    from spidermatch.cli.resume import rerun_reason

    source, target = pair
    folder = pair_dir(run_dir, source, target)
    inputs = _pair_input_files(dataset, source, target)
    reason = rerun_reason(finished_result(folder), key, inputs)
    if reason is None:
        result = finished_result(folder)
        logger.info("skipping finished pair %s -> %s (%s)", source, target, result["status"])
        return result, 0
    logger.info("matching %s -> %s: %s", source, target, reason)
    code = run_pair(
        cfg,
        folder,
        lambda: _dataset_inputs(dataset, source, target, cfg.resolution),
        lambda inputs: memo.pair(inputs, (source, target)),
        record={"settings_hash": key, "input_files": inputs},
    )
    result = finished_result(folder)
    if result is None or result.get("settings_hash") != key:  # result.json could not be written
        result = {"status": "output_error", "error": f"no result.json written in {folder}"}
    return result, code


def _stop_eval(run_dir: Path, summary: dict, where: str, code: int) -> int:
    """Record in ``summary.json`` where a signal stopped the eval; return its exit code."""
    summary["interrupted"] = f"{where} (the pair in progress is not counted and runs again on resume)"
    shutdown.write_result(run_dir / "summary.json", summary)
    logger.warning("eval interrupted %s; run the same command again to resume", where)
    return code


def run_eval(cfg, run_dir: Path) -> int:
    """Match every selected pair of a dataset into ``run_dir``, resuming finished pairs.

    A stored pair result is reused only if it was made with the same settings (a hash in
    its ``result.json``) from unchanged input files; otherwise the pair runs again. A
    signal stops the run after recording the pair in progress as ``interrupted``.
    """
    from spidermatch.cli.batch import summary_row, write_summary

    with shutdown.signals_handled():
        try:
            run_dir.mkdir(parents=True, exist_ok=True)
            dataset, pairs, memo, key = _open_eval(cfg)
        except (shutdown.RunInterrupted, OSError, *INPUT_ERRORS) as error:
            status, code, message, _ = shutdown.final_status(error, INPUT_ERRORS)
            logger.error("%s", message)
            return code
        settings = {
            "dataset": str(cfg.dataset),
            "resolution": cfg.resolution,
            "features": memo.name,
            "strategy": cfg.solver.strategy,
            "pairs": len(pairs),
            "settings_hash": key,
        }
        rows, summary = [], write_summary(run_dir, [], len(pairs), settings)
        try:
            for source, target in _progress(pairs):
                result, code = _eval_pair(cfg, run_dir, dataset, memo, key, (source, target))
                if code in shutdown.SIGNAL_EXIT_CODES.values():
                    return _stop_eval(run_dir, summary, f"{source} -> {target}", code)
                rows.append(summary_row(source, target, result))
                summary = write_summary(run_dir, rows, len(pairs), settings)
                shutdown.raise_if_stopped()  # a signal that came while a pair's files were written
        except shutdown.RunInterrupted as stop:
            return _stop_eval(run_dir, summary, "between pairs", stop.exit_code)
    _plot_run(run_dir, memo.name)
    logger.info("summary: %s", json.dumps({k: summary[k] for k in ("statuses", "geodesic_error")}))
    logger.info("wrote %s and %s", run_dir / "summary.csv", run_dir / "summary.json")
    return 0


def _progress(pairs):
    from tqdm.auto import tqdm

    return tqdm(pairs, desc="pairs", unit="pair")


def _dataset_inputs(dataset, source: str, target: str, resolution: int) -> MatchInputs:
    x, y = dataset.load(source), dataset.load(target)
    if hasattr(dataset, "corr_path"):
        check_ground_truth(x.corr, y.corr, dataset.corr_path(source), dataset.corr_path(target))
    else:
        check_ground_truth(x.corr, y.corr, f"{source} ground truth", f"{target} ground truth")
    return MatchInputs(x.mesh, y.mesh, x.corr, y.corr, int(resolution), f"{source} -> {target}")


def _plot_run(run_dir: Path, label: str) -> None:
    from spidermatch.cli.batch import collect_errors
    from spidermatch.report.plot import save_error_curves

    errors = collect_errors(run_dir)
    if errors.size:
        save_error_curves({label: errors}, run_dir / "errors.png")


def _configure_logging(level: str) -> None:
    logging.getLogger("spidermatch").setLevel(level)
    logging.getLogger("features").setLevel(level)


def _save_run_config(cfg, hydra_cfg, output_dir: Path) -> None:
    """``.hydra/config.yaml``, ``hydra.yaml`` and ``overrides.yaml``, written once the folder is held.

    The configs set ``hydra.output_subdir: null`` so that Hydra does not write them itself
    before the run folder is locked (a second run into the folder would overwrite them).
    """
    from omegaconf import OmegaConf

    folder = output_dir / ".hydra"
    try:
        folder.mkdir(exist_ok=True)
    except OSError as error:
        raise shutdown.OutputError(f"{folder}: cannot be created ({error.strerror or error})") from error
    for name, content in (
        ("config.yaml", cfg),
        ("hydra.yaml", OmegaConf.create({"hydra": hydra_cfg})),
        ("overrides.yaml", OmegaConf.create(list(hydra_cfg.overrides.task))),
    ):
        write_atomic(folder / name, OmegaConf.to_yaml(content))


def _held_run(run, cfg, hydra_cfg, output_dir: Path) -> int:
    """``run(cfg, output_dir)`` with the folder locked and the configuration saved; the exit code."""
    try:
        with shutdown.folder_lock(output_dir):
            _save_run_config(cfg, hydra_cfg, output_dir)
            return run(cfg, output_dir)
    except shutdown.FolderInUse as error:
        logger.error("%s", error)
        return EXIT_BAD_INPUT
    except shutdown.OutputError as error:
        logger.error("%s; nothing was run", error)
        return shutdown.EXIT_OUTPUT_ERROR


def _hydra_app(run, config_name: str):
    import hydra
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    @hydra.main(config_path="pkg://conf", config_name=config_name, version_base="1.3")
    def app(cfg) -> None:
        _configure_logging(cfg.log_level)
        hydra_cfg = HydraConfig.get()
        code = _held_run(run, cfg, hydra_cfg, Path(hydra_cfg.runtime.output_dir))
        if shutdown.native_work_abandoned():
            # a solve left running after a signal: end now (all files are written)
            logging.shutdown()
            sys.stderr.flush()
            os._exit(code)
        if code and hydra_cfg.mode != RunMode.MULTIRUN:
            sys.exit(code)

    return app


def file_run_overrides(overrides: list[str]) -> list[str]:
    """Command-line overrides with ``data=files`` added when ``source=`` is given without ``data=``.

    The data group decides the default resolution and is saved in ``.hydra/``, so a file
    run must select it before Hydra composes the config (the defaults list cannot look at
    ``source``).
    """
    keys = {item.split("=", 1)[0].lstrip("+~") for item in overrides if "=" in item}
    if "source" in keys and "data" not in keys:
        return [*overrides, "data=files"]
    return list(overrides)


def match_main() -> None:
    """Console entry point of ``spidermatch-match``."""
    from spidermatch.cli.options import exit_on_bad_command_line

    sys.argv[1:] = file_run_overrides(sys.argv[1:])
    exit_on_bad_command_line("match", sys.argv[1:])
    _hydra_app(run_match, "match")()


def eval_main() -> None:
    """Console entry point of ``spidermatch-eval``."""
    from spidermatch.cli.options import exit_on_bad_command_line

    exit_on_bad_command_line("eval", sys.argv[1:])
    _hydra_app(run_eval, "eval")()


if __name__ == "__main__":
    match_main()
