"""Decimation to a target face count, with the map back to full-resolution vertices."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from spidermatch.geometry.mesh import Mesh, MeshError, make_mesh, triangle_areas

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Decimated:
    """A low-resolution mesh and where its vertices come from.

    Attributes
    ----------
    mesh : Mesh
        The decimated mesh, V_low vertices.
    to_full : np.ndarray, shape (V_low,), int64
        For each low-resolution vertex, the nearest vertex of the full-resolution mesh.

    """

    mesh: Mesh
    to_full: np.ndarray


DECIMATION_METHODS = ("shortest_edge", "qslim")


def decimate(mesh: Mesh, target_faces: int, method: str = "shortest_edge") -> Decimated:
    """Decimate ``mesh`` by manifold-preserving edge collapses to ``target_faces`` triangles.

    Uses libigl: ``shortest_edge`` collapses the shortest edge to its midpoint (as the
    SpiderMatch reference implementation does, giving even triangles); ``qslim``
    uses quadric error metrics (keeps detail, uneven triangles).

    Parameters
    ----------
    mesh : Mesh
        Full-resolution mesh (V, F).
    target_faces : int
        Wanted number of faces. A mesh that already has at most this many faces is
        returned unchanged with the identity map.

    Returns
    -------
    Decimated
        Low-resolution mesh and the (V_low,) map to the nearest full-resolution vertex.

    Raises
    ------
    MeshError
        If the decimated mesh is not a single manifold surface (too few faces for the shape).

    """
    if target_faces < 4:
        raise MeshError(f"{mesh.name}: cannot decimate to {target_faces} faces (need at least 4)")
    if mesh.n_faces <= target_faces:
        return Decimated(mesh, np.arange(mesh.n_verts, dtype=np.int64))
    if method not in DECIMATION_METHODS:
        raise ValueError(f"unknown decimation method {method!r}; choose from {DECIMATION_METHODS}")
    import igl

    collapse = igl.decimate if method == "shortest_edge" else igl.qslim
    verts, faces, _, _ = collapse(
        np.asfortranarray(mesh.verts, dtype=np.float64),
        np.asfortranarray(mesh.faces, dtype=np.int32),
        int(target_faces),
    )
    verts, faces = _drop_degenerate_and_unused(np.asarray(verts, np.float64), np.asarray(faces, np.int64))
    name = f"{mesh.name} (decimated to {target_faces} faces)"
    try:
        low = make_mesh(verts, faces, name)
    except MeshError as error:
        raise MeshError(f"{error}; try a higher resolution") from error
    logger.debug("decimated %s: %d -> %d faces", mesh.name, mesh.n_faces, low.n_faces)
    return Decimated(low, nearest_vertices(mesh.verts, low.verts))


def nearest_vertices(verts: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Index of the vertex (V, 3) nearest to each point (N, 3), ties to the lower index, (N,) int64.

    A vertex collapsed to an edge's midpoint is equally far from both ends: the tie is
    broken by index, not by rounding, so a turned or moved copy of a mesh gets the same map.
    """
    distance, index = cKDTree(verts).query(points, k=min(2, len(verts)))
    distance, index = distance.reshape(len(points), -1), index.reshape(len(points), -1)
    nearest = index[:, 0].astype(np.int64)
    if index.shape[1] == 2:
        tie = distance[:, 1] - distance[:, 0] <= 1e-9 * np.maximum(distance[:, 1], 1e-300)
        nearest[tie] = np.minimum(index[tie, 0], index[tie, 1])
    return nearest


def _drop_degenerate_and_unused(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Remove faces with repeated vertices or zero area, then vertices no face uses."""
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    extent = float(np.ptp(verts, axis=0).max()) or 1.0
    keep = ~repeated & (triangle_areas(verts, faces) > 1e-14 * extent**2)
    faces = faces[keep]
    used = np.unique(faces)
    new_index = np.full(len(verts), -1, dtype=np.int64)
    new_index[used] = np.arange(len(used))
    return verts[used], new_index[faces]
