"""Accuracy of the nearest-neighbour map in feature space, at full resolution.

    .venv/bin/python bench/bench_features.py --data ../shared/data/FAUST_r \
        --pairs tr_reg_070:tr_reg_071 tr_reg_072:tr_reg_073 --features wks

Prints, per pair, the mean geodesic error (Princeton protocol) and the time to compute
the features, and writes the rows as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from feature_options import add_feature_options, parse_checked

from features.extractor import extractor_by_name
from spidermatch.data.datasets import open_dataset
from spidermatch.eval.errors import feature_map_errors


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", default="synthetic")
    parser.add_argument("--pairs", nargs="+", required=True, help="SOURCE:TARGET shape names")
    add_feature_options(parser)
    parser.add_argument("--out", default="bench/results/features.json")
    args = parse_checked(parser, argv)
    dataset = open_dataset(args.data)
    extractor = extractor_by_name(args.features, args.checkpoint, use_cache=False)
    rows = []
    for text in args.pairs:
        a, b = text.split(":")
        x, y = dataset.load(a), dataset.load(b)
        start = time.perf_counter()
        feat_x, feat_y = extractor(x.mesh.centred()), extractor(y.mesh.centred())
        seconds = (time.perf_counter() - start) / 2
        error = feature_map_errors(feat_x, feat_y, x.corr, y.corr, y.mesh).mean
        rows.append(
            {
                "pair": text,
                "vertices": [x.mesh.n_verts, y.mesh.n_verts],
                "features": args.features,
                "mean_geodesic_error": round(error, 4),
                "feature_time_per_shape_s": round(seconds, 3),
            }
        )
        print(json.dumps(rows[-1]), flush=True)
    mean = sum(r["mean_geodesic_error"] for r in rows) / len(rows)
    print(f"mean over {len(rows)} pairs: {mean:.4f}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"argv": sys.argv, "rows": rows, "mean": mean}, indent=2) + "\n")


if __name__ == "__main__":
    main()
