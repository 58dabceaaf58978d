"""LP relaxation and integer optimum per constraint-family subset: where the integrality gap comes from.

Example (FAUST_r, WKS features, 500 faces, two pairs):

    .venv/bin/python bench/bench_lp_families.py --data ../shared/data/FAUST_r \
        --pairs tr_reg_070:tr_reg_071 tr_reg_072:tr_reg_073 --faces 500 --mip \
        --out bench/results/lp_families.json

For each pair and each subset of (CYC, CON, PES, ANS) it prints and writes: LP value,
number of fractional LP values, how many layers the LP crosses on more than one edge
(a mixture of several paths) and the longest cyclic run of such layers, and, with
``--mip``, the certified integer optimum and the LP's gap to it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from feature_options import add_feature_options, load_pair_with_features, parse_checked

SUBSETS = (("CYC", "CON"), ("CYC", "CON", "PES"), ("CYC", "CON", "ANS"), ("CYC", "CON", "PES", "ANS"))
COLUMNS = ("pair", "families", "lp_value", "fractional", "split_layers", "longest_split_run", "lp_s",
           "optimum", "status", "gap")  # fmt: skip


def prepare_pair(data: str, pair: str, faces: int, features: str, checkpoint: str | None):
    """Curve, product graph and full model of one FAUST_r-style pair."""
    from spidermatch.pipeline import MatchSettings, prepare

    x, y, feat_x, feat_y = load_pair_with_features(data, tuple(pair.split(":")), features, checkpoint)
    _, _, curve, graph, model = prepare(
        x.mesh, y.mesh, feat_x, feat_y, MatchSettings(resolution=faces, strategy="rcfix"), {}
    )
    return curve, graph, model


def family_row(curve, graph, model, families, mip: bool, options) -> dict:
    """LP (and optionally integer) figures of the model restricted to ``families``."""
    from spidermatch.model.ilp import build_model
    from spidermatch.model.product_graph import cyclic_runs, split_layers
    from spidermatch.solve.rcfix import solve_lp
    from spidermatch.solve.strategies import solve_with_strategy
    from spidermatch.solve.types import count_fractional, relative_gap

    sub = build_model(graph, curve, model.costs, families)
    start = time.perf_counter()
    lp = solve_lp(sub, options)
    if lp is None:
        return {"families": "+".join(families), "status": "infeasible"}
    split = split_layers(graph, lp.x)
    row = {
        "families": "+".join(families),
        "lp_value": lp.dual.bound,
        "fractional": count_fractional(lp.x),
        "split_layers": f"{int(split.sum())}/{graph.n_layers}",
        "longest_split_run": max((length for _, length in cyclic_runs(split)), default=0),
        "lp_s": round(time.perf_counter() - start, 2),
    }
    if mip:
        result = solve_with_strategy("rcfix", sub, graph, curve, options)
        row.update(optimum=result.objective, status=result.status)
        row["gap"] = relative_gap(result.objective, lp.dual.bound)
    return row


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", required=True, help="FAUST_r-style folder")
    parser.add_argument("--pairs", "--pair", nargs="+", required=True, help="SOURCE:TARGET shape names")
    parser.add_argument("--faces", type=int, default=250)
    add_feature_options(parser)
    parser.add_argument("--mip", action="store_true", help="also solve each subset to optimality (rcfix)")
    parser.add_argument("--time-limit", type=float, default=600.0)
    parser.add_argument("--out", default="bench/results/lp_families.json")
    args = parse_checked(parser, argv)

    from spidermatch.solve.types import SolverOptions

    options = SolverOptions(threads=1, time_limit=args.time_limit)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    rows = []
    print(" | ".join(COLUMNS))
    for pair in args.pairs:
        curve, graph, model = prepare_pair(args.data, pair, args.faces, args.features, args.checkpoint)
        for families in SUBSETS:
            row = {"pair": pair, **family_row(curve, graph, model, families, args.mip, options)}
            rows.append(row)
            print(" | ".join(str(row.get(k, "-")) for k in COLUMNS), flush=True)
            # written after every row: a run stopped half way keeps what it measured
            out.write_text(json.dumps({"argv": sys.argv, "rows": rows}, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
