"""LP relaxation and integer optimum per constraint-family subset: where the integrality gap comes from.

Example (FAUST_r, WKS features, 250 faces):

    .venv/bin/python bench/bench_lp_families.py --data ../shared/data/FAUST_r \
        --pair tr_reg_070:tr_reg_071 --faces 250 --out bench/results/lp_families.json

For each subset of (CYC, CON, PES, ANS) it prints and writes: LP value, number of
fractional LP values, and, with ``--mip``, the certified integer optimum and the gap.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

SUBSETS = (("CYC", "CON"), ("CYC", "CON", "PES"), ("CYC", "CON", "ANS"), ("CYC", "CON", "PES", "ANS"))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", required=True, help="FAUST_r-style folder")
    parser.add_argument("--pair", required=True, help="SOURCE:TARGET shape names")
    parser.add_argument("--faces", type=int, default=250)
    parser.add_argument("--mip", action="store_true", help="also solve each subset to optimality (rcfix)")
    parser.add_argument("--time-limit", type=float, default=600.0)
    parser.add_argument("--out", default="bench/results/lp_families.json")
    args = parser.parse_args(argv)

    from features.extractor import WKSExtractor
    from spidermatch.datasets import open_dataset
    from spidermatch.ilp import build_model
    from spidermatch.pipeline import MatchSettings, prepare
    from spidermatch.solve.highs import SolverOptions, relative_gap
    from spidermatch.solve.strategies import count_fractional, solve_lp, solve_with_strategy

    source, target = args.pair.split(":")
    dataset = open_dataset(args.data)
    x, y = dataset.load(source), dataset.load(target)
    extractor = WKSExtractor()
    feat_x, feat_y = extractor(x.mesh.centred()), extractor(y.mesh.centred())
    _, _, curve, graph, model = prepare(
        x.mesh, y.mesh, feat_x, feat_y, MatchSettings(resolution=args.faces), {}
    )
    options = SolverOptions(threads=1, time_limit=args.time_limit)
    rows = []
    print("families | LP value | fractional | LP s | integer optimum | status | gap")
    for families in SUBSETS:
        sub = build_model(graph, curve, model.costs, families)
        start = time.perf_counter()
        lp = solve_lp(sub, options)
        row = {
            "families": "+".join(families),
            "lp_value": lp.dual.bound,
            "fractional": count_fractional(lp.x),
            "lp_s": round(time.perf_counter() - start, 2),
        }
        if args.mip:
            result = solve_with_strategy("rcfix", sub, graph, curve, options)
            row.update(optimum=result.objective, status=result.status)
            row["gap"] = relative_gap(result.objective, lp.dual.bound)
        rows.append(row)
        print(
            " | ".join(
                str(row.get(k, "-"))
                for k in ("families", "lp_value", "fractional", "lp_s", "optimum", "status", "gap")
            )
        )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"argv": sys.argv, "rows": rows}, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
