"""How solving strategies scale with the resolution: one subprocess per instance (clean peak memory).

For every (pair, faces, strategy): the time of every stage (features, decimation, curve,
costs, build, solve, check), the columns built against the full model's, rows, status,
objective, bound, gap, mean geodesic error, the curve length and the peak memory.
Strategies that need the full model (rcfix, plain) are skipped where it would have more
than ``--full-model-columns`` columns (about 3.7 f^2 columns at f faces).

Example (the five FAUST_r validation pairs, learned features):

    .venv/bin/python bench/bench_scaling.py \
        --data ../shared/data/FAUST_r --features learned --checkpoint runs/faust_sup_s0/best.pt \
        --faces 1000 2000 --strategies colgen rcfix --time-limit 600

Prints one row per instance and writes all rows to
bench/results/solver_scaling_faust_val.{json,csv} (``--out``).
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import multiprocessing as mp
import resource
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from feature_options import add_feature_options, load_pair_with_features, parse_checked

from spidermatch.solve.types import FLOW_ROWS_VALUES

VALIDATION_PAIRS = [f"tr_reg_{i:03d}:tr_reg_{i + 1:03d}" for i in range(70, 80, 2)]
STAGES = ("features", "decimate", "curve", "costs", "build", "solve", "check")
COLUMNS = (
    "pair", "faces", "strategy", "status", "columns_built", "columns_full", "rows", "curve_length",
    "build_s", "solve_s", "gap", "objective", "geo_err", "peak_mib",
)  # fmt: skip
FULL_MODEL_COLUMNS_PER_FACE2 = 3.74  # |E_P| ~ 0.575 f * 6.5 f on FAUST_r meshes decimated to f faces


@dataclass(frozen=True)
class Instance:
    """One solve of a benchmark: the pair, its resolution and every setting that tells runs apart.

    The defaults are the library's (the Christofides tour, seed 0, the flow rows found
    needed, the LP's connectivity cuts on, no extra HiGHS option, no solver log).
    """

    data: str | None
    pair: tuple[str, str]
    faces: int
    strategy: str
    features: str
    checkpoint: str | None
    adapt_steps: int
    time_limit: float
    curve_matching: str
    log_dir: str | None = None
    highs: dict = field(default_factory=dict)  # extra HiGHS options for every solve (bench_solve.py --highs)
    tour: str = "christofides"
    curve_seed: int = 0
    flow_rows: str = "found"
    lp_cuts: bool = True

    @property
    def log_name(self) -> str:
        """The file name of this instance's solver log: every setting that tells two instances apart."""
        # the defaults are left unnamed, as the stored logs are
        rows_named = "" if self.flow_rows == "found" else f"_flow_rows_{self.flow_rows}"
        cuts_named = "" if self.lp_cuts else "_no_lp_cuts"
        settings = f"{self.faces}_{self.strategy}_{self.tour}_seed{self.curve_seed}"
        return f"{self.pair[0]}_{self.pair[1]}_{settings}{rows_named}{cuts_named}.log"


