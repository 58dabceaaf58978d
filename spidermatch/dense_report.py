"""Files and figures of a dense map: ``dense_matches.csv``, ``dense_map.npz`` and the result.json entry.

``dense_map.npz`` holds, for the V_X vertices of the original source mesh:

=========  ==============  ======================================================
key        shape, dtype    content
=========  ==============  ======================================================
``vertex`` (V_X,) int64    target vertex (0-based) of each source vertex
``face``   (V_X,) int64    target face (0-based row of the target's face list)
``bary``   (V_X, 3) float  barycentric coordinates of the image point in ``face``
``method`` () str          the densification method
=========  ==============  ======================================================
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import numpy as np

from spidermatch.dense import DenseMap, feature_nearest_neighbours
from spidermatch.guard import atomic_path
from spidermatch.mesh import Mesh
from spidermatch.metrics import (
    consistency,
    geodesic_errors,
    sampled_faces,
    scored_face_count,
    vertex_map_consistency,
)

logger = logging.getLogger(__name__)


def write_dense_outputs(output_dir: Path, dense: DenseMap) -> tuple[Path, Path]:
    """Write ``dense_matches.csv`` (``source_vertex,target_vertex``, a row per source vertex) and the npz."""
    csv_path, npz_path = output_dir / "dense_matches.csv", output_dir / "dense_map.npz"
    rows = np.stack([np.arange(dense.vertex.size), dense.vertex], axis=1)
    with atomic_path(csv_path) as tmp:
        np.savetxt(tmp, rows, fmt="%d", delimiter=",", header="source_vertex,target_vertex", comments="")
    with atomic_path(npz_path) as tmp:
        overlap = {} if dense.covered is None else {"target_covered": dense.covered}
        np.savez(
            tmp,
            vertex=dense.vertex,
            face=dense.face,
            bary=dense.bary,
            method=np.array(dense.method),
            **overlap,
        )
    return csv_path, npz_path


def read_dense_map(path: str | os.PathLike) -> DenseMap:
    """Load a ``dense_map.npz`` written by :func:`write_dense_outputs`."""
    with np.load(path) as data:
        covered = data["target_covered"] if "target_covered" in data else None
        return DenseMap(data["vertex"], data["face"], data["bary"], str(data["method"]), covered)


NEAREST_NEIGHBOUR_PRODUCTS = 8e10
"""Multiply-adds the features' nearest-neighbour map may cost (queries x V_Y x D; a few seconds)."""


def nearest_neighbour_faces(n_target: int, n_features: int) -> int:
    """Source faces whose features' nearest neighbours fit :data:`NEAREST_NEIGHBOUR_PRODUCTS` (>= 500)."""
    queries = NEAREST_NEIGHBOUR_PRODUCTS / max(n_target * n_features, 1)
    return max(int(queries // 3), 500)  # a sparse sample of faces has about three vertices each


def dense_figures(
    dense: DenseMap,
    source: Mesh,
    target: Mesh,
    source_features: np.ndarray,
    target_features: np.ndarray,
    source_corr: np.ndarray | None = None,
    target_corr: np.ndarray | None = None,
) -> tuple[dict, np.ndarray | None]:
    """Consistency (and, with ground truth, error) of the dense map and of the features' nearest neighbours.

    Parameters
    ----------
    dense : DenseMap
    source, target : Mesh
        The full-resolution meshes (V_X, V_Y vertices).
    source_features, target_features : np.ndarray, shapes (V_X, D), (V_Y, D)
    source_corr, target_corr : np.ndarray, shape (K,), optional
        Reference points for the dense Princeton protocol.

    Returns
    -------
    figures : dict
        ``{"method", "dense": {tears, flips, flipped, degenerate[, geodesic_error]},
        "nearest_neighbour": {...}, "scored_faces": {dense, nearest_neighbour}, "metrics_time_s"}``,
        JSON-ready. A large source is scored on a fixed sample of its faces
        (:func:`~spidermatch.metrics.scored_face_count`: fewer against larger targets), and
        the features' map on as many as :func:`nearest_neighbour_faces` allows, so that the
        figures never cost more than the match.
    errors : np.ndarray, shape (K,), or None
        The dense map's error at each reference point (with ground truth).

    """
    start = time.perf_counter()
    faces = sampled_faces(source, scored_face_count(target.n_verts))
    nn_faces = sampled_faces(source, nearest_neighbour_faces(target.n_verts, np.shape(target_features)[1]))
    scored = np.arange(source.n_verts) if nn_faces is None else np.unique(source.faces[nn_faces])
    if source_corr is not None:
        scored = np.union1d(scored, source_corr)
    nearest = np.zeros(source.n_verts, dtype=np.int64)  # the features' map, where it is scored
    nearest[scored] = feature_nearest_neighbours(np.asarray(source_features)[scored], target_features)
    figures = {
        "method": dense.method,
        "dense": consistency(source, target, dense.points(target), dense.face, dense.bary, faces).as_dict(),
        "nearest_neighbour": vertex_map_consistency(source, target, nearest, nn_faces).as_dict(),
        "scored_faces": {
            "dense": source.n_faces if faces is None else int(faces.size),
            "nearest_neighbour": source.n_faces if nn_faces is None else int(nn_faces.size),
        },
    }
    errors = None
    if source_corr is not None and target_corr is not None:
        maps = {"dense": dense.vertex, "nearest_neighbour": nearest}
        per_map = geodesic_errors(maps, source_corr, target_corr, target)
        for name, values in per_map.items():
            figures[name]["geodesic_error"] = float(values.mean())
        errors = per_map["dense"]
    figures["metrics_time_s"] = round(time.perf_counter() - start, 3)
    logger.info(
        "dense map (%s): tears %.4f, flips %.4f%s; features' nearest neighbours: tears %.4f, flips %.4f%s",
        dense.method,
        figures["dense"]["tears"],
        figures["dense"]["flips"],
        _error_text(figures["dense"]),
        figures["nearest_neighbour"]["tears"],
        figures["nearest_neighbour"]["flips"],
        _error_text(figures["nearest_neighbour"]),
    )
    return figures, errors


def _error_text(figures: dict) -> str:
    return f", mean geodesic error {figures['geodesic_error']:.4f}" if "geodesic_error" in figures else ""
