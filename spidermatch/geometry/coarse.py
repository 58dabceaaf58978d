"""Where the vertices of a full-resolution mesh lie on its decimation, found along the surface.

Projecting a vertex onto the nearest low-resolution triangle in space goes wrong where
two parts of a body nearly touch (a hand on a hip, the thighs): the nearest triangle
may belong to the other part. Here every full-resolution vertex first gets the
low-resolution vertex nearest to it along the edges of the full mesh (its *label*),
and it may only land on low-resolution triangles around that vertex and its neighbours.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.remesh import Decimated
from spidermatch.geometry.surface import (
    closest_triangle_points,
    padded_rows,
    vertex_face_table,
    vertex_rings,
)


def coarse_labels(full: Mesh, low: Decimated) -> np.ndarray:
    """Low-resolution vertex nearest to each full-resolution vertex along the full mesh's edges.

    Returns
    -------
    np.ndarray, shape (V_full,), int64
        Index into ``low.mesh`` vertices; a vertex of another connected component
        than every low-resolution vertex gets the nearest one in space.

    """
    edges = full.edges
    length = np.linalg.norm(full.verts[edges[:, 0]] - full.verts[edges[:, 1]], axis=1)
    graph = sp.coo_matrix((np.maximum(length, 1e-12), (edges[:, 0], edges[:, 1])), (full.n_verts,) * 2)
    _, _, nearest_source = dijkstra(
        graph.tocsr(), directed=False, indices=np.unique(low.to_full), min_only=True, return_predecessors=True
    )
    low_of_full = np.full(full.n_verts, -1, dtype=np.int64)
    low_of_full[low.to_full] = np.arange(len(low.to_full))
    labels = np.where(nearest_source >= 0, low_of_full[np.maximum(nearest_source, 0)], -1)
    unreached = labels < 0
    if unreached.any():
        from scipy.spatial import cKDTree

        labels[unreached] = cKDTree(low.mesh.verts).query(full.verts[unreached])[1]
    return labels


def ring_faces(mesh: Mesh, vertices: np.ndarray) -> np.ndarray:
    """Faces around each given vertex and around its neighbours, shape (N, C), padded with -1."""
    around = vertex_face_table(mesh)[vertex_rings(mesh)[vertices]]
    return around.reshape(len(vertices), -1)


RING_FACE_CELLS = 8_000_000
"""Entries of the candidate table (points x faces around their rings, padding included) that
:func:`closest_points_near` builds at once."""


def closest_points_near(
    mesh: Mesh, points: np.ndarray, vertices: np.ndarray, clip: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Each point's closest point on the faces around ``vertices[n]`` and around its neighbours.

    The candidate table is as wide as the mesh's widest ring times its most faces at a vertex
    (65 x 64 on a scan whose faces were split at their centroids: 2.3 GB for 70 000 points at
    once), so it is built a block of points at a time; each point's answer is its own.

    Parameters
    ----------
    mesh : Mesh
    points : np.ndarray, shape (N, 3)
    vertices : np.ndarray, shape (N,), int
    clip : bool
        As :func:`~spidermatch.geometry.surface.closest_triangle_points`.

    Returns
    -------
    face : np.ndarray, shape (N,), int64
    bary : np.ndarray, shape (N, 3)

    """
    step = max(1, RING_FACE_CELLS // (vertex_rings(mesh).shape[1] * vertex_face_table(mesh).shape[1]))
    face, bary = np.empty(len(points), dtype=np.int64), np.empty((len(points), 3))
    for begin in range(0, len(points), step):
        rows = slice(begin, begin + step)
        face[rows], bary[rows] = closest_triangle_points(
            mesh.verts, mesh.faces, points[rows], clip=clip, candidates=ring_faces(mesh, vertices[rows])
        )
    return face, bary


def project_onto_coarse(
    full: Mesh, low: Decimated, clip: bool = True, labels: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Each full-resolution vertex's closest point on the low-resolution surface near its label.

    ``labels`` (V_full,): :func:`coarse_labels` of ``full``, if the caller has them already.

    Returns
    -------
    face : np.ndarray, shape (V_full,), int64
        Low-resolution face.
    bary : np.ndarray, shape (V_full, 3)
        See :func:`spidermatch.geometry.surface.closest_triangle_points` for ``clip``.

    """
    if labels is None:
        labels = coarse_labels(full, low)
    return closest_points_near(low.mesh, full.verts, labels, clip=clip)


def faces_by_label(full: Mesh, labels: np.ndarray, n_low: int) -> np.ndarray:
    """Full-resolution faces touching a vertex of each label, shape (n_low, C), padded with -1."""
    corner_label = labels[full.faces].T.reshape(-1)
    corner_face = np.tile(np.arange(len(full.faces)), 3)
    pairs = np.unique(np.stack([corner_label, corner_face], axis=1), axis=0)
    return padded_rows(pairs[:, 0], pairs[:, 1], n_low)
