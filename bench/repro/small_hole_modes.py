"""A source with one hole: matched as a whole shape or in the partial mode? (a probe, not part of the product)

``SMALL_HOLE_SHARE`` (spidermatch/geometry/mesh.py) decides when a boundary loop is a scanner's
small hole (the pair is matched as two whole shapes) rather than a cut (the partial mode). This
probe cuts one hole of 2-6 rings of faces around a seeded random vertex of the source, matches
it to the target in both modes through the API (the threshold set to 1 for the whole mode, to 0
for the partial mode) and prints, per hole, the share of the area removed, the share its loop
spans, the status, the mean geodesic dense error over the source's surviving reference points
(target's sqrt(area)) and the time. The source must have the smaller area (the partial mode
refuses a "part" larger than its whole); of a hole that leaves an island only the largest piece is kept.

    python bench/repro/small_hole_modes.py --data ../shared/data/FAUST_r \
        --checkpoint ../runs/faust_unsup_seed0/best.pt --pair tr_reg_071:tr_reg_070 --seed 1
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import spidermatch
import spidermatch.geometry.mesh as mesh_module
from spidermatch.data.datasets import ShapeFolder
from spidermatch.eval.errors import pointwise_geodesic_errors
from spidermatch.geometry.mesh import Mesh, loop_spans
from spidermatch.geometry.partial import edge_adjacency, kept_part


def holed(mesh: Mesh, centre: int, rings: int) -> tuple[Mesh, np.ndarray, float]:
    """``mesh`` without the faces whose corners all lie within ``rings`` rings of ``centre``.

    Returns its largest clean piece, the original index of each of its vertices and the removed
    share of the area.
    """
    inside = np.zeros(mesh.n_verts, dtype=bool)
    inside[centre] = True
    adjacency = edge_adjacency(mesh)
    for _ in range(rings):
        inside |= adjacency @ inside.astype(float) > 0
    part = kept_part(mesh, ~inside[mesh.faces].all(axis=1), f"{mesh.name} holed", "hole")
    return part.mesh, part.to_original, 1.0 - part.kept_area


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True)
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--pair", required=True, help="SOURCE:TARGET, the source the smaller")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rings", type=int, nargs="*", default=[2, 3, 4, 5, 6])
    args = parser.parse_args()
    from features.learned import LearnedExtractor

    extractor = LearnedExtractor(args.checkpoint)
    folder = ShapeFolder(args.data)
    source, target = (folder.load(name) for name in args.pair.split(":"))
    rng = np.random.default_rng(args.seed)
    for rings in args.rings:
        centre = int(rng.integers(source.mesh.n_verts))
        hole, used, removed = holed(source.mesh, centre, rings)
        index = -np.ones(source.mesh.n_verts, dtype=np.int64)
        index[used] = np.arange(used.size)
        kept = index[source.corr] >= 0
        span = float(loop_spans(hole.verts, hole.faces).max() / hole.area)
        for mode, share in (("whole", 1.0), ("partial", 0.0)):
            mesh_module.SMALL_HOLE_SHARE = share
            started = time.perf_counter()
            result = spidermatch.match(hole, target.mesh, features=extractor, resolution=1000, time_limit=120)
            images = result.dense_map[index[source.corr[kept]]]
            error = pointwise_geodesic_errors(target.mesh, images, target.corr[kept]).mean()
            row = {
                "pair": args.pair, "centre": centre, "rings": rings, "removed": round(removed, 4),
                "span": round(span, 4), "mode": mode, "status": result.status,
                "dense_error": round(float(error), 4), "seconds": round(time.perf_counter() - started, 1),
            }  # fmt: skip
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
