"""Does the orientation search give a rotated copy of a shape the features of the shape itself?

For every shape, a network that reads coordinates is run through
:class:`features.learned.LearnedExtractor` on the shape as it is and on rotated copies (random
rotations, and lying on its back: 90 degrees about x), with the principal-axis alignments
(``orientation_frames``) on and off. A row gives the orientation the search chose, the
residual rotation between the copy as presented and the shape as presented (degrees; 0 means
the copy is seen exactly as the shape), and the mean cosine between the copy's and the
shape's per-vertex descriptors (1: identical features).

    .venv/bin/python bench/bench_orientation.py --data ../shared/data/FAUST_r \
        --checkpoint runs/faust_unsup_seed0/best.pt --shapes tr_reg_070..tr_reg_079 \
        --out bench/results/orientation_search_rotated_faust_val

Writes ``<out>.json`` and ``<out>.csv``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_scaling import write_rows  # noqa: E402

from spidermatch.data.datasets import open_dataset  # noqa: E402
from spidermatch.data.synthetic import random_rotation, rotation_angle  # noqa: E402
from spidermatch.geometry.io import load_mesh  # noqa: E402
from spidermatch.geometry.mesh import Mesh  # noqa: E402
from train.data import select_names  # noqa: E402

LYING = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # 90 degrees about x


def presented(extractor, mesh: Mesh) -> tuple[np.ndarray, np.ndarray, str]:
    """Descriptors (V, D), the rotation applied to the centred input (3, 3) and its description."""
    features = extractor(mesh.centred())
    chosen = extractor.orientations[mesh.name]
    return features, chosen.rotation.numpy(), chosen.describe()


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", required=True)
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--shapes", default="tr_reg_070..tr_reg_079")
    parser.add_argument("--random", type=int, default=2, help="random rotations per shape")
    parser.add_argument("--out", default=str(ROOT / "bench" / "results" / "orientation_search_rotated"))
    args = parser.parse_args()
    from features.learned import LearnedExtractor

    extractors = {
        frames: LearnedExtractor(args.checkpoint, orientation_frames=frames) for frames in (False, True)
    }
    dataset = open_dataset(args.data)
    spec = args.shapes if ".." in args.shapes else args.shapes.split(",")
    names = select_names(dataset.names, spec, "--shapes")
    rng = np.random.default_rng(0)
    rows = []
    for name in names:
        mesh = load_mesh(Path(args.data) / "off" / f"{name}.off")
        rotations = {"lying": LYING, **{f"random{i}": random_rotation(rng) for i in range(args.random)}}
        for frames, extractor in extractors.items():
            base, base_rotation, _ = presented(extractor, mesh)
            for label, rotation in {"as_is": np.eye(3), **rotations}.items():
                copy = Mesh(mesh.verts @ rotation.T, mesh.faces, name)
                features, chosen, description = presented(extractor, copy)
                # the copy's input is chosen @ rotation @ x; the shape's is base_rotation @ x
                residual = chosen @ rotation @ base_rotation.T
                row = {
                    "shape": name,
                    "frames": frames,
                    "copy": label,
                    "chosen": description,
                    "residual_degrees": round(rotation_angle(residual), 2),
                    "feature_cosine": round(float(np.mean(np.sum(features * base, axis=1))), 4),
                }
                print(json.dumps(row), flush=True)
                rows.append(row)
    summary = {}
    for frames in (False, True):
        for copy in ("as_is", "lying", "random"):
            mine = [r for r in rows if r["frames"] == frames and r["copy"].startswith(copy)]
            summary[f"frames={frames} {copy}"] = {
                "copies": len(mine),
                "seen_as_the_shape (residual < 20 deg)": sum(r["residual_degrees"] < 20 for r in mine),
                "mean_feature_cosine": round(float(np.mean([r["feature_cosine"] for r in mine])), 4),
            }
    write_rows(Path(args.out).with_suffix(".json"), rows, {"summary": summary})
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
