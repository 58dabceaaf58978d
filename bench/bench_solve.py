"""Benchmark solving strategies on dataset pairs: one subprocess per instance (clean peak memory).

Example (FAUST_r from the shared data folder, WKS features):

    .venv/bin/python bench/bench_solve.py --data ../shared/data/FAUST_r \
        --pairs tr_reg_070:tr_reg_071 --resolutions 100 250 500 --strategies plain \
        --time-limit 900 --out bench/results/solve.json

Prints one table row per (pair, resolution, strategy) and writes all rows as JSON and CSV: the
instances and rows of ``bench_scaling.py`` (one runner for both), with HiGHS options of your own.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import time
from pathlib import Path

from bench_scaling import Instance, add_lp_cuts_option, format_row, run_instance, write_rows
from feature_options import add_feature_options, parse_checked

COLUMNS = (
    "pair",
    "faces",
    "features",
    "strategy",
    "status",
    "columns_built",
    "rows",
    "solve_s",
    "objective",
    "bound",
    "gap",
    "check",
    "geo_err",
    "peak_mib",
)


def highs_option(text: str) -> tuple[str, object]:
    """``NAME=VALUE`` as a HiGHS option, VALUE read as int, float or bool where it is one."""
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise SystemExit(f"--highs expects NAME=VALUE, got {text!r}")
    for convert in (int, float):
        try:
            return name, convert(value)
        except ValueError:
            pass
    return name, {"true": True, "false": False}.get(value.lower(), value)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", default="synthetic", help="FAUST_r-style folder, or 'synthetic'")
    parser.add_argument("--pairs", nargs="+", required=True, help="SOURCE:TARGET shape names")
    parser.add_argument("--resolutions", nargs="+", type=int, default=[100, 250, 500])
    parser.add_argument("--strategies", nargs="+", default=["plain"])
    add_feature_options(parser)
    parser.add_argument("--time-limit", type=float, default=600.0)
    parser.add_argument("--out", default="bench/results/solve.json")
    add_lp_cuts_option(parser)
    parser.add_argument(
        "--highs",
        nargs="*",
        default=[],
        metavar="NAME=VALUE",
        help="extra HiGHS options for every solve, e.g. mip_pscost_minreliable=0",
    )
    args = parse_checked(parser, argv)
    highs = dict(highs_option(text) for text in args.highs)
    rows = []
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    print(" | ".join(COLUMNS), flush=True)
    context = mp.get_context("spawn")
    for pair_text in args.pairs:
        pair = tuple(pair_text.split(":"))
        for faces in args.resolutions:
            for strategy in args.strategies:
                # no adaptation; the default tour, seed and flow rows
                task = Instance(
                    args.data, pair, faces, strategy, args.features, args.checkpoint, 0, args.time_limit,
                    "greedy", highs=highs, lp_cuts=args.lp_cuts,
                )  # fmt: skip
                start = time.perf_counter()
                with context.Pool(1) as pool:
                    row = pool.apply(run_instance, (task,))
                row["total_s"] = round(time.perf_counter() - start, 1)
                rows.append(row)
                print(format_row(row, COLUMNS), flush=True)
                write_rows(out, rows)  # after every instance: an interrupted run keeps what it measured
    if highs:
        print(f"HiGHS options: {highs}")
    print(f"wrote {out} and {out.with_suffix('.csv')}")


if __name__ == "__main__":
    main()
