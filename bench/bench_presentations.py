"""Partial-to-full runs matched in each of the part's best presentations to the network.

The orientation search ranks how a part is shown to the network (orientation and place on
the whole, :meth:`features.orientation.OrientationSearch.ranked_for_part`); its first choice
is sometimes the wrong side or region of the body. This bench matches every run of
``bench_partial.py`` (same parts, pairs and scoring) in each of the ``--presentations`` best
presentations, each with its own ``--time-limit``, and records per presentation its search
score, status, objective, dense error, IoU and distortion. The summary then scores the rules
that choose among them without ground truth: the search's first (what matching does), the lowest
objective, and the lowest objective only where it undercuts the first by more than a margin,
each over all runs and over the first and second half of the runs (a rule chosen on one half
is checked on the other). Measured and not kept (docs/partial.md, "Several presentations"):
the certified objective does not tell the right presentation reliably::

    .venv/bin/python bench/bench_presentations.py --data ../shared/data/FAUST_r \\
        --parts <make_partial.py seed 0> --pairs bench/faust_val_pairs.txt \\
        --checkpoint <faust_r_unsup_partial>/best.pt --time-limit 120 \\
        --out bench/results/partial_presentations_faust_val_1000.json

Writes the rows and the summary as JSON (and CSV); ``--runs FIRST:STOP`` runs a slice,
``bench_partial.py merge`` joins slices.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_partial import (  # noqa: E402
    BAD_ERROR,
    area_iou,
    network_extractor,
    part_against_whole,
    part_manifest,
    partial_to_full_runs,
    true_overlap,
)
from bench_scaling import write_rows  # noqa: E402

import spidermatch  # noqa: E402
from spidermatch.data.datasets import ShapeFolder  # noqa: E402
from spidermatch.eval.errors import pointwise_geodesic_errors  # noqa: E402
from spidermatch.feature_transfer import part_feature_options  # noqa: E402

MARGINS = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3)
"""Margins the summary scores the lowest-objective rule with."""


def presentation_rows(index: int, part_name: str, target_name: str, args, folder, extractor) -> list[dict]:
    """One row per presentation of run ``index``: how it was shown, its matching and its scores."""
    run = part_against_whole(Path(args.parts), folder, part_name, target_name, None, None, None, False)
    started = time.perf_counter()
    options, feat_y = part_feature_options(extractor, run.part, run.target.mesh, args.presentations)
    search_s = round(time.perf_counter() - started, 1)
    sources, truth_images = run.scored_points()
    truth_region = true_overlap(run.target.mesh, run.target.corr, run.kept_rows)
    rows = []
    for rank, (label, feat_x) in enumerate(options):
        started = time.perf_counter()
        result = spidermatch.match(
            run.part,
            run.target.mesh,
            features=(feat_x, feat_y),
            resolution=args.faces,
            time_limit=args.time_limit,
            strict=False,
        )
        row = {
            "run": index,
            "part": part_name,
            "target": target_name,
            "rank": rank,
            "presentation": label,
            "mode": result.details.pair.mode if result.details.pair else "?",
            "status": result.status,
            "objective": result.objective if result.matches is not None else None,
            "solve_s": round(result.timings.get("solve", float("nan")), 1),
            "match_s": round(time.perf_counter() - started, 1),
            "search_s": search_s,
        }
        if result.dense_map is not None:
            errors = pointwise_geodesic_errors(run.target.mesh, result.dense_map[sources], truth_images)
            row["dense_error"] = round(float(errors.mean()), 4)
            row["iou"] = round(area_iou(run.target.mesh, result.target_covered, truth_region), 4)
        if result.quality:
            row["distortion"] = result.quality["distortion"]
        print(json.dumps(row), flush=True)
        rows.append(row)
    return rows


def chosen(presentations: list[dict], margin: float | None) -> dict:
    """The presentation a rule keeps: the first (``margin`` None) or the cheapest beating it by ``margin``."""
    first = presentations[0]
    solved = [row for row in presentations if row.get("objective") is not None]
    if margin is None or not solved:
        return first
    cheapest = min(solved, key=lambda row: row["objective"])
    if first.get("objective") is None or cheapest["objective"] < (1.0 - margin) * first["objective"]:
        return cheapest
    return first


def rule_figures(runs: list[list[dict]], margin: float | None) -> dict:
    """Mean and median dense error, mean IoU and wrong maps of the presentations a rule keeps."""
    kept = [chosen(run, margin) for run in runs]
    if not kept:
        return {"runs": 0}
    errors = [row.get("dense_error", 1.0) for row in kept]  # no map: counted as wrong
    return {
        "runs": len(kept),
        "mean_dense_error": round(statistics.mean(errors), 4),
        "median_dense_error": round(statistics.median(errors), 4),
        "mean_iou": round(statistics.mean(row.get("iou", 0.0) for row in kept), 4),
        f"above_{BAD_ERROR}": sum(error > BAD_ERROR for error in errors),
        "changed_from_first": sum(row["rank"] != 0 for row in kept),
    }


def summary(rows: list[dict]) -> dict:
    """Each rule's figures over all complete runs and over their first and second half."""
    by_run: dict[int, list[dict]] = {}
    for row in rows:
        by_run.setdefault(row["run"], []).append(row)
    runs = [by_run[index] for index in sorted(by_run)]
    half = len(runs) // 2
    rules = {"first": None, **{f"cheapest_margin_{margin:g}": margin for margin in MARGINS}}
    return {
        name: {
            "all": rule_figures(runs, margin),
            "first_half": rule_figures(runs[:half], margin),
            "second_half": rule_figures(runs[half:], margin),
        }
        for name, margin in rules.items()
    }


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", required=True)
    parser.add_argument("--parts", required=True)
    parser.add_argument("--pairs", required=True)
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--presentations", type=int, default=3)
    parser.add_argument("--faces", type=int, default=1000)
    parser.add_argument(
        "--time-limit", type=float, default=120.0, help="each presentation's own solver limit"
    )
    parser.add_argument("--runs", default=None, help="FIRST:STOP, a slice of the runs (or a comma list)")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    folder = ShapeFolder(args.data)
    runs = list(enumerate(partial_to_full_runs(part_manifest(Path(args.parts)), args.pairs, folder)))
    if args.runs and ":" in args.runs:
        first, stop = (int(text) for text in args.runs.split(":"))
        runs = runs[first:stop]
    elif args.runs:
        wanted = {int(text) for text in args.runs.split(",")}
        runs = [run for run in runs if run[0] in wanted]
    extractor = network_extractor(args.checkpoint)
    rows = []
    for index, (part_name, target_name) in runs:
        rows += presentation_rows(index, part_name, target_name, args, folder, extractor)
        write_rows(args.out, rows, {"summary": summary(rows)})
    print(json.dumps(summary(rows), indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
