"""Nearest-neighbour map error of WKS, learned features, and learned features after test-time adaptation.

    .venv/bin/python bench/bench_adaptation.py --data ../shared/data/TOSCA_animals \
        --checkpoint outputs/train/<run>/best.pt --pairs cat5:cat0 dog5:dog0 horse5:horse0 \
        --adapt-steps 0 20 --out bench/results/tosca_adaptation_nn.json

For every pair, at full resolution: the mean geodesic error (Princeton protocol) of the
nearest-neighbour map in feature space for WKS and for the network after each number of
adaptation steps (0 = the trained network as is), and the seconds it took. Prints one
JSON row per pair and the means, and writes them all as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from feature_options import pair_problem

from features.extractor import WKSExtractor
from features.learned import LearnedExtractor
from spidermatch.data.datasets import open_dataset
from spidermatch.eval.errors import feature_map_errors


def nn_error(feat_x, feat_y, x, y) -> float:
    """Mean geodesic error of the nearest-neighbour map from X to Y."""
    return float(feature_map_errors(feat_x, feat_y, x.corr, y.corr, y.mesh).mean)


def pair_row(x, y, wks: WKSExtractor, learned: dict[int, LearnedExtractor]) -> dict:
    """Errors and times of every feature kind on one pair."""
    row = {"pair": f"{x.name}:{y.name}", "vertices": [x.mesh.n_verts, y.mesh.n_verts]}
    start = time.perf_counter()
    row["wks"] = round(nn_error(wks(x.mesh), wks(y.mesh), x, y), 4)
    row["wks_s"] = round(time.perf_counter() - start, 2)
    for steps, extractor in learned.items():
        start = time.perf_counter()
        feat_x, feat_y = extractor.pair_features(x.mesh, y.mesh)
        row[f"learned_adapt{steps}"] = round(nn_error(feat_x, feat_y, x, y), 4)
        row[f"learned_adapt{steps}_s"] = round(time.perf_counter() - start, 2)
    return row


def main(argv: list[str] | None = None) -> None:
    formatter = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=formatter)
    parser.add_argument("--data", required=True, help="a dataset folder with off/ and corres/")
    parser.add_argument("--pairs", nargs="+", required=True, help="SOURCE:TARGET shape names")
    parser.add_argument("--checkpoint", required=True, help="a spidermatch-train best.pt")
    parser.add_argument("--adapt-steps", nargs="+", type=int, default=[0, 20])
    parser.add_argument("--out", default="bench/results/adaptation_nn.json")
    args = parser.parse_args(argv)
    problem = pair_problem(args.data, args.pairs)
    if problem:
        parser.error(problem)
    if not Path(args.checkpoint).is_file():
        parser.error(f"--checkpoint {args.checkpoint}: no such file")
    dataset = open_dataset(args.data)
    wks = WKSExtractor()
    learned = {steps: LearnedExtractor(args.checkpoint, adapt_steps=steps) for steps in args.adapt_steps}
    rows = []
    for text in args.pairs:
        source, target = text.split(":")
        rows.append(pair_row(dataset.load(source), dataset.load(target), wks, learned))
        print(json.dumps(rows[-1]), flush=True)
    kinds = ["wks", *(f"learned_adapt{steps}" for steps in args.adapt_steps)]
    means = {kind: round(sum(row[kind] for row in rows) / len(rows), 4) for kind in kinds}
    print(f"mean over {len(rows)} pairs: " + ", ".join(f"{k} {v:.4f}" for k, v in means.items()))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"argv": sys.argv, "rows": rows, "means": means}, indent=2) + "\n")


if __name__ == "__main__":
    main()
