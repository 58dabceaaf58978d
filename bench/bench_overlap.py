"""The source overlap of pairs of parts alone: the descriptors' estimate against the void-vertex matching.

For every pair of parts of ``bench_partial.py --mode both`` (a part of one shape against a part
of the other shape of its pair that truly share at least ``--min-overlap`` of each part's area)
the features are computed once, as ``spidermatch.match(..., partial="both")`` computes them, and
the source overlap is found by the descriptors' cycle consistency
(:func:`spidermatch.geometry.overlap.estimated_overlap`) and by the matching with a void vertex
(:func:`spidermatch.overlap_solve.matched_overlap`) for each ``--void-factors`` value, with the
void cheaper outside the estimate by each ``--outside-weights`` value (1: the same). Per run and
method: the area-weighted IoU, precision and recall of the region (before its largest clean piece
is taken) against the true overlap, and for the matching its status, gap and solve time. No
second solve, no dense map: this measures only the step that chooses what is matched::

    .venv/bin/python bench/bench_overlap.py --data ../shared/data/FAUST_r --parts runs/partial_faust_s1 \\
        --pairs bench/faust_val_pairs.txt --checkpoint runs/<faust_r_unsup_partial>/best.pt \\
        --void-factors 1.5 2 3 --runs 0:8 --out outputs/overlap_void_factors.json

Prints one row per run and method, then the summary per method; writes rows and summary as JSON
and CSV.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from bench_partial import (
    add_part_options,
    apply_part_search_options,
    area_iou,
    network_extractor,
    overlap_runs,
    part_manifest,
    part_pair,
    runs_slice,
)
from bench_scaling import format_row, write_rows

from spidermatch.api import descriptor_overlap, pair_features
from spidermatch.data.datasets import ShapeFolder
from spidermatch.overlap_solve import matched_overlap
from spidermatch.pipeline import MatchSettings
from spidermatch.solve.types import SolverOptions

COLUMNS = ("part", "target", "method", "iou", "precision", "recall", "status", "gap", "solve_s", "void_share")


def region_scores(mesh, region: np.ndarray, truth: np.ndarray) -> dict:
    """Area-weighted IoU, precision and recall of ``region`` against ``truth``, each (V,) bool on ``mesh``."""
    areas = mesh.vertex_areas
    both = areas[region & truth].sum()
    return {
        "iou": round(area_iou(mesh, region, truth), 4),
        "precision": round(float(both / max(areas[region].sum(), 1e-30)), 4),
        "recall": round(float(both / max(areas[truth].sum(), 1e-30)), 4),
    }


def overlap_rows(names: tuple[str, str], parts: Path, folder: ShapeFolder, args, extractor) -> list[dict]:
    """One row per method for the pair of parts ``names``."""
    pair = part_pair(parts, folder, names)
    source, target = pair.meshes
    feat_x, feat_y, _ = pair_features(extractor, source, target, overlap=True)
    truth = pair.truths[0]
    estimate = descriptor_overlap(source, target, feat_x, feat_y)
    names_of = {"part": names[0], "target": names[1]}
    rows = [{**names_of, "method": "features", **region_scores(source, estimate, truth)}]
    settings = MatchSettings(resolution=args.faces, solver=SolverOptions(time_limit=args.time_limit))
    for factor in args.void_factors:
        for weight in args.outside_weights:  # 1: the estimate plays no part
            started = time.perf_counter()
            prior = None if weight == 1 else estimate
            found = matched_overlap(source, target, feat_x, feat_y, settings, factor, prior, weight)
            method = f"matched {factor:g}" + ("" if prior is None else f" outside {weight:g}")
            row = {**names_of, "method": method, **found.summary()}
            row["total_s"] = round(time.perf_counter() - started, 1)
            if found.region is not None:
                row.update(region_scores(source, found.region, truth))
            rows.append(row)
    return rows


def summary(rows: list[dict]) -> dict:
    """Per method: runs, mean and median IoU, mean precision and recall, certified share, median solve."""
    out = {}
    for method in dict.fromkeys(row["method"] for row in rows):
        group = [row for row in rows if row["method"] == method]
        scored = [row for row in group if "iou" in row]
        figures = {"runs": len(group)}
        if scored:
            figures.update(
                iou_mean=round(statistics.fmean(r["iou"] for r in scored), 4),
                iou_median=round(statistics.median(r["iou"] for r in scored), 4),
                precision_mean=round(statistics.fmean(r["precision"] for r in scored), 4),
                recall_mean=round(statistics.fmean(r["recall"] for r in scored), 4),
            )
        if "status" in group[0]:
            figures["certified"] = sum(row.get("status") == "optimal" for row in group)
            figures["solve_s_median"] = statistics.median(row.get("solve_s", float("nan")) for row in group)
        out[method] = figures
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_part_options(parser, "a trained network, or 'wks' for WKS descriptors")
    parser.add_argument("--void-factors", nargs="+", type=float, default=[2.0])
    parser.add_argument(
        "--outside-weights",
        nargs="+",
        type=float,
        default=[1.0],
        help="the void's cost outside the descriptors' estimate, as a share of lambda (1: no estimate)",
    )
    parser.add_argument("--min-overlap", type=float, default=0.3)
    parser.add_argument("--faces", type=int, default=1000)
    parser.add_argument("--time-limit", type=float, default=120.0)
    parser.add_argument("--runs", default=None, help="FIRST:STOP, a slice of the pairs of parts")
    parser.add_argument("--out", required=True, type=Path)
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    apply_part_search_options(args)
    folder = ShapeFolder(args.data)
    runs = runs_slice(overlap_runs(part_manifest(args.parts), args, folder), args.runs)
    extractor = "wks" if args.checkpoint == "wks" else network_extractor(args.checkpoint)
    print(" | ".join(COLUMNS), flush=True)
    rows: list[dict] = []
    for names in runs:
        for row in overlap_rows(names, args.parts, folder, args, extractor):
            rows.append(row)
            print(format_row(row, COLUMNS, 4), flush=True)
        write_rows(args.out, rows, {"summary": summary(rows)})
    print(json.dumps(summary(rows), indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