def run_instance(task: Instance) -> dict:
    """Match one pair at one resolution with one strategy; the row of figures."""
    pair = task.pair
    label = f"{pair[0]}:{pair[1]}"
    if task.log_dir:  # the solver's INFO log of this instance, one file per instance
        import logging

        logging.basicConfig(filename=str(Path(task.log_dir) / task.log_name), level=logging.INFO, force=True)
    from spidermatch.eval.errors import sparse_map_errors
    from spidermatch.pipeline import MatchSettings, match
    from spidermatch.solve.types import SolverOptions
    from spidermatch.validate import OptionError

    sampler = TreeMemorySampler()
    start = time.perf_counter()
    x, y, feat_x, feat_y = load_pair_with_features(
        task.data, pair, task.features, task.checkpoint, task.adapt_steps
    )
    features_s = time.perf_counter() - start
    settings = MatchSettings(
        resolution=task.faces,
        strategy=task.strategy,
        curve_matching=task.curve_matching,
        curve_tour=task.tour,
        curve_seed=task.curve_seed,
        solver=SolverOptions(
            time_limit=task.time_limit, extra=task.highs, flow_rows=task.flow_rows, lp_cuts=task.lp_cuts
        ),
    )
    try:
        result = match(x.mesh, y.mesh, feat_x, feat_y, settings)
    except OptionError as refused:  # e.g. the memory estimate: a row saying why, and the next instance
        return {
            "pair": label, "faces": task.faces, "strategy": task.strategy, "status": "refused",
            "message": str(refused), "features_s": round(features_s, 2), **peak_memory(),
            "sampled_peak_mib": sampler.stop(),
        }  # fmt: skip
    solved = result.solve
    row = {
        "pair": label,
        "faces": task.faces,
        "features": task.features,
        "strategy": task.strategy,
        "curve_matching": task.curve_matching,
        "curve_tour": task.tour,
        "curve_seed": task.curve_seed,
        "flow_rows": task.flow_rows,
        "lp_cuts": task.lp_cuts,
        "adapt_steps": task.adapt_steps,
        "status": solved.status,
        "columns_built": _columns_built(task.strategy, solved, result.graph.n_edges),
        "columns_full": result.graph.n_edges,
        "rows": solved.n_rows,
        "curve_length": result.curve.length,
        "build_s": round(result.timings.get("build", 0.0), 2),  # the full model's; costs_s below
        "solve_s": round(solved.wall_time, 2),
        "gap": solved.gap,
        "objective": solved.objective,
        "bound": solved.bound,
        "check": None if result.check is None else bool(result.check.ok),
        "geo_err": None,
        "message": solved.message,
        "tours": tours_tried(result.tours),
        "tours_side_by_side": bool(result.tours) and all(t.get("side_by_side") for t in result.tours),
    }
    row.update({f"{stage}_s": round(result.timings.get(stage, 0.0), 2) for stage in STAGES[1:]})
    row["features_s"] = round(features_s, 2)
    if result.low_map is not None and x.corr is not None and y.corr is not None:
        pairs = result.full_pairs
        errors = sparse_map_errors(pairs[:, 0], pairs[:, 1], x.mesh, x.corr, y.corr, y.mesh)
        row["geo_err"] = round(errors.mean, 4)
    row.update(peak_memory())
    row["sampled_peak_mib"] = sampler.stop()
    return row


def tours_tried(tours: list[dict]) -> str | None:
    """``curve_tour="auto"``: each tour tried as tour:status:gap:seconds, the kept one starred."""
    if not tours:
        return None
    return "; ".join(
        f"{'*' if t['chosen'] else ''}{t['tour']}:{t['status']}:{t['gap']}:{t['solve_s']:.0f}s" for t in tours
    )


def _columns_built(strategy: str, solved, full_columns: int) -> int | None:
    """Columns the strategy built: all for a full-model strategy, unknown (None) if colgen did not say."""
    if solved.columns_built is not None or strategy == "colgen":
        return solved.columns_built
    return full_columns


class TreeMemorySampler:
    """The largest total memory of this process and its descendants, sampled in a thread.

    The total is the sum of proportional set sizes (``Pss`` in ``/proc/<pid>/smaps_rollup``),
    which counts a page shared after ``fork`` once in all, so it is what the process tree held
    at that moment; with two solver processes side by side (``curve.tour=auto``) the sum of the
    largest child's and this process's peaks (:func:`peak_memory`) is not. Linux only (0 elsewhere).
    Reading ``smaps_rollup`` walks a process's pages (about 45 ms for 3 GiB), so it samples
    every ``every_s`` seconds: a restricted MIP holds its peak far longer, and the solvers keep
    their cores.
    """

    def __init__(self, every_s: float = 5.0) -> None:
        import threading

        self.peak_kib, self._every_s, self._done = 0, every_s, threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()

    def _sample(self) -> None:
        import os

        while not self._done.wait(self._every_s):
            self.peak_kib = max(self.peak_kib, sum(_pss_kib(pid) for pid in _process_tree(os.getpid())))

    def stop(self) -> float:
        """Stop sampling; the peak in MiB."""
        self._done.set()
        self._thread.join()
        return round(self.peak_kib / 1024, 1)


def _process_tree(pid: int) -> list[int]:
    """``pid`` and its descendants (Linux ``/proc``; just ``pid`` where it cannot be read)."""
    tree, todo = [], [pid]
    while todo:
        current = todo.pop()
        tree.append(current)
        try:
            for task in Path(f"/proc/{current}/task").iterdir():
                todo += [int(child) for child in (task / "children").read_text().split()]
        except OSError:
            continue
    return tree


