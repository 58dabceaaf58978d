"""``spidermatch-collect DIR``: one table and one figure for all evaluation runs below DIR.

Finds every ``summary.json`` below DIR, prints one row per run (its settings, pairs,
failures, mean and median geodesic error, median solve time), writes ``DIR/collected.csv``
and draws all runs' cumulative error curves into ``DIR/curves.png``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from spidermatch.collect import COLUMNS, collect, save_collected_curves, write_collected


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
