"""A whole shape's small holes closed for matching, and the way back to the mesh as given.

A raw scan of a whole surface has small holes where the scanner saw nothing
(:data:`~spidermatch.geometry.mesh.SMALL_HOLE_SHARE`). Matched as they are, each hole is a
boundary that the other shape lacks there: the decimated mesh keeps a hole that is large at its
resolution, the SpiderCurve has to run round it, and the dense map's deformation has nothing to
hold it. A whole shape is therefore matched on a copy with each small hole closed by a fan to
its loop's centroid (:class:`ClosedCopy`), and everything the match says is told back on the
mesh as given: a point on a fan face moves out from the centre to the hole's rim (radially,
onto the fan face's outer edge, which is a boundary edge of one given face), a fan's centre
vertex is never named. docs/partial.md, "Whole shapes are matched with their small holes closed",
has the measurements.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from spidermatch.geometry.mesh import (
    EDGE_SLOT_CORNERS,
    Mesh,
    directed_face_edges,
    small_holes_closed,
    topology,
)


@dataclass(frozen=True, eq=False)
class ClosedCopy:
    """A mesh with its small holes closed by fans: the given mesh's vertices and faces come first.

    Attributes
    ----------
    mesh : Mesh
        The closed copy, V + H vertices (one centre per hole) and F + K faces (one per rim edge).
    n_verts, n_faces : int
        V and F, the given mesh's counts.
    rim_face : np.ndarray, shape (K,), int64
        The given face across the outer edge of each fan face.
    rim_corners : np.ndarray, shape (K, 2), int64
        Where (0-2) in ``rim_face`` lie the fan face's corners 0 and 1 (its outer edge).

    """

    mesh: Mesh
    n_verts: int
    n_faces: int
    rim_face: np.ndarray
    rim_corners: np.ndarray

    def rim_means(self, rows: np.ndarray) -> np.ndarray:
        """The mean of per-vertex ``rows`` (V, D) over each hole's rim: a row for each centre (H, D)."""
        rows = np.asarray(rows, dtype=np.float64)
        fans = self.mesh.faces[self.n_faces :]
        centres = fans[:, 2] - self.n_verts
        n_holes = self.mesh.n_verts - self.n_verts
        sums = np.zeros((n_holes, rows.shape[1]))
        np.add.at(sums, centres, rows[fans[:, 0]])
        return sums / np.bincount(centres, minlength=n_holes)[:, None]

    def on_given_surface(self, face: np.ndarray, bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Surface points (face (N,), barycentric (N, 3)) of the copy moved onto the given mesh.

        A point on a fan face goes radially out from the hole's centre to the fan face's outer
        edge (the centre itself to that edge's midpoint); the other points stay where they are.
        """
        face, bary = np.asarray(face, dtype=np.int64).copy(), np.asarray(bary, dtype=np.float64).copy()
        on_fan = np.flatnonzero(face >= self.n_faces)
        if not on_fan.size:
            return face, bary
        fan = face[on_fan] - self.n_faces
        rim = bary[on_fan, :2]
        total = rim.sum(axis=1, keepdims=True)
        rim = np.where(total > 0, rim / np.where(total > 0, total, 1.0), 0.5)
        moved = np.zeros((on_fan.size, 3))
        rows = np.arange(on_fan.size)
        moved[rows, self.rim_corners[fan, 0]] = rim[:, 0]
        moved[rows, self.rim_corners[fan, 1]] = rim[:, 1]
        face[on_fan], bary[on_fan] = self.rim_face[fan], moved
        return face, bary

    def given_vertices(self, vertex: np.ndarray, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """``vertex`` (N,) of points on the given mesh, each centre replaced by its point's nearest corner.

        ``face`` and ``bary`` are the points on the given mesh (:meth:`on_given_surface`).
        """
        vertex = np.asarray(vertex, dtype=np.int64).copy()
        centre = np.flatnonzero(vertex >= self.n_verts)
        corner = np.argmax(bary[centre], axis=1)
        vertex[centre] = self.mesh.faces[face[centre], corner]
        return vertex


def closed_but_for_small_holes(mesh: Mesh) -> bool:
    """Whether ``mesh`` (validated) is a whole surface: no boundary loop but small holes."""
    return topology(mesh).open_boundaries == 0


def sides_to_close(target: Mesh, partial: bool, overlap: bool = False) -> tuple[bool, bool]:
    """Whether the source and the target of a pair get their small holes closed.

    Two whole shapes both; a part (``partial``) never, its target when that is closed but for
    small holes (a whole scan); with ``overlap`` (two parts, ``partial="both"``) neither.
    """
    whole = not (partial or overlap)
    return whole, whole or (partial and not overlap and closed_but_for_small_holes(target))


def closed_copy(mesh: Mesh) -> ClosedCopy | None:
    """``mesh`` with its small holes closed (:func:`small_holes_closed`), or None when it has none."""
    closed = small_holes_closed(mesh)
    if closed is mesh:
        return None
    fans = closed.faces[mesh.n_faces :]
    rim_face, rim_corners = _rim_faces(mesh.faces, fans[:, 1], fans[:, 0])
    return ClosedCopy(closed, mesh.n_verts, mesh.n_faces, rim_face, rim_corners)


def _rim_faces(faces: np.ndarray, start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The face running each boundary edge ``start -> end`` (K,), and where its ``end`` and ``start`` lie.

    Returns the face (K,) and its corners (K, 2) of ``end`` and ``start``: the fan face over
    that edge runs it backwards, ``end`` first.
    """
    directed = directed_face_edges(faces)
    n = int(faces.max()) + 1
    keys = directed[:, 0] * n + directed[:, 1]
    order = np.argsort(keys)
    found = order[np.searchsorted(keys, start * n + end, sorter=order)]
    corners = EDGE_SLOT_CORNERS[found % 3]
    return (found // 3).astype(np.int64), corners[:, ::-1].astype(np.int64)


def nearest_given_vertices(
    to_full: np.ndarray, low_verts: np.ndarray, copy: ClosedCopy, full: Mesh
) -> np.ndarray:
    """``to_full`` (V_low,) of a decimated copy with each hole centre replaced by the nearest given vertex.

    ``low_verts`` (V_low, 3) are the decimated vertices and ``full`` the copy in their frame.
    """
    to_full = np.asarray(to_full, dtype=np.int64).copy()
    centre = np.flatnonzero(to_full >= copy.n_verts)
    if centre.size:
        to_full[centre] = cKDTree(full.verts[: copy.n_verts]).query(low_verts[centre])[1]
    return to_full
