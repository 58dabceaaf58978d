"""Calibration of the quality verdict (spidermatch/eval/quality.py) against ground truth.

Runs ``spidermatch-eval`` on seeded random ordered pairs of each collection (resuming finished
pairs), then reads every pair's ``result.json``: the verdict's figures (computed without ground
truth, judged again with the current thresholds of ``spidermatch.eval.quality.judge``) beside the
mean geodesic error (with it). A matching is *bad* when its dense map's mean error
exceeds ``--bad-error`` (0.1 of sqrt(area): a mirrored or misplaced body part; correct maps
on FAUST_r are near 0.03). Prints and writes the confusion table of "suspect" against "bad"
per collection and overall, and the same table for other thresholds of the mirror figure, alone
and confirmed by the dense map's (``dense_mirror``).

Example (WKS on FAUST_r humans at 500 faces, TOSCA animals with a label-free TOSCA checkpoint
at 1000 faces, FAUST_r humans with that checkpoint):

    .venv/bin/python bench/bench_quality.py \
        --collection faust_wks:../shared/data/FAUST_r:25:any:500 \
        --collection tosca_learned:../shared/data/TOSCA_animals:15:class:1000:CHECKPOINT \
        --out bench/results/quality_verdict_calibration

A collection is NAME:DATA:N_PAIRS:any|class|FIRST..LAST:RESOLUTION[:CHECKPOINT] (``class``: both
shapes of a pair from one class, the name's letters before its number, as TOSCA's ground truth
needs; ``FIRST..LAST``: shapes named in that range only, e.g. ``tr_reg_070..tr_reg_079``, the
FAUST_r shapes the label-free recipe does not train on).
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from bench_scaling import write_rows  # noqa: E402

sys.path.insert(0, str(ROOT))
from spidermatch.eval.quality import DISTORTION_SUSPECT, MIRROR_SUSPECT, judge  # noqa: E402


def pair_list(data: Path, n_pairs: int, within: str, seed: int) -> list[tuple[str, str]]:
    """``n_pairs`` seeded random ordered pairs of distinct shapes.

    ``within``: ``any``; ``class`` (of one class); ``FIRST..LAST`` (names in that range, e.g. the
    shapes a network was not trained on).
    """
    names = sorted(path.stem for path in (data / "off").glob("*.off"))
    if ".." in within:
        first, last = within.split("..")
        names, within = [name for name in names if first <= name <= last], "any"
    kind = {name: re.sub(r"\d+$", "", name) for name in names}
    candidates = [(a, b) for a in names for b in names if a != b and (within == "any" or kind[a] == kind[b])]
    order = np.random.default_rng(seed).permutation(len(candidates))[:n_pairs]
    return [candidates[i] for i in order]


def run_collection(spec: str, work: Path, seed: int, time_limit: float) -> list[dict]:
    name, data, n_pairs, within, resolution, *checkpoint = spec.split(":")
    data = Path(data)
    pairs = pair_list(data, int(n_pairs), within, seed)
    pairs_file = work / f"{name}_pairs.txt"
    pairs_file.write_text("".join(f"{a} {b}\n" for a, b in pairs))
    run_dir = work / name
    command = [
        str(Path(sys.executable).parent / "spidermatch-eval"),
        f"dataset={data}",
        f"pairs_file={pairs_file}",
        f"resolution={resolution}",
        f"name={name}",
        f"hydra.run.dir={run_dir}",
        f"solver.time_limit={time_limit}",
        *(["features=learned", f"checkpoint={checkpoint[0]}"] if checkpoint else []),
    ]
    with open(work / f"{name}.log", "w") as log:
        subprocess.run(command, stdout=log, stderr=subprocess.STDOUT, check=False)
    found = [row for row in map(read_pair, sorted((run_dir / "pairs").glob("*/result.json"))) if row]
    return [{"collection": name, **row} for row in found]


def read_pair(path: Path) -> dict | None:
    """Verdict, figures and errors of one pair's result.json (None without a matching)."""
    report = json.loads(path.read_text())
    quality = report.get("quality")
    if not quality:
        return None
    dense_figures = (report.get("dense") or {}).get("dense") or {}
    dense = dense_figures.get("geodesic_error")
    return {
        "pair": path.parent.name,
        "status": report.get("status"),
        "verdict": quality["verdict"],
        "mirror": quality.get("mirror", quality["flipped"] / max(1.0 - quality["degenerate"], 1e-12)),
        "flipped": quality["flipped"],
        "degenerate": quality["degenerate"],
        "distinct": quality["distinct"],
        "gap": quality["gap"],
        "distortion": quality.get("distortion"),  # None in a result.json written before the figure existed
        "distortion_judged": quality.get("distortion_judged", True),
        "sparse_error": (report.get("geodesic_error") or {}).get("mean"),
        "dense_error": dense,
        # the verdict's own dense figures; the mirror one from the dense report for older runs
        "dense_mirror": quality.get("dense_mirror", mirror_from_dense_report(dense_figures)),
        "dense_distortion": quality.get("dense_distortion"),
        "reasons": "; ".join(quality["reasons"]),
    }


