"""Partial-to-full matching: parts of FAUST_r-style shapes (bench/make_partial.py) against whole ones.

For every listed pair (a, b) and every part of a (plane cut, holes, single view) the part is
matched to b, and every part of b to a, through the Python API as a user calls it. Per run:
the mode the pair was recognised in, the status, the solve and whole-run times, the mean
geodesic error of the dense map over the reference points the part kept (in sqrt(area) of
the target), and the overlap: the IoU, weighted by vertex area, of the target region the map
says it covers with the region that truly corresponds to the part (each target vertex takes
the answer of its nearest reference point).

``--mode whole`` runs today's forced full-shape matching (``partial="off"``: the part
measured in its own unit, features as for a whole shape) on the same pairs, for comparison::

    .venv/bin/python bench/bench_partial.py --data ../shared/data/FAUST_r --parts runs/partial_faust \\
        --pairs bench/faust_val_pairs.txt --checkpoint ../runs/faust_unsup_partial_seed0/best.pt \\
        --time-limit 120 --out bench/results/partial_to_full_faust_val_1000.json

Prints one row per run, then the summary; writes rows and summary as JSON and CSV.
"""

from __future__ import annotations

import argparse
import json
import logging
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from bench_scaling import format_row, write_rows
from scipy.spatial import cKDTree

import spidermatch
from spidermatch.data.datasets import ShapeFolder, read_pairs_file
from spidermatch.eval.errors import pointwise_geodesic_errors
from spidermatch.geometry.io import load_mesh
from spidermatch.geometry.mesh import Mesh

COLUMNS = ("part", "target", "kept_area", "mode", "status", "gap", "solve_s", "total_s", "dense_error", "iou")


def true_overlap(target: Mesh, target_corr: np.ndarray, kept_rows: np.ndarray) -> np.ndarray:
    """Target vertices whose nearest reference point (3-D) is one the part kept, shape (V_Y,) bool."""
    _, nearest = cKDTree(target.verts[target_corr]).query(target.verts)
    return kept_rows[nearest]


def area_iou(target: Mesh, predicted: np.ndarray, truth: np.ndarray) -> float:
    """Intersection over union of two vertex sets, each vertex weighted by its area."""
    areas = target.vertex_areas
    return float(areas[predicted & truth].sum() / areas[predicted | truth].sum())


def run_pair(part_name: str, parts: Path, folder: ShapeFolder, target_name: str, args, extractor) -> dict:
    """Match one part to one whole shape and score it."""
    manifest = {row["part"]: row for row in json.loads((parts / "partial.json").read_text())["parts"]}
    entry = manifest[part_name]
    part = load_mesh(parts / "off" / f"{part_name}.off")
    to_original = np.load(parts / "maps" / f"{part_name}.npy")
    whole, target = folder.load(entry["shape"]), folder.load(target_name)
    position = -np.ones(whole.mesh.n_verts, dtype=np.int64)
    position[to_original] = np.arange(to_original.size)
    kept_rows = position[whole.corr] >= 0
    row = {"part": part_name, "target": target_name, "kept_area": entry["kept_area"]}
    started = time.perf_counter()
    result = spidermatch.match(
        part,
        target.mesh,
        features=extractor,
        resolution=args.faces,
        time_limit=args.time_limit,
        strict=False,
        partial="auto" if args.mode == "partial" else "off",
    )
    row["total_s"] = round(time.perf_counter() - started, 1)
    row.update(
        mode=result.details.pair.mode if result.details.pair else "?",
        status=result.status,
        gap=result.gap,
        solve_s=round(result.timings.get("solve", float("nan")), 1),
    )
    if result.dense_map is None:
        return row
    sources = position[whole.corr[kept_rows]]
    errors = pointwise_geodesic_errors(target.mesh, result.dense_map[sources], target.corr[kept_rows])
    row["dense_error"] = round(float(errors.mean()), 4)
    truth = true_overlap(target.mesh, target.corr, kept_rows)
    covered = result.dense.covered
    if covered is None:  # the whole mode says nothing of coverage: every image vertex, as the map gives it
        covered = np.zeros(target.mesh.n_verts, dtype=bool)
        covered[result.dense_map] = True
    row["iou"] = round(area_iou(target.mesh, covered, truth), 4)
    return row


def _mean(rows: list[dict], key: str) -> float | None:
    return round(statistics.mean(row[key] for row in rows), 4) if rows else None


def summary(rows: list[dict]) -> dict:
    """Certified share, median times, mean dense error and IoU over the runs (and per cut kind)."""

    def figures(group: list[dict]) -> dict:
        scored = [row for row in group if "dense_error" in row]
        return {
            "runs": len(group),
            "optimal": sum(row["status"] == "optimal" for row in group),
            "median_total_s": statistics.median(row["total_s"] for row in group),
            "median_solve_s": statistics.median(row["solve_s"] for row in group),
            "mean_dense_error": _mean(scored, "dense_error"),
            "mean_iou": _mean(scored, "iou"),
        }

    kinds = sorted({row["part"].rsplit("-", 1)[1] for row in rows})
    return {
        "all": figures(rows),
        **{kind: figures([r for r in rows if r["part"].endswith(kind)]) for kind in kinds},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="the FAUST_r-style folder the parts were cut from")
    parser.add_argument("--parts", required=True, type=Path, help="the output folder of make_partial.py")
    parser.add_argument("--pairs", required=True, help="pairs file: 'a b' per line")
    parser.add_argument("--checkpoint", required=True, help="a trained network, or 'wks' for WKS descriptors")
    parser.add_argument("--mode", choices=("partial", "whole"), default="partial")
    parser.add_argument("--faces", type=int, default=1000)
    parser.add_argument("--time-limit", type=float, default=120.0)
    parser.add_argument("--runs", default=None, help="FIRST:STOP, a slice of the runs")
    parser.add_argument("--out", required=True, type=Path)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    from features.learned import LearnedExtractor

    folder = ShapeFolder(args.data)
    manifest = json.loads((args.parts / "partial.json").read_text())["parts"]
    runs = [
        (row["part"], b if row["shape"] == a else a)
        for a, b in read_pairs_file(args.pairs, folder.names)
        for row in manifest
        if row["shape"] in (a, b)
    ]
    runs = list(dict.fromkeys(runs))
    if args.runs:
        first, stop = (int(text) for text in args.runs.split(":"))
        runs = runs[first:stop]
    extractor = "wks" if args.checkpoint == "wks" else LearnedExtractor(args.checkpoint)
    print(" | ".join(COLUMNS), flush=True)
    rows = []
    for part_name, target_name in runs:
        rows.append(run_pair(part_name, args.parts, folder, target_name, args, extractor))
        print(format_row(rows[-1], COLUMNS, 4), flush=True)
        write_rows(args.out, rows, {"summary": summary(rows)})
    print(json.dumps(summary(rows), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
