"""Cut shapes of a FAUST_r-style dataset into partial ones with exact ground truth.

For every listed shape and every cut kind (plane cuts, geodesic holes, single views from a
random camera; :mod:`spidermatch.geometry.partial`) one partial copy keeping 30-70 % of the area
(``--keep``) is written, from a fixed seed so that the figures built on them repeat::

    python bench/make_partial.py --data ../shared/data/FAUST_r --shapes tr_reg_070..tr_reg_079 \\
        --out runs/partial_faust

Large parts, as a scan with the feet cut off by the floor or a few holes (a single view never
keeps that much)::

    python bench/make_partial.py --data ../shared/data/FAUST_r --shapes tr_reg_070..tr_reg_079 \\
        --kinds plane holes --keep 0.7 0.95 --out runs/partial_faust_large

The output folder holds ``off/<shape>-<kind>.off`` (the part), ``maps/<shape>-<kind>.npy``
(the original vertex of every kept vertex: the exact ground truth) and ``partial.json``
(per part: its shape, kind, kept area and vertex count). Ground truth against other shapes
goes through the original's ``corres/<shape>.vts``.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import zlib
from pathlib import Path

import numpy as np

from spidermatch.data.datasets import ShapeFolder
from spidermatch.geometry.io import save_mesh
from spidermatch.geometry.partial import CUT_KINDS, random_cut

logger = logging.getLogger("bench.make_partial")


def shape_names(folder: ShapeFolder, spec: str) -> list[str]:
    """Names from ``first..last`` (inclusive, over the sorted names) or a comma list."""
    names = sorted(folder.names)
    if ".." in spec:
        first, last = spec.split("..")
        return names[names.index(first) : names.index(last) + 1]
    return spec.split(",")


def write_parts(
    folder: ShapeFolder,
    names: list[str],
    kinds: list[str],
    out: Path,
    seed: int,
    keep: tuple[float, float] = (0.3, 0.7),
) -> list[dict]:
    """Write one partial copy of every shape per kind; returns the manifest rows."""
    (out / "off").mkdir(parents=True, exist_ok=True)
    (out / "maps").mkdir(parents=True, exist_ok=True)
    rows = []
    for name in names:
        mesh = folder.load(name).mesh
        for kind in kinds:
            rng = np.random.default_rng([seed, zlib.crc32(f"{name}-{kind}".encode())])
            part = random_cut(mesh, kind, rng, keep, name=f"{name}-{kind}")
            save_mesh(part.mesh, out / "off" / f"{name}-{kind}.off")
            np.save(out / "maps" / f"{name}-{kind}.npy", part.to_original)
            row = {
                "part": f"{name}-{kind}",
                "shape": name,
                "kind": kind,
                "kept_area": round(part.kept_area, 4),
                "vertices": part.mesh.n_verts,
            }
            logger.info("%s", row)
            rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="a FAUST_r-style folder (off/, corres/)")
    parser.add_argument("--shapes", required=True, help="first..last or a comma list of shape names")
    parser.add_argument("--kinds", nargs="+", default=list(CUT_KINDS), choices=CUT_KINDS)
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--keep", type=float, nargs=2, default=(0.3, 0.7), metavar=("LOW", "HIGH"), help="kept area share"
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    folder = ShapeFolder(args.data)
    names = shape_names(folder, args.shapes)
    rows = write_parts(folder, names, args.kinds, args.out, args.seed, tuple(args.keep))
    manifest = {"data": args.data, "seed": args.seed, "keep": list(args.keep), "parts": rows}
    (args.out / "partial.json").write_text(json.dumps(manifest, indent=2) + "\n")
    print(f"wrote {len(rows)} partial shapes to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
