"""Time and peak memory of the closest-point search the dense stage runs on large scans.

The dense map projects every source vertex onto the target several times
(:func:`spidermatch.geometry.surface.closest_triangle_points`); on a raw scan that is hundreds
of thousands of points, each with tens of candidate faces. For each point count, points near
the mesh's surface (its vertices repeated and moved by a centimetre-scale noise) are projected
onto it in a fresh process, which reports the search's time and its peak memory above what the
process held before (``ru_maxrss``)::

    .venv/bin/python bench/bench_closest_points.py --mesh ../shared/data/FAUST_r/off/tr_reg_000.off \\
        --points 20000 80000 320000 --out bench/results/closest_points_faust_scan_sizes.json

Without ``--mesh`` a synthetic creature is used. Writes the rows as JSON (and CSV).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_scaling import write_rows  # noqa: E402

NOISE = 0.01  # of the mesh's sqrt(area): points near the surface, as a fitted dense map's are


def load(mesh_path: str | None):
    """The mesh to project onto: a file, or a synthetic creature of 5000 vertices."""
    if mesh_path is not None:
        from spidermatch.geometry.io import load_mesh

        return load_mesh(mesh_path)
    from spidermatch.data.datasets import SyntheticShapes

    shapes = SyntheticShapes(n_shapes=1, n_verts=5000)
    return shapes.load(shapes.names[0]).mesh


def measure(task: tuple[str | None, int, int]) -> dict:
    """Project ``n_points`` points onto the mesh in this (fresh) process: seconds and MiB above the start."""
    from spidermatch.geometry.surface import closest_surface_points

    mesh_path, n_points, seed = task
    mesh = load(mesh_path)
    rng = np.random.default_rng(seed)
    picked = rng.integers(0, mesh.n_verts, n_points)
    points = mesh.verts[picked] + rng.normal(scale=NOISE * np.sqrt(mesh.area), size=(n_points, 3))
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    started = time.perf_counter()
    face, _ = closest_surface_points(mesh, points)
    seconds = time.perf_counter() - started
    rise = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    return {
        "mesh": mesh_path or "synthetic creature",
        "mesh_vertices": mesh.n_verts,
        "points": n_points,
        "seconds": round(seconds, 2),
        "peak_rise_mib": round(rise, 1),
        "faces_found": int(np.unique(face).size),
    }


def main(argv: list[str] | None = None) -> None:
    """Measure every point count in its own process and write the rows."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--mesh", default=None, help="a mesh file (default: a synthetic creature)")
    parser.add_argument("--points", nargs="+", type=int, default=[20000, 80000, 320000])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="bench/results/closest_points.json")
    args = parser.parse_args(argv)
    rows = []
    context = mp.get_context("spawn")
    for n_points in args.points:
        with context.Pool(1) as pool:
            row = pool.apply(measure, ((args.mesh, n_points, args.seed),))
        rows.append(row)
        print(
            f"{row['points']:>8} points on {row['mesh_vertices']} vertices: {row['seconds']:.2f} s, "
            f"peak +{row['peak_rise_mib']:.0f} MiB",
            flush=True,
        )
        write_rows(Path(args.out), rows)
    print(f"wrote {args.out} and {Path(args.out).with_suffix('.csv')}")


if __name__ == "__main__":
    main()