def mirror_from_dense_report(figures: dict) -> float | None:
    """``dense_mirror`` from a dense report's ``flipped`` and ``degenerate`` (None without a dense map)."""
    if "flipped" not in figures:
        return None
    return round(figures["flipped"] / max(1.0 - figures.get("degenerate", 0.0), 1e-12), 4)


def confusion(rows: list[dict], bad_error: float, suspect=lambda row: row["verdict"] == "suspect") -> dict:
    """Counts of suspect/plausible against bad/good, with precision and recall of 'suspect'."""
    bad = [
        (row["dense_error"] if row["dense_error"] is not None else row["sparse_error"]) > bad_error
        for row in rows
    ]
    flagged = [suspect(row) for row in rows]
    tp = sum(b and f for b, f in zip(bad, flagged))
    fp = sum(f and not b for b, f in zip(bad, flagged))
    fn = sum(b and not f for b, f in zip(bad, flagged))
    tn = len(rows) - tp - fp - fn
    return {
        "pairs": len(rows),
        "bad": tp + fn,
        "suspect_and_bad": tp,
        "suspect_but_good": fp,
        "plausible_but_bad": fn,
        "plausible_and_good": tn,
        "precision": round(tp / (tp + fp), 3) if tp + fp else None,
        "recall": round(tp / (tp + fn), 3) if tp + fn else None,
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--collection", action="append", required=True)
    parser.add_argument("--bad-error", type=float, default=0.1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--time-limit", type=float, default=120.0)
    parser.add_argument("--work", default=None)
    parser.add_argument("--out", default=str(ROOT / "bench" / "results" / "quality_verdict_calibration"))
    args = parser.parse_args()
    work = Path(args.work or tempfile.mkdtemp(prefix="quality_"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for spec in args.collection:
        found = run_collection(spec, work, args.seed, args.time_limit)
        print(f"{spec}: {len(found)} pairs with a matching", flush=True)
        rows += found
    for row in rows:  # judged by the current thresholds from the stored figures
        row.update(judge(row), reasons="; ".join(judge(row)["reasons"]))
    tables = {
        name: confusion([r for r in rows if r["collection"] == name], args.bad_error)
        for name in dict.fromkeys(row["collection"] for row in rows)
    }
    tables["all"] = confusion(rows, args.bad_error)
    sweep = {
        f"mirror>{threshold}": confusion(rows, args.bad_error, lambda row, t=threshold: row["mirror"] > t)
        for threshold in (0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5)
    }
    with_dense = [row for row in rows if row.get("dense_mirror") is not None]
    sweep.update(
        {  # the mirror figure confirmed by the dense map's (spidermatch.eval.quality.judge)
            f"mirror>{MIRROR_SUSPECT} and dense_mirror>{threshold}": confusion(
                with_dense,
                args.bad_error,
                lambda row, t=threshold: row["mirror"] > MIRROR_SUSPECT and row["dense_mirror"] > t,
            )
            for threshold in (0.1, 0.15, 0.2, 0.25, 0.3)
        }
    )
    sweep.update(
        {
            f"distinct<{threshold}": confusion(
                rows, args.bad_error, lambda row, t=threshold: row["distinct"] < t
            )
            for threshold in (0.4, 0.5, 0.6)
        }
    )
    measured = [row for row in rows if row["distortion"] is not None]
    if measured:  # around the verdict's threshold
        sweep.update(
            {
                f"distortion>{threshold}": confusion(
                    measured, args.bad_error, lambda row, t=threshold: row["distortion"] > t
                )
                for threshold in sorted({0.04, 0.05, DISTORTION_SUSPECT, 0.08, 0.12})
            }
        )
    print(json.dumps({"confusion": tables, "mirror_threshold_sweep": sweep}, indent=2))
    write_rows(
        Path(args.out).with_suffix(".json"), rows, {"confusion": tables, "mirror_threshold_sweep": sweep}
    )


if __name__ == "__main__":
    main()
