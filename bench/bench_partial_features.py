"""How well a network's features alone place partial shapes: the nearest-feature map of each part.

The partial mode's accuracy rests on the part's descriptors finding the right region of the
whole target (docs/partial.md). This bench measures that without any solve, in seconds per
run, so that training recipes can be compared on the runs ``bench_partial.py`` makes: each
part of ``make_partial.py``'s output against the shapes it is paired with (and, with
``--own``, against the very shape it was cut from, in the same pose: there only the cut can
mislead the features). Per run: the mean geodesic error (target's sqrt(area)) of the
nearest-feature map over the reference points the part kept, the share of them above 0.1,
and the orientation the part search chose (features as ``LearnedExtractor.part_features``
gives them to the partial mode)::

    .venv/bin/python bench/bench_partial_features.py --data ../shared/data/FAUST_r \\
        --parts runs/partial_faust --pairs bench/faust_val_pairs.txt \\
        --checkpoint ../runs/faust_unsup_partial_seed0/best.pt \\
        --out bench/results/partial_features_faust_val.json

``--turn-parts SEED`` presents every part in a random rotation, moved (as in ``bench_partial.py``).
Prints one row per run, then the summary; writes rows and summary as JSON and CSV.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from bench_partial import (
    add_part_options,
    apply_part_search_options,
    network_extractor,
    part_against_whole,
    part_manifest,
    partial_to_full_runs,
    run_and_write,
)

from spidermatch.data.datasets import ShapeFolder
from spidermatch.eval.errors import pointwise_geodesic_errors

COLUMNS = ("part", "target", "kept_area", "orientation", "nn_error", "large", "seconds")
LARGE_ERROR = 0.1  # a point farther than this from its true image is on the wrong region


def run_part(part_name: str, parts: Path, folder: ShapeFolder, target_name: str, args, extractor) -> dict:
    """Nearest-feature errors of one part against one whole shape."""
    run = part_against_whole(parts, folder, part_name, target_name, args.turn_parts)
    part, target, row = run.part, run.target, run.row
    started = time.perf_counter()
    feat_part, feat_target = extractor.part_features(part, target.mesh)
    row["seconds"] = round(time.perf_counter() - started, 1)
    chosen = extractor.orientations.get(part.name)
    row["orientation"] = chosen.describe() if chosen is not None else "-"
    sources, truth_images = run.scored_points()
    predicted = np.argmax(feat_part[sources] @ feat_target.T, axis=1)
    errors = pointwise_geodesic_errors(target.mesh, predicted, truth_images)
    row["nn_error"] = round(float(errors.mean()), 4)
    row["large"] = round(float((errors > LARGE_ERROR).mean()), 4)
    return row


def summary(rows: list[dict]) -> dict:
    """Mean and median error, share of large errors, runs above 0.1: other shapes, own shape, per kind."""

    def figures(group: list[dict]) -> dict:
        if not group:
            return {"runs": 0}
        errors = [row["nn_error"] for row in group]
        return {
            "runs": len(group),
            "mean_nn_error": round(statistics.mean(errors), 4),
            "median_nn_error": round(statistics.median(errors), 4),
            "mean_large": round(statistics.mean(row["large"] for row in group), 4),
            "runs_above_0.1": sum(error > LARGE_ERROR for error in errors),
        }

    own = [row for row in rows if row["part"].startswith(row["target"] + "-")]
    other = [row for row in rows if row not in own]
    kinds = sorted({row["part"].rsplit("-", 1)[1] for row in rows})
    return {
        "other_shape": figures(other),
        "own_shape": figures(own),
        **{kind: figures([r for r in other if r["part"].endswith(kind)]) for kind in kinds},
    }


def planned_runs(args, folder: ShapeFolder) -> list[tuple[str, str]]:
    """(part, target) of every run: the shapes paired with the part's shape (and itself with ``--own``)."""
    manifest = part_manifest(args.parts)
    runs = partial_to_full_runs(manifest, args.pairs, folder)
    if args.own:
        runs += [(row["part"], row["shape"]) for row in manifest]
    return list(dict.fromkeys(runs))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_part_options(parser, "a trained network")
    parser.add_argument("--own", action="store_true", help="also each part against the shape it was cut from")
    parser.add_argument("--out", required=True, type=Path)
    args = parser.parse_args(argv)
    if args.scan_copies is not None:  # the API caps features of large meshes; this bench does not
        raise SystemExit("--scan-copies: measure scans end to end with bench_partial.py")
    apply_part_search_options(args)
    folder = ShapeFolder(args.data)
    extractor = network_extractor(args.checkpoint)
    run_and_write(
        planned_runs(args, folder),
        lambda part, target: run_part(part, args.parts, folder, target, args, extractor),
        COLUMNS,
        summary,
        args.out,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
