"""The files of one match run.

``matches.csv``, ``result.json`` (written even when a stage fails, with the reason), the dense
map's files and the pictures.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from spidermatch import shutdown
from spidermatch.cli.inputs import MatchInputs
from spidermatch.eval.errors import sparse_map_errors
from spidermatch.eval.quality import remarks
from spidermatch.geometry.partial import overlap_summary
from spidermatch.pipeline import MatchResult
from spidermatch.shutdown import write_atomic

logger = logging.getLogger("spidermatch.match")


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
            "curve_tours": result.tours or None,  # curve.tour=auto: each tour tried, the kept one marked
            "check": {"ok": bool(result.check.ok), "problems": list(result.check.problems)}
            if result.check
            else None,
            "timings_s": {name: round(seconds, 3) for name, seconds in result.timings.items()},
        }
    )
    return summary


def final_line(report: dict, code: int) -> str:
    """One line that ends every run: status, gap, quality verdict, error against ground truth, outputs."""
    parts = [f"result: {report.get('status')}"]
    if report.get("gap") is not None:
        parts.append(f"gap {report['gap']:.1e}")
    quality = report.get("quality")
    if quality:
        said = remarks(quality)
        parts.append(f"quality {quality['verdict']}" + (f" ({said[0]})" if said else ""))
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
    "dense_inverse_matches.csv",
    "dense_map.npz",
    "dense_geodesic_errors.npy",
    "correspondence.png",
    "spider_curve.png",
    "texture.png",
    "error.png",
    "viewer.html",
)
"""Files a match may write into its run folder; an earlier run's copies are removed at the start."""


class ForeignFolder(shutdown.OutputError):
    """The run folder holds files named as a run's outputs that no run wrote: nothing is written there."""


def start_run(output_dir: Path, result_path: Path | None, report: dict) -> None:
    """Create the run folder, remove an earlier run's outputs and write a 'started' ``result.json``.

    Every output a run leaves is then its own: a run that writes fewer files (e.g.
    ``dense.enabled=false``) never leaves another pair's dense map beside its result.
    """
    if result_path is not None:  # else nothing to tell the user's own result.json from a run's
        refuse_foreign_folder(output_dir)
    try:
        output_dir.mkdir(parents=True, exist_ok=True)
        stale = _present_outputs(output_dir)
        for path in stale:
            path.unlink()
    except OSError as error:
        message = f"{output_dir}: the run folder cannot be prepared ({error.strerror})"
        raise shutdown.OutputError(message) from error
    if stale:
        logger.info("removed %d outputs of an earlier run in %s", len(stale), output_dir)
    if result_path is not None:
        write_atomic(result_path, json.dumps(report, indent=2) + "\n")


def refuse_foreign_folder(output_dir: Path) -> None:
    """Raise :class:`ForeignFolder` if ``output_dir`` holds files named as outputs that no run wrote.

    Read only: called before a run writes anything into the folder (its lock, ``.hydra/``).
    """
    present = _present_outputs(output_dir)
    if present and not _earlier_run(output_dir):
        names = ", ".join(path.name for path in present)
        raise ForeignFolder(
            f"{output_dir}: holds {names}, which no earlier spidermatch run wrote (neither its "
            f"{shutdown.LOCK_NAME} nor its result.json is there): choose another run folder "
            "(hydra.run.dir=...) or move them"
        )


def _present_outputs(output_dir: Path) -> list[Path]:
    """The files of ``output_dir`` named as a run's outputs (:data:`RUN_OUTPUTS`)."""
    return [output_dir / name for name in RUN_OUTPUTS if (output_dir / name).exists()]


def _earlier_run(output_dir: Path) -> bool:
    """True if a spidermatch run used the folder.

    Its lock file is there, or its ``result.json`` (an object with its status and folder; runs
    of versions before the lock file left only that).
    """
    if (output_dir / shutdown.LOCK_NAME).exists():
        return True
    try:
        report = json.loads((output_dir / "result.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(report, dict) and "status" in report and "output_dir" in report


def write_interim_result(cfg, output_dir: Path, report: dict) -> None:
    """``result.json`` as soon as the matching is written: status ``writing`` with the solver's figures.

    A process killed in a later stage (e.g. by the kernel's OOM killer) leaves this file.
    """
    if cfg.output.result_json:
        write_atomic(output_dir / "result.json", json.dumps(report, indent=2) + "\n")


def stage_failed(report: dict, stage: str, error: BaseException) -> int:
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


def write_matching(
    cfg, output_dir: Path, result: MatchResult, inputs: MatchInputs, report: dict
) -> tuple[np.ndarray, np.ndarray] | None:
    """``matches.csv`` and, with ground truth, the sparse map's errors; returns (vertices, errors) or None."""
    pairs = result.full_pairs
    if cfg.output.matches_csv:
        written = pairs.copy()
        if inputs.piece_of is not None:  # partial=both or repair=true: name the user's source vertices
            written[:, 0] = inputs.piece_of[0][written[:, 0]]
        if inputs.target_of is not None:  # repair=true: name the user's target vertices
            written[:, 1] = inputs.target_of[0][written[:, 1]]
        for column, weld in enumerate((inputs.source_weld, inputs.target_weld)):
            if weld is not None:  # a file with repeated vertices: name its own
                written[:, column] = weld.file_ids(written[:, column])
        write_matches(output_dir / "matches.csv", written)
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


def write_dense(
    output_dir: Path, result: MatchResult, inputs: MatchInputs, features: tuple, report: dict
) -> np.ndarray | None:
    """``dense_matches.csv``, ``dense_map.npz`` and the dense figures in ``report`` (see dense_report).

    Returns the dense map's geodesic errors (K,) at the reference points, or None without ground truth.
    """
    from spidermatch.dense.densify import certified_agreement
    from spidermatch.dense.maps import in_given_corners
    from spidermatch.report.dense_report import dense_figures, write_dense_outputs

    welds = (inputs.source_weld, inputs.target_weld)
    as_given = in_given_corners(result.dense, inputs.source, inputs.target)
    for path in write_dense_outputs(output_dir, as_given, inputs.piece_of, inputs.target_of, welds):
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
        report.setdefault("overlap", {}).update(overlap_summary(inputs.target, result.dense.covered))
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


def write_pngs(
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
