"""Whole ``spidermatch-match`` runs, process start to exit: what a user waits for, stage by stage.

For every pair, one ``spidermatch-match`` process (its own interpreter, imports, feature
extraction, solve, dense map and outputs; PNGs off unless ``--png``). The row holds the wall
time of the process, its peak memory, the status and gap from its ``result.json``, every
stage's time from there, and the mean geodesic error when ``--ground-truth`` passes the
``corres/`` files (that adds the evaluation's time to the process). With ``--cold-cache`` every
process gets an empty operator cache (``SPIDERMATCH_CACHE_DIR``), as a user's first match of
new meshes has; otherwise the user's cache is used as it is.

Example (the five FAUST_r validation pairs, label-free features, default resolution and
strategy):

    .venv/bin/python bench/bench_match_process.py --data ../shared/data/FAUST_r \
        --checkpoint runs/faust_unsup_orient_s0/best.pt

Prints one row per pair and writes all rows to
bench/results/match_process_faust_val.{json,csv} (``--out``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_scaling import format_row, write_rows
from feature_options import pair_problem

VALIDATION_PAIRS = [f"tr_reg_{i:03d}:tr_reg_{i + 1:03d}" for i in range(70, 80, 2)]
COLUMNS = ("pair", "exit_code", "status", "gap", "process_s", "features_s", "solve_s", "dense_s", "peak_mib")


def match_command(args: argparse.Namespace, source: str, target: str, run_dir: Path) -> list[str]:
    """The ``spidermatch-match`` command line for one pair."""
    data = Path(args.data)
    command = [
        match_executable(),
        f"source={data / 'off' / f'{source}.off'}",
        f"target={data / 'off' / f'{target}.off'}",
        f"hydra.run.dir={run_dir}",
        f"output.png={'true' if args.png else 'false'}",
    ]
    if args.checkpoint:
        command += ["features=learned", f"checkpoint={args.checkpoint}"]
    if args.ground_truth:
        command += [
            f"source_corr={data / 'corres' / f'{source}.vts'}",
            f"target_corr={data / 'corres' / f'{target}.vts'}",
        ]
    return command + list(args.override)


def match_executable() -> str:
    """The ``spidermatch-match`` script next to this interpreter (or on PATH)."""
    beside = Path(sys.executable).parent / "spidermatch-match"
    found = str(beside) if beside.exists() else shutil.which("spidermatch-match")
    if found is None:
        sys.exit("spidermatch-match not found: install the project (pip install -e .)")
    return found


def run_process(
    command: list[str], log_path: Path, cache_dir: Path | None = None
) -> tuple[int, float, float]:
    """Run ``command`` (output to ``log_path``); its exit code, wall seconds and peak MiB.

    With ``cache_dir`` the process keeps its operator cache there instead of the user's.
    """
    environment = dict(os.environ)
    if cache_dir is not None:
        environment["SPIDERMATCH_CACHE_DIR"] = str(cache_dir)
    with log_path.open("w") as log:
        start = time.perf_counter()
        process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=environment)
        _, status, usage = os.wait4(process.pid, 0)
        wall = time.perf_counter() - start
    process.returncode = os.waitstatus_to_exitcode(status)
    return process.returncode, wall, usage.ru_maxrss / 1024


def pair_row(pair: str, code: int, wall: float, peak_mib: float, run_dir: Path) -> dict:
    """The row of one run, from its exit and its ``result.json`` (if written)."""
    row = {"pair": pair, "exit_code": code, "process_s": round(wall, 2), "peak_mib": round(peak_mib, 1)}
    result_path = run_dir / "result.json"
    if not result_path.exists():
        return {**row, "status": "no result.json"}
    result = json.loads(result_path.read_text())
    row.update(status=result.get("status"), gap=result.get("gap"), objective=result.get("objective"))
    row.update({f"{stage}_s": seconds for stage, seconds in (result.get("timings_s") or {}).items()})
    row["total_time_s"] = result.get("total_time_s")
    error = result.get("geodesic_error") or {}
    dense = (result.get("dense") or {}).get("dense") or {}
    row["sparse_error"], row["dense_error"] = error.get("mean"), dense.get("geodesic_error")
    return row


def summary_of(rows: list[dict], cold_cache: bool = False) -> dict:
    """The median process time of the runs that exited 0, and whether the caches were cold."""
    finished = [row["process_s"] for row in rows if row.get("exit_code") == 0]
    median = statistics.median(finished) if finished else None
    return {"summary": {"median_process_s": median, "cold_cache": cold_cache}}


def main(argv: list[str] | None = None) -> None:
    """Run ``spidermatch-match`` once per pair and write the table."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", required=True, help="FAUST_r-style folder (off/, corres/)")
    parser.add_argument("--pairs", nargs="+", default=VALIDATION_PAIRS, help="SOURCE:TARGET shape names")
    parser.add_argument("--checkpoint", default=None, help="trained network (features=learned); WKS without")
    parser.add_argument(
        "--ground-truth", action="store_true", help="pass corres/ files (adds the evaluation)"
    )
    parser.add_argument("--png", action="store_true", help="write the PNGs too")
    parser.add_argument(
        "--cold-cache", action="store_true", help="an empty operator cache for every process (a first run)"
    )
    parser.add_argument(
        "--override", nargs="*", default=[], help="further Hydra overrides, e.g. resolution=2000"
    )
    parser.add_argument("--out", default="bench/results/match_process_faust_val.json")
    args = parser.parse_args(argv)
    problem = pair_problem(args.data, args.pairs)
    if problem:
        parser.error(problem)
    out, rows = Path(args.out), []
    out.parent.mkdir(parents=True, exist_ok=True)
    print(" | ".join(COLUMNS), flush=True)
    with tempfile.TemporaryDirectory(prefix="bench_match_") as work:
        for pair in args.pairs:
            source, target = pair.split(":")
            run_dir = Path(work) / f"{source}__{target}"
            cache_dir = Path(work) / f"cache_{source}__{target}" if args.cold_cache else None
            code, wall, peak = run_process(
                match_command(args, source, target, run_dir), Path(work) / "log.txt", cache_dir
            )
            rows.append(pair_row(pair, code, wall, peak, run_dir))
            print(format_row(rows[-1], COLUMNS, 4), flush=True)
            write_rows(
                out, rows, summary_of(rows, args.cold_cache)
            )  # after every pair: a run stopped half way keeps what it measured
    print(f"wrote {out} and {out.with_suffix('.csv')}")


if __name__ == "__main__":
    main()
