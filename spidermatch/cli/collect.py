"""``spidermatch-collect DIR``: the summaries of evaluation runs (e.g. a sweep) in one table and one figure.

Every ``summary.json`` below a folder becomes one row (the run's settings, pairs,
failures, mean and median geodesic error, median solve time), written to
``collected.csv``; all runs' cumulative error curves go into ``curves.png``. A sweep job that
ended without a summary (its ``.hydra/exit_code`` not 0: no meshes found, a bad option) gets a row
too; every row has the job's exit code, and the command exits with 1 after writing the table when a
job failed.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

from spidermatch.cli.batch import collect_errors
from spidermatch.cli.sweep import natural_key, recorded_code

COLUMNS = (
    "run",
    "folder",
    "features",
    "resolution",
    "strategy",
    "pairs",
    "finished",
    "failures",
    "mean_error",
    "median_error",
    "median_solve_s",
    "exit_code",
)


def run_overrides(run_dir: Path) -> list[str]:
    """The command-line overrides Hydra recorded for one run (empty if there are none)."""
    recorded = run_dir / ".hydra" / "overrides.yaml"
    if not recorded.is_file():
        return []
    from omegaconf import OmegaConf

    return [str(item) for item in OmegaConf.load(recorded)]


def run_labels(run_dirs: list[Path], root: Path) -> list[str]:
    """Name each run by the overrides that differ between the runs (the swept values).

    Falls back to the run's folder relative to ``root`` when nothing distinguishes it.
    """
    overrides = [run_overrides(run_dir) for run_dir in run_dirs]
    shared = set.intersection(*(set(items) for items in overrides)) if len(overrides) > 1 else set()
    labels = []
    for run_dir, items in zip(run_dirs, overrides):
        varying = [item for item in items if item not in shared]
        labels.append(",".join(varying) if varying else (str(run_dir.relative_to(root)) or "."))
    return labels


def failed_jobs(root: Path) -> list[Path]:
    """Eval sweep jobs below ``root`` that recorded a non-zero exit code and wrote no summary.

    A folder with a ``result.json`` is a match run's (a ``spidermatch-match -m`` job), not an eval's.
    """
    return [
        marker.parent
        for marker in root.rglob(".hydra")
        if not any((marker.parent / name).is_file() for name in ("summary.json", "result.json"))
        and recorded_code(marker.parent) not in (None, 0)
    ]


def collect(root: Path) -> list[dict]:
    """One row per ``summary.json`` below ``root`` and per failed job without one, in folder order."""
    run_dirs = {path.parent for path in root.rglob("summary.json")} | set(failed_jobs(root))
    run_dirs = sorted(run_dirs, key=lambda folder: natural_key(folder.relative_to(root)))
    labels = run_labels(run_dirs, root)
    rows = []
    for run_dir, label in zip(run_dirs, labels):
        if not (run_dir / "summary.json").is_file():
            row = dict.fromkeys(COLUMNS)
            row.update(run=label, folder=str(run_dir.relative_to(root)), exit_code=recorded_code(run_dir))
            rows.append(row)
            continue
        path = run_dir / "summary.json"
        summary = json.loads(path.read_text())
        settings = summary.get("settings", {})
        rows.append(
            {
                "run": label,
                "folder": str(path.parent.relative_to(root)) or ".",
                "features": settings.get("features"),
                "resolution": settings.get("resolution"),
                "strategy": settings.get("strategy"),
                "pairs": summary.get("pairs_planned"),
                "finished": summary.get("pairs_finished"),
                "failures": len(summary.get("failures", [])),
                "mean_error": summary["geodesic_error"]["mean"],
                "median_error": summary["geodesic_error"]["median"],
                "median_solve_s": summary["solve_s"]["median"],
                "exit_code": recorded_code(run_dir),
            }
        )
    return rows


def write_collected(root: Path, rows: list[dict]) -> Path:
    """Write ``rows`` (one per run, keys :data:`COLUMNS`) to ``root/collected.csv``."""
    path = root / "collected.csv"
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(COLUMNS))
        writer.writeheader()
        writer.writerows(rows)
    return path


def save_collected_curves(root: Path, rows: list[dict]) -> Path | None:
    """All runs' cumulative error curves in ``root/curves.png``; None if no run has errors."""
    from spidermatch.report.curves import save_error_curves

    runs = {r["run"]: collect_errors(root / r["folder"]) for r in rows if r["pairs"] is not None}
    runs = {label: errors for label, errors in runs.items() if errors.size}
    return save_error_curves(runs, root / "curves.png") if runs else None


def main(argv: list[str] | None = None) -> None:
    """Console entry point."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("root", type=Path, help="folder holding evaluation runs (searched recursively)")
    parser.add_argument("--no-plot", action="store_true", help="skip curves.png")
    args = parser.parse_args(argv)
    rows = collect(args.root)
    if not rows:
        matches = next(args.root.rglob("result.json"), None) is not None
        hint = " (it holds spidermatch-match runs; collect reads spidermatch-eval runs)" if matches else ""
        raise SystemExit(f"{args.root}: no summary.json found below this folder{hint}")
    print(" | ".join(COLUMNS))
    for row in rows:
        print(" | ".join(f"{row[c]:.4f}" if isinstance(row[c], float) else str(row[c]) for c in COLUMNS))
    print(f"wrote {write_collected(args.root, rows)}")
    if not args.no_plot:
        curves = save_collected_curves(args.root, rows)
        if curves is not None:
            print(f"wrote {curves}")
    failed = [row for row in rows if row["exit_code"] not in (None, 0)]
    if failed:
        names = ", ".join(
            f"{row['folder']} (exit {row['exit_code']}{'' if row['pairs'] is not None else ', no summary'})"
            for row in failed
        )
        raise SystemExit(f"{len(failed)} of {len(rows)} runs failed: {names}")


if __name__ == "__main__":
    main()
