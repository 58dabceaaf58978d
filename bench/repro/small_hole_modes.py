"""A source with one hole: matched as a whole shape or in the partial mode? (a probe, not part of the product)

``SMALL_HOLE_SHARE`` (spidermatch/geometry/mesh.py) decides when a boundary loop is a scanner's
small hole (the pair is matched as two whole shapes) rather than a cut (the partial mode). This
probe cuts one hole of 2-6 rings of faces around a seeded random vertex of the source, matches
it to the target in both modes through the API (for the whole mode the threshold set to 1 and
the alignment a hole needs, ``HOLE_ALIGNMENT``, to 0; for the partial mode the threshold to 0)
and prints, per hole, the share of the area removed, the share its loop spans, the status, the
mean geodesic dense error over the source's surviving reference points (target's sqrt(area)) and
the time. The source should have the smaller area (a "part" with more area than its whole is read
as a part of a larger body, ``MAX_PART_AREA_RATIO``); of a hole that leaves an island only the
largest piece is kept. ``--keep 0.9 0.8``
cuts the legs off instead (a horizontal plane keeping that share of the area: the feet at 0.9,
loops of about 0.5 % each, across the legs: a cut, so the partial mode by default), and
``--partial-checkpoint`` gives the partial mode its own network, as a user would.

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
from spidermatch.geometry.partial import edge_adjacency, kept_part, plane_cut


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


def feet_cut(mesh: Mesh, keep: float) -> tuple[Mesh, np.ndarray, float]:
    """``mesh`` cut by a horizontal plane keeping the top ``keep`` of its area (feet or lower legs off).

    Returns the part, the original index of each of its vertices and the removed share of the area.
    """
    part = plane_cut(mesh, np.array([0.0, -1.0, 0.0]), keep, f"{mesh.name} cut at the legs")
    return part.mesh, part.to_original, 1.0 - part.kept_area


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True)
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument(
        "--partial-checkpoint", default=None, help="the network of the partial mode (default: --checkpoint)"
    )
    parser.add_argument("--pair", required=True, help="SOURCE:TARGET, the source the smaller")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rings", type=int, nargs="*", default=[2, 3, 4, 5, 6])
    parser.add_argument(
        "--keep",
        type=float,
        nargs="*",
        default=None,
        help="instead of holes: the legs cut, keeping these shares",
    )
    parser.add_argument("--time-limit", type=float, default=120.0)
    args = parser.parse_args()
    from features.learned import LearnedExtractor

    extractors = {"whole": LearnedExtractor(args.checkpoint)}
    extractors["partial"] = (
        LearnedExtractor(args.partial_checkpoint) if args.partial_checkpoint else extractors["whole"]
    )
    folder = ShapeFolder(args.data)
    source, target = (folder.load(name) for name in args.pair.split(":"))
    rng = np.random.default_rng(args.seed)
    cuts = [("keep", keep) for keep in args.keep] if args.keep else [("rings", rings) for rings in args.rings]
    for kind, size in cuts:
        if kind == "keep":
            centre, (hole, used, removed) = None, feet_cut(source.mesh, size)
        else:
            centre = int(rng.integers(source.mesh.n_verts))
            hole, used, removed = holed(source.mesh, centre, size)
        index = -np.ones(source.mesh.n_verts, dtype=np.int64)
        index[used] = np.arange(used.size)
        kept = index[source.corr] >= 0
        span = float(loop_spans(hole.verts, hole.faces).max() / hole.area)
        for mode, share in (("whole", 1.0), ("partial", 0.0)):
            mesh_module.SMALL_HOLE_SHARE = share
            mesh_module.HOLE_ALIGNMENT = 0.0  # the whole mode takes a limb cut for a hole too
            started = time.perf_counter()
            result = spidermatch.match(
                hole, target.mesh, features=extractors[mode], resolution=1000, time_limit=args.time_limit
            )
            images = result.dense_map[index[source.corr[kept]]]
            error = pointwise_geodesic_errors(target.mesh, images, target.corr[kept]).mean()
            row = {
                "pair": args.pair, "centre": centre, kind: size, "removed": round(removed, 4),
                "span": round(span, 4), "mode": mode, "status": result.status,
                "dense_error": round(float(error), 4), "seconds": round(time.perf_counter() - started, 1),
            }  # fmt: skip
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
