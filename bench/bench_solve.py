"""Benchmark solving strategies on dataset pairs: one subprocess per instance (clean peak memory).

Example (FAUST_r from the shared data folder, WKS features):

    .venv/bin/python bench/bench_solve.py --data ../shared/data/FAUST_r \
        --pairs tr_reg_070:tr_reg_071 --resolutions 100 250 500 --strategies plain \
        --time-limit 900 --out bench/results/solve.json

Prints one table row per (pair, resolution, strategy) and writes all rows as JSON and CSV.
"""

from __future__ import annotations

import argparse
import csv
import json
import multiprocessing as mp
import resource
import sys
import time
from pathlib import Path

from feature_options import add_feature_options, load_pair_with_features, parse_checked

COLUMNS = (
    "pair",
    "faces",
    "features",
    "strategy",
    "status",
    "variables",
    "rows",
    "build_s",
    "solve_s",
    "objective",
    "bound",
    "gap",
    "check",
    "geo_err",
    "peak_mib",
)


def run_instance(args: tuple) -> dict:
    data, pair, faces, strategy, features, time_limit, checkpoint, highs = args

    from spidermatch.eval.errors import sparse_map_errors
    from spidermatch.pipeline import MatchSettings, match
    from spidermatch.solve.types import SolverOptions

    x, y, feat_x, feat_y = load_pair_with_features(data, pair, features, checkpoint)
    solver = SolverOptions(time_limit=time_limit, extra=highs)
    settings = MatchSettings(resolution=faces, strategy=strategy, solver=solver)
    result = match(x.mesh, y.mesh, feat_x, feat_y, settings)
    row = {
        "pair": f"{pair[0]}:{pair[1]}",
        "faces": faces,
        "features": features,
        "strategy": strategy,
        "status": result.solve.status,
        "variables": result.solve.n_vars,
        "rows": result.solve.n_rows,
        "build_s": round(sum(result.timings.get(k, 0.0) for k in ("decimate", "curve", "costs", "build")), 2),
        "solve_s": round(result.solve.wall_time, 2),
        "objective": result.solve.objective,
        "bound": result.solve.bound,
        "gap": result.solve.gap,
        "check": None if result.check is None else bool(result.check.ok),
        "geo_err": None,
        "message": result.solve.message,  # in the files only: why a run stopped (e.g. HiGHS's time limit)
    }
    if result.low_map is not None and x.corr is not None and y.corr is not None:
        pairs = result.full_pairs
        row["geo_err"] = round(
            sparse_map_errors(pairs[:, 0], pairs[:, 1], x.mesh, x.corr, y.corr, y.mesh).mean, 4
        )
    row["peak_mib"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    return row


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


def format_row(row: dict) -> str:
    cells = []
    for key in COLUMNS:
        value = row.get(key)
        cells.append(f"{value:.6g}" if isinstance(value, float) else str(value))
    return " | ".join(cells)


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
                settings = (strategy, args.features, args.time_limit, args.checkpoint, highs)
                task = (args.data, pair, faces, *settings)
                start = time.perf_counter()
                with context.Pool(1) as pool:
                    row = pool.apply(run_instance, (task,))
                row["total_s"] = round(time.perf_counter() - start, 1)
                rows.append(row)
                print(format_row(row), flush=True)
                write_rows(out, rows)  # after every instance: an interrupted run keeps what it measured
    if highs:
        print(f"HiGHS options: {highs}")
    print(f"wrote {out} and {out.with_suffix('.csv')}")


def write_rows(out: Path, rows: list[dict]) -> None:
    out.write_text(json.dumps({"argv": sys.argv, "rows": rows}, indent=2) + "\n")
    with out.with_suffix(".csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


if __name__ == "__main__":
    main()
