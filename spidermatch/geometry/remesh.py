"""Decimation to a target face count, with the map back to full-resolution vertices.

Each low-resolution vertex stands for the full-resolution vertices collapsed into it, and is
mapped to the full-resolution vertex nearest to it in space *among those near its birth
vertex along the surface*: edge collapses move the survivors to midpoints, off the surface,
and where two parts of a body touch (hands pressed together, a foot resting on a knee) the
vertex nearest in space can lie on the other part, which put the certified matches, the
features they read and the dense map's labels on the wrong part there.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from spidermatch.geometry.graph_distance import farther_than
from spidermatch.geometry.mesh import Mesh, MeshError, make_mesh, mean_incident_edge_length, triangle_areas

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Decimated:
    """A low-resolution mesh and where its vertices come from.

    Attributes
    ----------
    mesh : Mesh
        The decimated mesh, V_low vertices.
    to_full : np.ndarray, shape (V_low,), int64
        For each low-resolution vertex, the full-resolution vertex nearest to it on its own part
        of the surface (:func:`surface_nearest_vertices`).

    """

    mesh: Mesh
    to_full: np.ndarray


DECIMATION_METHODS = ("shortest_edge", "qslim")

BIRTH_REACH = 2.0
"""How far along the full mesh's edges, in the low-resolution vertex's mean edge lengths, its
full-resolution vertex may lie from the vertex it was born from."""

NEAREST_CANDIDATES = 8
"""Full-resolution vertices nearest in space that are tried, in order, for each low-resolution vertex."""


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
    verts, faces, _, births = collapse(
        np.asfortranarray(mesh.verts, dtype=np.float64),
        np.asfortranarray(mesh.faces, dtype=np.int32),
        int(target_faces),
    )
    verts, faces, kept = _drop_degenerate_and_unused(
        np.asarray(verts, np.float64), np.asarray(faces, np.int64)
    )
    name = f"{mesh.name} (decimated to {target_faces} faces)"
    try:
        low = make_mesh(verts, faces, name, outward=False)  # the decimation keeps the mesh's orientation
    except MeshError as error:
        raise MeshError(f"{error}; try a higher resolution") from error
    logger.debug("decimated %s: %d -> %d faces", mesh.name, mesh.n_faces, low.n_faces)
    reach = BIRTH_REACH * mean_incident_edge_length(low)
    births = np.asarray(births, dtype=np.int64)[kept]
    return Decimated(low, surface_nearest_vertices(mesh, low.verts, births, reach))


def surface_nearest_vertices(
    mesh: Mesh, points: np.ndarray, births: np.ndarray, reach: np.ndarray
) -> np.ndarray:
    """The vertex nearest to each point in space among those near its birth vertex along the edges.

    The first of the point's :data:`NEAREST_CANDIDATES` nearest vertices (ties to the lower
    index, as :func:`nearest_vertices`) that lies within ``reach`` of the birth vertex along the
    mesh's edges; the birth vertex itself when none does.

    Parameters
    ----------
    mesh : Mesh
        The full-resolution mesh (V vertices).
    points : np.ndarray, shape (N, 3)
        Low-resolution vertices.
    births : np.ndarray, shape (N,), int
        The vertex of ``mesh`` each point was born from (it was collapsed into the point).
    reach : np.ndarray, shape (N,)

    Returns
    -------
    np.ndarray, shape (N,), int64
    """
    chosen = np.asarray(births, dtype=np.int64).copy()
    candidates = _nearest_in_order(mesh.verts, points, NEAREST_CANDIDATES)
    open_ = np.arange(len(points))
    for column in candidates.T:
        near = ~farther_than(mesh, chosen[open_], column[open_], reach[open_])
        chosen[open_[near]] = column[open_[near]]
        open_ = open_[~near]
        if not open_.size:
            break
    return chosen


def nearest_vertices(verts: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Index of the vertex (V, 3) nearest to each point (N, 3), ties to the lower index, (N,) int64.

    A vertex collapsed to an edge's midpoint is equally far from both ends: the tie is
    broken by index, not by rounding, so a turned or moved copy of a mesh gets the same map.
    """
    return _nearest_in_order(verts, points, 2)[:, 0]


def _nearest_in_order(verts: np.ndarray, points: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` vertices nearest to each point, nearest first, shape (N, min(k, V)), int64.

    The first two swap places when they are equally far and the second has the lower index
    (:func:`nearest_vertices`' rule).
    """
    k = min(k, len(verts))
    distance, index = cKDTree(verts).query(points, k=k)
    distance, index = distance.reshape(len(points), k), index.reshape(len(points), k).astype(np.int64)
    if k >= 2:
        tie = distance[:, 1] - distance[:, 0] <= 1e-9 * np.maximum(distance[:, 1], 1e-300)
        swap = tie & (index[:, 1] < index[:, 0])
        index[swap, :2] = index[swap, 1::-1]
    return index


def _drop_degenerate_and_unused(
    verts: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Remove faces with repeated vertices or zero area, then vertices no face uses (``kept``: the rest)."""
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    extent = float(np.ptp(verts, axis=0).max()) or 1.0
    keep = ~repeated & (triangle_areas(verts, faces) > 1e-14 * extent**2)
    faces = faces[keep]
    used = np.unique(faces)
    new_index = np.full(len(verts), -1, dtype=np.int64)
    new_index[used] = np.arange(len(used))
    return verts[used], new_index[faces], used
