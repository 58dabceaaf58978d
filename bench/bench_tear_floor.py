"""How few tears a vertex map between two meshes can have, from their edge lengths alone.

The tear figure (:mod:`spidermatch.eval.metrics`) counts a source edge as torn when its two
images lie more than ``TEAR_THRESHOLD`` times sqrt(area) apart. On meshes with long edges
that counts edges no map can keep together: a source edge longer than the threshold tears
when it is mapped at its own length, and a target edge that long tears whenever a source
edge lands on its two ends. Per pair this prints the share of source edges above the
threshold (in the source's sqrt(area)) and the tears of the target's identity map onto
itself, scored by the same function as the dense maps (``vertex_map_consistency``)::

    .venv/bin/python bench/bench_tear_floor.py --data ../shared/data/TOSCA_animals \\
        --pairs cat5:cat0 cat0:cat5 dog5:dog0 dog0:dog5 horse5:horse0 horse0:horse5 \\
        --out bench/results/tear_floor_tosca_heldout.json

Writes ``<out>`` (JSON) and the same rows as CSV.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from bench_scaling import format_row, write_rows

from spidermatch.data.datasets import open_dataset
from spidermatch.eval.metrics import TEAR_THRESHOLD, vertex_map_consistency
from spidermatch.geometry.mesh import Mesh

COLUMNS = ("pair", "source_edges_above_threshold", "target_identity_tears", "target_longest_edge")


def unit_edge_lengths(mesh: Mesh) -> np.ndarray:
    """Length of every edge (E,) in the mesh's sqrt(area)."""
    return mesh.edge_lengths / np.sqrt(mesh.area)


def floor_row(text: str, source: Mesh, target: Mesh) -> dict:
    """The pair's figures (see the module docstring)."""
    identity = vertex_map_consistency(target, target, np.arange(target.n_verts))
    return {
        "pair": text,
        "source_edges_above_threshold": round(float(np.mean(unit_edge_lengths(source) > TEAR_THRESHOLD)), 4),
        "target_identity_tears": round(float(identity.tears), 4),
        "target_longest_edge": round(float(unit_edge_lengths(target).max()), 4),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True)
    parser.add_argument("--pairs", nargs="+", required=True, help="SOURCE:TARGET shape names")
    parser.add_argument("--out", required=True, type=Path)
    args = parser.parse_args(argv)
    dataset = open_dataset(args.data)
    print(" | ".join(COLUMNS), flush=True)
    rows = []
    for text in args.pairs:
        source, target = (dataset.load(name).mesh for name in text.split(":"))
        rows.append(floor_row(text, source, target))
        print(format_row(rows[-1], COLUMNS, 4), flush=True)
    write_rows(args.out, rows, {"tear_threshold": TEAR_THRESHOLD})
    return 0


if __name__ == "__main__":
    sys.exit(main())
