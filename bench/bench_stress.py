"""Stress run: many random ordered pairs of humans and animals, each a whole ``spidermatch-match``.

What it checks, per run: the process exits with a documented code (no native abort), its
``result.json`` ends in a final status (not ``started`` or ``writing``), and the solve stage
ends within ``--time-limit`` + ``--grace`` seconds (no hang). What it reports: the certified
share, the status and exit-code counts, and the distribution of solve and process times, per
(faces, adaptation steps) cell and per kind of pair.

Pairs are drawn with a fixed seed, in four kinds taken in turn: two FAUST_r humans, two
TOSCA_animals of one class, two animals of different classes, a human and an animal (either
order). The configurations (every ``--faces`` with every ``--adapt-steps``) are taken in turn
by blocks of four pairs, so every kind meets every configuration. Features are learned and
label-free: ``--faust-checkpoint`` for two humans, ``--tosca-checkpoint`` otherwise. Ground
truth (and so the mean geodesic error) exists for two humans and for animals of one class.
PNGs and the viewer are off; the dense map is on.

Example (100 pairs at 500 and 1000 faces, with and without 20 adaptation steps):

    .venv/bin/python bench/bench_stress.py --faust ../shared/data/FAUST_r \
        --tosca ../shared/data/TOSCA_animals --faust-checkpoint ../runs/faust_unsup_seed0/best.pt \
        --tosca-checkpoint ../shared/repro/colgen_abort/tosca_unsup_seed0.pt --pairs 100 --time-limit 60

Prints one row per run and writes all rows with the summary to
bench/results/stress_faust_tosca_500_1000.{json,csv} (``--out``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import random
import statistics
import tempfile
from pathlib import Path

from bench_match_process import match_executable, pair_row, run_process
from bench_scaling import format_row, write_rows

KINDS = ("humans", "one animal class", "two animal classes", "human and animal")
FINAL_STATUSES = (
    "optimal", "feasible", "infeasible", "no_solution", "solver_failure", "input_error", "output_error",
)  # fmt: skip
DOCUMENTED_EXIT_CODES = (0, 2, 3, 4, 5, 6)  # README "Statuses and exit codes" (1: an uncaught error)
COLUMNS = (
    "n",
    "kind",
    "pair",
    "faces",
    "adapt",
    "exit_code",
    "status",
    "gap",
    "solve_s",
    "process_s",
    "peak_mib",
)


class Collections:
    """The shapes of the two collections by name, with the class of each animal."""

    def __init__(self, faust: Path, tosca: Path) -> None:
        self.folders = {"faust": faust, "tosca": tosca}
        self.humans = sorted(path.stem for path in (faust / "off").glob("*.off"))
        self.animals = sorted(path.stem for path in (tosca / "off").glob("*.off"))
        if not self.humans or not self.animals:
            raise SystemExit(f"no .off shapes in {faust / 'off'} or {tosca / 'off'}")

    @staticmethod
    def animal_class(name: str) -> str:
        return name.rstrip("0123456789")

    def draw(self, kind: str, rng: random.Random) -> tuple[str, str]:
        """One ordered pair of distinct shapes of ``kind``."""
        if kind == "humans":
            return tuple(rng.sample(self.humans, 2))
        if kind == "one animal class":
            classes = sorted({self.animal_class(name) for name in self.animals})
            paired = [c for c in classes if sum(self.animal_class(n) == c for n in self.animals) > 1]
            chosen = rng.choice(paired)  # a class with two animals at least
            members = [name for name in self.animals if self.animal_class(name) == chosen]
            return tuple(rng.sample(members, 2))
        if kind == "two animal classes":
            while True:
                pair = tuple(rng.sample(self.animals, 2))
                if self.animal_class(pair[0]) != self.animal_class(pair[1]):
                    return pair
        pair = (rng.choice(self.humans), rng.choice(self.animals))
        return pair if rng.random() < 0.5 else pair[::-1]

    def folder_of(self, name: str) -> Path:
        return self.folders["faust" if name in self.humans else "tosca"]

    def has_ground_truth(self, source: str, target: str) -> bool:
        if source in self.humans and target in self.humans:
            return True
        both_animals = source in self.animals and target in self.animals
        return both_animals and self.animal_class(source) == self.animal_class(target)


def draw_runs(collections: Collections, n_pairs: int, configurations: list, seed: int) -> list[dict]:
    """The runs: pair i has kind ``KINDS[i % 4]`` and configuration ``(i // 4) % len(configurations)``."""
    rng = random.Random(seed)
    runs = []
    for index in range(n_pairs):
        kind = KINDS[index % len(KINDS)]
        faces, adapt = configurations[(index // len(KINDS)) % len(configurations)]
        source, target = collections.draw(kind, rng)
        runs.append(
            {"n": index, "kind": kind, "source": source, "target": target, "faces": faces, "adapt": adapt}
        )
    return runs


def stress_command(args: argparse.Namespace, collections: Collections, run: dict, run_dir: Path) -> list[str]:
    """The ``spidermatch-match`` command line of one run."""
    source, target = run["source"], run["target"]
    humans = source in collections.humans and target in collections.humans
    command = [
        match_executable(),
        f"source={collections.folder_of(source) / 'off' / f'{source}.off'}",
        f"target={collections.folder_of(target) / 'off' / f'{target}.off'}",
        f"hydra.run.dir={run_dir}",
        "features=learned",
        f"checkpoint={args.faust_checkpoint if humans else args.tosca_checkpoint}",
        f"features.adapt_steps={run['adapt']}",
        f"resolution={run['faces']}",
        f"solver.time_limit={args.time_limit}",
        "output.png=false",
        "output.viewer=false",
        *args.override,
    ]
    if collections.has_ground_truth(source, target):
        command += [
            f"source_corr={collections.folder_of(source) / 'corres' / f'{source}.vts'}",
            f"target_corr={collections.folder_of(target) / 'corres' / f'{target}.vts'}",
        ]
    return command


def checked_row(run: dict, row: dict, run_dir: Path, time_limit: float, grace: float) -> dict:
    """The run's row with what the stress run checks: a documented exit, a final status, no hang."""
    result_path = run_dir / "result.json"
    result = json.loads(result_path.read_text()) if result_path.exists() else {}
    solve_s = (result.get("timings_s") or {}).get("solve")
    row = {
        "n": run["n"], "kind": run["kind"], "faces": run["faces"], "adapt": run["adapt"], **row,
        "solver_status": result.get("solver_status"), "verdict": (result.get("quality") or {}).get("verdict"),
        "message": (result.get("solver") or {}).get("message") or result.get("error"),
        "tours": _tours(result.get("curve_tours")),
    }  # fmt: skip
    row["documented_exit"] = row["exit_code"] in DOCUMENTED_EXIT_CODES
    row["final_status"] = row.get("status") in FINAL_STATUSES
    row["within_limit"] = solve_s is None or solve_s <= time_limit + grace
    row["certified"] = row.get("status") == "optimal"
    return row


def _tours(records: list[dict] | None) -> str | None:
    """``curve.tour=auto``: each tour tried as tour:status, the kept one starred (None otherwise)."""
    if not records:
        return None
    return "; ".join(f"{'*' if t['chosen'] else ''}{t['tour']}:{t['status']}" for t in records)


def _distribution(values: list[float]) -> dict:
    """Median, 90th percentile and maximum of ``values`` (None when empty)."""
    if not values:
        return {"median": None, "p90": None, "max": None}
    ordered = sorted(values)
    return {
        "median": round(statistics.median(ordered), 2),
        "p90": round(ordered[min(len(ordered) - 1, int(0.9 * len(ordered)))], 2),
        "max": round(ordered[-1], 2),
    }


def summary_of(rows: list[dict], key) -> dict:
    """Per group (``key(row)``): runs, certified share, failed checks, time distributions, errors."""
    groups: dict = {}
    for row in rows:
        groups.setdefault(key(row), []).append(row)
    summary = {}
    for name, members in sorted(groups.items(), key=lambda item: str(item[0])):
        errors = [row["dense_error"] for row in members if row.get("dense_error") is not None]
        summary[str(name)] = {
            "runs": len(members),
            "certified": sum(row["certified"] for row in members),
            "certified_share": round(sum(row["certified"] for row in members) / len(members), 3),
            "statuses": dict(sorted(_count(row.get("status") for row in members).items())),
            "exit_codes": dict(sorted(_count(str(row["exit_code"]) for row in members).items())),
            "undocumented_exits": sum(not row["documented_exit"] for row in members),
            "not_final": sum(not row["final_status"] for row in members),
            "past_limit_and_grace": sum(not row["within_limit"] for row in members),
            "solve_s": _distribution([row["solve_s"] for row in members if row.get("solve_s") is not None]),
            "process_s": _distribution([row["process_s"] for row in members]),
            "peak_mib": _distribution([row["peak_mib"] for row in members]),
            "dense_error_mean": round(statistics.mean(errors), 4) if errors else None,
        }
    return summary


def summaries_of(rows: list[dict]) -> dict:
    """The summaries by configuration, by kind of pair, and over all rows."""
    return {
        "by_configuration": summary_of(rows, lambda row: f"{row['faces']} faces, adapt {row['adapt']}"),
        "by_kind": summary_of(rows, lambda row: row["kind"]),
        "all": summary_of(rows, lambda row: "all")["all"],
    }


def _count(values) -> dict:
    counts: dict = {}
    for value in values:
        counts[str(value)] = counts.get(str(value), 0) + 1
    return counts


def main(argv: list[str] | None = None) -> None:
    """Run every drawn pair as one ``spidermatch-match`` process and write rows and summaries."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--faust", type=Path, required=True, help="FAUST_r-style folder (off/, corres/)")
    parser.add_argument("--tosca", type=Path, required=True, help="TOSCA_animals-style folder")
    parser.add_argument("--faust-checkpoint", required=True, help="label-free network for two humans")
    parser.add_argument("--tosca-checkpoint", required=True, help="label-free network for pairs with animals")
    parser.add_argument("--pairs", type=int, default=100)
    parser.add_argument("--faces", nargs="+", type=int, default=[500, 1000])
    parser.add_argument("--adapt-steps", nargs="+", type=int, default=[0, 20])
    parser.add_argument("--time-limit", type=float, default=60.0, help="solver.time_limit of every run")
    parser.add_argument(
        "--grace", type=float, default=10.0, help="seconds past the limit that count as a hang"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--runs", default=None, help="FIRST:STOP: only these of the drawn runs (e.g. one share per core)"
    )
    parser.add_argument(
        "--indices", nargs="+", type=int, default=None, help="only these of the drawn runs (after --runs)"
    )
    parser.add_argument(
        "--override", nargs="+", default=[], help="further spidermatch-match options, e.g. curve.tour=auto"
    )
    parser.add_argument(
        "--combine", nargs="+", type=Path, default=None, help="write --out from these outputs' rows instead"
    )
    parser.add_argument("--out", default="bench/results/stress_faust_tosca_500_1000.json")
    args = parser.parse_args(argv)
    if args.combine:
        rows = sorted(
            (row for path in args.combine for row in json.loads(path.read_text())["rows"]),
            key=lambda r: r["n"],
        )
        write_rows(
            Path(args.out), rows, {"summary": summaries_of(rows), "combined": [str(p) for p in args.combine]}
        )
        print(json.dumps(summaries_of(rows)["all"], indent=2))
        return
    collections = Collections(args.faust, args.tosca)
    configurations = list(itertools.product(args.faces, args.adapt_steps))
    runs = draw_runs(collections, args.pairs, configurations, args.seed)
    if args.runs:
        first, stop = (int(part) for part in args.runs.split(":"))
        runs = runs[first:stop]
    if args.indices:
        runs = [run for run in runs if run["n"] in set(args.indices)]
    out, rows = Path(args.out), []
    out.parent.mkdir(parents=True, exist_ok=True)
    print(" | ".join(COLUMNS), flush=True)
    with tempfile.TemporaryDirectory(prefix="bench_stress_") as work:
        for run in runs:
            run_dir = Path(work) / f"{run['n']:03d}_{run['source']}__{run['target']}"
            command = stress_command(args, collections, run, run_dir)
            code, wall, peak = run_process(command, Path(work) / f"{run['n']:03d}.log")
            row = pair_row(f"{run['source']}:{run['target']}", code, wall, peak, run_dir)
            rows.append(checked_row(run, row, run_dir, args.time_limit, args.grace))
            print(format_row(rows[-1], COLUMNS, 4), flush=True)
            write_rows(
                out, rows, {"summary": summaries_of(rows)}
            )  # after every run: a stopped run keeps its rows
    print(json.dumps(summaries_of(rows)["all"], indent=2))
    print(f"wrote {out} and {out.with_suffix('.csv')}")


if __name__ == "__main__":
    main()
