"""The quality verdict on pairs like the built-in demo: synthetic creatures at a few hundred faces.

Each pair is two generated creatures (seeds s and s + 1, 2000 vertices, exact ground truth),
matched through the Python API with WKS features at each resolution, as the built-in demo
(``spidermatch-match``, seeds 0 and 1, 200 faces) is. Per run: the status, the verdict and its
reasons, the figures of the certified low-resolution map (``mirror``, ``distortion``) beside those
of the dense map (``dense_mirror``, ``dense_distortion``), the verdict the certified map's figures
alone give (``verdict_low_res``, as before the dense map was consulted), and the dense map's
mean geodesic error over the reference points::

    .venv/bin/python bench/bench_synthetic_verdict.py --seeds 0 2 4 6 8 --faces 200 400 \\
        --out bench/results/quality_verdict_synthetic_wks_200_400.json

Prints one row per run and writes the rows as JSON and CSV.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT))

from bench_scaling import write_rows  # noqa: E402

from spidermatch import api  # noqa: E402
from spidermatch.data.datasets import SyntheticShapes  # noqa: E402
from spidermatch.eval.errors import pointwise_geodesic_errors  # noqa: E402
from spidermatch.eval.quality import judge  # noqa: E402

FIGURES = ("mirror", "dense_mirror", "distortion", "dense_distortion")


def creature(seed: int, n_verts: int):
    shapes = SyntheticShapes(n_shapes=1, n_verts=n_verts, seed=seed)
    return shapes.load(shapes.names[0])


def run_pair(seed: int, faces: int, n_verts: int) -> dict:
    """One synthetic pair (seed, seed + 1) matched with WKS at ``faces``: verdicts and figures."""
    source, target = creature(seed, n_verts), creature(seed + 1, n_verts)
    matching = api.match(source.mesh, target.mesh, features="wks", resolution=faces)
    row = {"pair": f"synthetic{seed}:{seed + 1}", "faces": faces, "status": matching.status}
    quality = matching.quality
    if quality is None:
        return row
    low_res = {key: value for key, value in quality.items() if not key.startswith("dense_")}
    row.update(
        verdict=quality["verdict"],
        verdict_low_res=judge(low_res)["verdict"],
        **{name: quality.get(name) for name in FIGURES},
        reasons="; ".join(quality["reasons"]),
    )
    if matching.dense_map is not None:
        errors = pointwise_geodesic_errors(target.mesh, matching.dense_map[source.corr], target.corr)
        row["dense_error"] = round(float(errors.mean()), 4)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 2, 4, 6, 8])
    parser.add_argument("--faces", nargs="+", type=int, default=[200, 400])
    parser.add_argument("--n-verts", type=int, default=2000, help="vertices of each creature (the demo's)")
    parser.add_argument("--out", required=True, type=Path)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    rows = []
    for faces in args.faces:
        for seed in args.seeds:
            rows.append(run_pair(seed, faces, args.n_verts))
            print(json.dumps(rows[-1]), flush=True)
    summary = {
        f"{faces} faces": {
            "runs": sum(row["faces"] == faces for row in rows),
            "suspect": sum(row["faces"] == faces and row.get("verdict") == "suspect" for row in rows),
            "suspect_low_res": sum(
                row["faces"] == faces and row.get("verdict_low_res") == "suspect" for row in rows
            ),
        }
        for faces in args.faces
    }
    print(json.dumps(summary, indent=2))
    write_rows(args.out.with_suffix(".json"), rows, {"summary": summary})


if __name__ == "__main__":
    main()
