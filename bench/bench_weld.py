"""Meshes written as triangle soups (a vertex per face corner, as STL stores them), welded back.

For every mesh of the given dataset folders: its soup is welded (:func:`spidermatch.geometry.weld.welded`)
and compared with the mesh itself. A row says whether the weld rebuilt the mesh exactly (one
welded vertex per vertex, the same faces), whether the welded mesh passes the loader's checks,
its topology, how many vertices the mesh has at a position another vertex shares (remeshed
self-contacts) and the weld's time. The mesh as given must not be welded at all (its
coincident vertices stay apart)::

    .venv/bin/python bench/bench_weld.py ../shared/data/FAUST_r ../shared/data/TOSCA_animals \\
        --out bench/results/weld_soups_faust_tosca.json

Writes the rows and a summary as JSON (and CSV).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_scaling import write_rows  # noqa: E402

from spidermatch.data.datasets import ShapeFolder  # noqa: E402
from spidermatch.geometry.io import load_mesh  # noqa: E402
from spidermatch.geometry.mesh import Mesh, MeshError, make_mesh, topology  # noqa: E402
from spidermatch.geometry.weld import welded  # noqa: E402


def soup_row(folder: str, name: str, mesh: Mesh) -> dict:
    """The weld of ``mesh``'s soup against ``mesh`` itself."""
    soup = Mesh(mesh.verts[mesh.faces].reshape(-1, 3), np.arange(3 * mesh.n_faces).reshape(-1, 3), name)
    started = time.perf_counter()
    weld = welded(soup)
    weld_s = time.perf_counter() - started
    pairs = np.unique(np.stack([mesh.faces.reshape(-1), weld.to_welded], axis=1), axis=0)
    exact = len(pairs) == mesh.n_verts == weld.mesh.n_verts
    shared = np.unique(mesh.verts, axis=0, return_inverse=True, return_counts=True)
    row = {
        "folder": Path(folder).name,
        "mesh": name,
        "vertices": mesh.n_verts,
        "coincident_vertices": int((shared[2][shared[1].reshape(-1)] > 1).sum()),
        "given_mesh_welded": welded(mesh) is not None,
        "rebuilt_exactly": bool(exact),
        "welded_vertices": weld.mesh.n_verts,
        "weld_s": round(weld_s, 3),
    }
    try:
        checked = make_mesh(weld.mesh.verts, weld.mesh.faces, name)
        row.update(valid=True, topology=str(topology(checked)))
    except MeshError as error:
        row.update(valid=False, topology=str(error))
    return row


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("folders", nargs="+")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    rows = []
    for folder in args.folders:
        shapes = ShapeFolder(folder)
        for name in shapes.names:
            rows.append(soup_row(folder, name, load_mesh(shapes.mesh_path(name))))
            print(json.dumps(rows[-1]), flush=True)
    summary = {
        "meshes": len(rows),
        "rebuilt_exactly": sum(row["rebuilt_exactly"] for row in rows),
        "valid": sum(row["valid"] for row in rows),
        "with_coincident_vertices": sum(row["coincident_vertices"] > 0 for row in rows),
        "given_meshes_welded": sum(row["given_mesh_welded"] for row in rows),
        "not_exact_topologies": sorted({row["topology"] for row in rows if not row["rebuilt_exactly"]}),
        "slowest_weld_s": max(row["weld_s"] for row in rows),
    }
    write_rows(args.out, rows, {"summary": summary})
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
