"""``spidermatch-collect DIR``: the summaries of evaluation runs (e.g. a sweep) in one table and one figure.

Every ``summary.json`` below a folder becomes one row (the run's settings, pairs,
failures, mean and median geodesic error, median solve time), written to
``collected.csv``; all runs' cumulative error curves go into ``curves.png``.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

from spidermatch.cli.batch import collect_errors

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
)


def natural_key(relative: Path) -> list:
    """Sort key that puts sweep job folders 2 before 10."""
    return [int(part) if part.isdigit() else part for part in relative.parts]


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


def collect(root: Path) -> list[dict]:
    """One row per ``summary.json`` found below ``root``, in the order of the runs' folders."""
    paths = sorted(root.rglob("summary.json"), key=lambda p: natural_key(p.parent.relative_to(root)))
    labels = run_labels([path.parent for path in paths], root)
    rows = []
    for path, label in zip(paths, labels):
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

    runs = {r["run"]: collect_errors(root / r["folder"]) for r in rows}
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
        raise SystemExit(f"{args.root}: no summary.json found below this folder")
    print(" | ".join(COLUMNS))
    for row in rows:
        print(" | ".join(f"{row[c]:.4f}" if isinstance(row[c], float) else str(row[c]) for c in COLUMNS))
    print(f"wrote {write_collected(args.root, rows)}")
    if not args.no_plot:
        curves = save_collected_curves(args.root, rows)
        if curves is not None:
            print(f"wrote {curves}")


if __name__ == "__main__":
    main()