def _pss_kib(pid: int) -> int:
    """Proportional set size of a process in KiB (0 if it has ended or cannot be read)."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return 0


def peak_memory() -> dict:
    """Peak resident MiB of this process and of its solver process (the largest child it waited for).

    The two run at once and share the pages the child has not written (``fork``), so their
    sum, ``peak_mib``, is an upper bound on what the instance held at any time.
    """
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    solver = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    return {
        "main_peak_mib": round(own, 1),
        "solver_peak_mib": round(solver, 1),
        "peak_mib": round(own + solver, 1),
    }


def skipped_row(pair: tuple, faces: int, strategy: str, limit: float) -> dict:
    """The row of an instance not run because its full model would be too large."""
    estimate = FULL_MODEL_COLUMNS_PER_FACE2 * faces**2
    return {
        "pair": f"{pair[0]}:{pair[1]}",
        "faces": faces,
        "strategy": strategy,
        "status": "skipped",
        "columns_full": int(estimate),
        "message": f"full model of ~{estimate / 1e6:.0f} M columns exceeds --full-model-columns {limit:.3g}",
    }


def add_lp_cuts_option(parser: argparse.ArgumentParser) -> None:
    """``--no-lp-cuts``: ``solver.lp_cuts=false`` for every solve (``args.lp_cuts``, True by default)."""
    parser.add_argument(
        "--no-lp-cuts", dest="lp_cuts", action="store_false", help="solver.lp_cuts=false (no cuts in the LP)"
    )


def write_rows(out: Path, rows: list[dict], extra: dict | None = None) -> None:
    """All rows as JSON (with the command line, the software's versions and ``extra``) and CSV (columns:
    every key any row has)."""
    from spidermatch.versions import software_versions

    header = {"argv": sys.argv, "software": software_versions(), **(extra or {})}
    out.write_text(json.dumps({**header, "rows": rows}, indent=2) + "\n")
    keys = list(dict.fromkeys(key for row in rows for key in row))
    with out.with_suffix(".csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)


def format_row(row: dict, columns: tuple = COLUMNS, digits: int = 6) -> str:
    """One printed table row: the values of ``columns``, floats to ``digits`` significant digits."""
    return " | ".join(
        f"{row.get(k):.{digits}g}" if isinstance(row.get(k), float) else str(row.get(k)) for k in columns
    )


def main(argv: list[str] | None = None) -> None:
    """Run every (pair, faces, strategy) in its own process and write the table."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", default="synthetic", help="FAUST_r-style folder, or 'synthetic'")
    parser.add_argument("--pairs", nargs="+", default=VALIDATION_PAIRS, help="SOURCE:TARGET shape names")
    parser.add_argument("--faces", nargs="+", type=int, default=[500, 1000, 2000, 4000])
    parser.add_argument("--strategies", nargs="+", default=["colgen", "rcfix"])
    parser.add_argument("--curve-matching", default="greedy", choices=("greedy", "blossom"))
    parser.add_argument("--curve-tour", default="christofides", choices=("christofides", "two_opt", "auto"))
    parser.add_argument(
        "--curve-seeds", nargs="+", type=int, default=[0], help="SpiderCurve start-vertex seeds, one run each"
    )
    parser.add_argument("--time-limit", type=float, default=600.0, help="seconds per solve")
    parser.add_argument("--flow-rows", default="found", choices=FLOW_ROWS_VALUES, help="solver.flow_rows")
    add_lp_cuts_option(parser)
    parser.add_argument("--full-model-columns", type=float, default=2.0e7)
    parser.add_argument("--out", default="bench/results/solver_scaling_faust_val.json")
    parser.add_argument("--log-dir", default=None, help="write each instance's INFO log to this folder")
    add_feature_options(parser, adaptation=True)
    args = parse_checked(parser, argv)
    out, rows = Path(args.out), []
    out.parent.mkdir(parents=True, exist_ok=True)
    if args.log_dir:
        Path(args.log_dir).mkdir(parents=True, exist_ok=True)
    print(" | ".join(COLUMNS), flush=True)
    context = mp.get_context("spawn")
    for faces in args.faces:
        for pair_text in args.pairs:
            pair = tuple(pair_text.split(":"))
            for strategy, curve_seed in itertools.product(args.strategies, args.curve_seeds):
                full = FULL_MODEL_COLUMNS_PER_FACE2 * faces**2
                if strategy != "colgen" and full > args.full_model_columns:
                    row = skipped_row(pair, faces, strategy, args.full_model_columns)
                else:
                    task = Instance(
                        args.data, pair, faces, strategy, args.features, args.checkpoint, args.adapt_steps,
                        args.time_limit, args.curve_matching, args.log_dir, tour=args.curve_tour,
                        curve_seed=curve_seed, flow_rows=args.flow_rows, lp_cuts=args.lp_cuts,
                    )  # fmt: skip
                    start = time.perf_counter()
                    with context.Pool(1) as pool:
                        row = pool.apply(run_instance, (task,))
                    row["process_s"] = round(time.perf_counter() - start, 1)
                rows.append(row)
                print(format_row(row), flush=True)
                write_rows(out, rows)  # after every instance: an interrupted run keeps what it measured
    print(f"wrote {out} and {out.with_suffix('.csv')}")


if __name__ == "__main__":
    main()
