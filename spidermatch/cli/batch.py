"""Matching over a dataset: pair selection, resumable per-pair results, summaries.

Each pair writes into ``<run>/pairs/<source>__<target>/`` (the match command's
outputs). A pair whose ``result.json`` exists is finished and skipped on a re-run;
``result.json`` is written atomically at the end of a pair, so a run killed half way
re-does only the pair it was working on.
"""

from __future__ import annotations

import csv
import json
import logging
import math
from pathlib import Path

import numpy as np

from spidermatch.data.datasets import DatasetError
from spidermatch.shutdown import atomic_path, write_atomic

logger = logging.getLogger(__name__)

SUMMARY_COLUMNS = (
    "source",
    "target",
    "resolution",
    "features",
    "status",
    "quality",
    "gap",
    "objective",
    "bound",
    "solve_s",
    "total_s",
    "geodesic_error",
    "dense_error",
    "nn_error",
    "dense_tears",
    "nn_tears",
    "dense_flips",
    "nn_flips",
    "dense_s",
    "reason",
)
MATCHED = ("optimal", "feasible")  # statuses of a pair with a matching
# summary.csv column -> (result.json "dense" entry, figure); see spidermatch.report.dense_report.
DENSE_COLUMNS = {
    f"{short}_{figure}": (entry, "geodesic_error" if figure == "error" else figure)
    for short, entry in (("dense", "dense"), ("nn", "nearest_neighbour"))
    for figure in ("error", "tears", "flips")
}


def select_pairs(
    names: list[str], all_pairs: list[tuple[str, str]], n_pairs: int | None = None, seed: int = 0
) -> list[tuple[str, str]]:
    """The first ``n_pairs`` of a fixed seeded order of ``all_pairs`` (all of them by default).

    The order is one seeded permutation of all pairs, so a larger ``n_pairs`` extends a smaller
    one with the same seed: ``n_pairs=3`` matches the pairs of ``n_pairs=2`` plus one more,
    and a resumed run re-uses their results. The chosen pairs are returned in the order of
    ``all_pairs``.
    """
    if n_pairs is None or n_pairs >= len(all_pairs):
        return list(all_pairs)
    if n_pairs < 1:
        raise DatasetError(f"n_pairs must be at least 1, got {n_pairs}")
    order = np.random.default_rng(seed).permutation(len(all_pairs))
    return [all_pairs[i] for i in sorted(order[:n_pairs])]


def pair_dir(run_dir: Path, source: str, target: str) -> Path:
    """Folder of one pair's outputs."""
    return run_dir / "pairs" / f"{source}__{target}"


def finished_result(folder: Path) -> dict | None:
    """The pair's ``result.json`` if the pair has finished (successfully or not), else None."""
    path = folder / "result.json"
    if not path.is_file():
        return None
    try:
        result = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        logger.warning("unreadable %s: the pair will be run again", path)
        return None
    return result if result.get("status") not in (None, "started", "writing") else None


def summary_row(source: str, target: str, result: dict) -> dict:
    """One line of ``summary.csv`` from a pair's ``result.json``."""
    error = result.get("geodesic_error") or {}
    timings = result.get("timings_s") or {}
    return {
        "source": source,
        "target": target,
        "resolution": result.get("resolution"),
        "features": result.get("features"),
        "status": result.get("status"),
        "quality": (result.get("quality") or {}).get("verdict"),
        "gap": result.get("gap"),
        "objective": result.get("objective"),
        "bound": result.get("bound"),
        "solve_s": timings.get("solve"),
        "total_s": result.get("total_time_s"),
        "geodesic_error": error.get("mean"),
        **_dense_columns(result),
        "reason": result.get("error", ""),
    }


def _dense_columns(result: dict) -> dict:
    """The dense map's and the features' nearest-neighbour figures from ``result.json`` (None if absent)."""
    dense = result.get("dense") or {}
    row = {column: (dense.get(entry) or {}).get(figure) for column, (entry, figure) in DENSE_COLUMNS.items()}
    row["dense_s"] = (result.get("timings_s") or {}).get("dense")
    return row


def _stats(values: list[float]) -> dict:
    finite = [v for v in values if v is not None and math.isfinite(v)]
    if not finite:
        return {"mean": None, "median": None, "n": 0}
    return {"mean": float(np.mean(finite)), "median": float(np.median(finite)), "n": len(finite)}


def summarise(rows: list[dict], n_planned: int) -> dict:
    """Means, medians and failures over the finished pairs."""
    statuses: dict[str, int] = {}
    for row in rows:
        statuses[row["status"]] = statuses.get(row["status"], 0) + 1
    succeeded = [r for r in rows if r["status"] in MATCHED]
    verdicts: dict[str, int] = {}
    for verdict in (row.get("quality") for row in succeeded):
        if verdict is not None:
            verdicts[verdict] = verdicts.get(verdict, 0) + 1
    return {
        "pairs_planned": n_planned,
        "pairs_finished": len(rows),
        "statuses": statuses,
        "quality": verdicts,  # the quality verdicts of the matched pairs (spidermatch.quality)
        "geodesic_error": _stats([r["geodesic_error"] for r in succeeded]),
        "solve_s": _stats([r["solve_s"] for r in succeeded]),
        "total_s": _stats([r["total_s"] for r in rows]),
        "gap": _stats([r["gap"] for r in succeeded]),
        **{column: _stats([r.get(column) for r in succeeded]) for column in (*DENSE_COLUMNS, "dense_s")},
        "failures": [
            {"source": r["source"], "target": r["target"], "status": r["status"], "reason": r["reason"]}
            for r in rows
            if r["status"] not in MATCHED
        ],
    }


def write_summary(run_dir: Path, rows: list[dict], n_planned: int, settings: dict) -> dict:
    """Write ``summary.csv`` and ``summary.json`` (atomically) and return the summary."""
    summary = summarise(rows, n_planned)
    summary["settings"] = settings
    write_atomic(run_dir / "summary.json", json.dumps(summary, indent=2) + "\n")
    with atomic_path(run_dir / "summary.csv") as tmp, tmp.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(SUMMARY_COLUMNS))
        writer.writeheader()
        writer.writerows(rows)
    return summary


def collect_errors(run_dir: Path) -> np.ndarray:
    """All per-point geodesic errors of a run's finished pairs, concatenated, shape (N,)."""
    files = sorted((run_dir / "pairs").glob("*/geodesic_errors.npy"))
    if not files:
        return np.zeros(0)
    return np.concatenate([np.load(f) for f in files])
