"""Fold-free rounding of a dense map to target vertices.

A dense map in point form (an image point on the target for every source vertex) becomes a
vertex map by taking, for each source vertex, a target vertex near its image point. The
nearest vertex folds image triangles where neighbouring image points lie within about one
target edge of each other: rounding can put three nearby points' vertices in the wrong
order, and the image triangle then faces against the target (a flip, see
:mod:`spidermatch.eval.metrics`); rounding the two ends of an edge apart can tear it. Here the
vertices of flipped image triangles and of stretched image edges (longer in space than the
tear threshold and than :data:`STRETCH` times the source edge) may move to a neighbour of
their nearest vertex, one source vertex at a time, when that leaves fewer of their image
triangles flipped plus image edges stretched; among equally good choices the one nearest
to the image point wins, measured in local target edge lengths and weighted by
:data:`DISTANCE_WEIGHT`. An image triangle whose corners share a target vertex is
degenerate, not flipped: such collapses are what any vertex map between meshes of similar
resolution has (the ground truth of FAUST_r has about a third), and they are counted apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spidermatch.eval.metrics import TEAR_THRESHOLD, oriented_triangles
from spidermatch.geometry.coarse import vertex_rings
from spidermatch.geometry.mesh import Mesh, mean_incident_edge_length
from spidermatch.geometry.operators import vertex_normals
from spidermatch.geometry.surface import vertex_face_table

DISTANCE_WEIGHT = 0.5
"""Cost of one local target edge length between a vertex and its image point, in flipped triangles."""

STRETCH = 2.0
"""An image edge longer than the tear threshold and this many times its (scaled) source length is torn."""

SWEEPS = 2
"""Passes over the vertices of flipped image triangles."""


def flipped_triangles(images: np.ndarray, target: Mesh, normals: np.ndarray) -> np.ndarray:
    """Whether each triangle of target vertices faces against the target.

    Parameters
    ----------
    images : np.ndarray, shape (F, 3)
        Target vertices of the corners of each image triangle (``vertex[source.faces]``).
    target : Mesh
    normals : np.ndarray, shape (V_Y, 3)
        The target's vertex normals.

    Returns
    -------
    np.ndarray, shape (F,), bool
        Flipped and not degenerate (as :func:`spidermatch.eval.metrics.flipped_faces` on a vertex map).

    """
    return oriented_triangles(target.verts[images], normals[images].sum(axis=1), target)[0]


def unfolded_vertices(
    source: Mesh,
    target: Mesh,
    vertex: np.ndarray,
    points: np.ndarray,
    fixed: np.ndarray | None = None,
) -> np.ndarray:
    """The vertex map ``vertex`` (V_X,) with vertices of flipped triangles and torn edges moved to mend them.

    Parameters
    ----------
    source, target : Mesh
    vertex : np.ndarray, shape (V_X,), int64
        Target vertex of each source vertex (e.g. the nearest corner of its image point).
    points : np.ndarray, shape (V_X, 3)
        The image points.
    fixed : np.ndarray, shape (K,), optional
        Source vertices that keep their target vertex (e.g. certified matches).

    Returns
    -------
    np.ndarray, shape (V_X,), int64
        Each entry ``vertex[i]`` or one of its target neighbours.

    """
    nearest = np.asarray(vertex, dtype=np.int64)
    vertex = nearest.copy()
    context = _Rounding(
        source,
        target,
        vertex_normals(target.verts, target.faces),
        vertex_rings(target),
        vertex_face_table(source),
        mean_incident_edge_length(target),
    )
    movable = np.ones(source.n_verts, dtype=bool)
    if fixed is not None:
        movable[np.asarray(fixed, dtype=np.int64)] = False
    for _ in range(SWEEPS):
        flipped = flipped_triangles(vertex[source.faces], target, context.normals)
        stretched = _stretched_edges(source.edges, vertex, context)
        candidates = np.union1d(source.faces[flipped], source.edges[stretched])
        for i in candidates[movable[candidates]]:
            vertex[i] = _best_choice(context, vertex, i, nearest[i], points[i])
    return vertex


@dataclass(frozen=True)
class _Rounding:
    """What choosing a source vertex's target vertex reads: the meshes and their tables."""

    source: Mesh
    target: Mesh
    normals: np.ndarray  # (V_Y, 3) target vertex normals
    rings: np.ndarray  # (V_Y, 1 + max degree) each target vertex and its neighbours
    around: np.ndarray  # (V_X, max faces) source faces at each source vertex, -1 padded
    local_edge: np.ndarray  # (V_Y,) mean edge length at each target vertex

    def allowed_length(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """How long the images of source edges (a, b) may be: the tear threshold or STRETCH times theirs.

        An edge that is long on the source too (a coarse mesh) is not torn by a long image.
        """
        scale = np.sqrt(self.target.area / self.source.area)
        own = np.linalg.norm(self.source.verts[a] - self.source.verts[b], axis=-1) * scale
        return np.maximum(TEAR_THRESHOLD * np.sqrt(self.target.area), STRETCH * own)


def _stretched_edges(edges: np.ndarray, vertex: np.ndarray, context: _Rounding) -> np.ndarray:
    """Source edges (E, 2) whose image vertices lie farther apart in space than allowed, bool (E,)."""
    verts = context.target.verts
    length = np.linalg.norm(verts[vertex[edges[:, 0]]] - verts[vertex[edges[:, 1]]], axis=1)
    return length > context.allowed_length(edges[:, 0], edges[:, 1])


def _best_choice(context: _Rounding, vertex: np.ndarray, i: int, start: int, point: np.ndarray) -> int:
    """Source vertex ``i``'s target vertex: ``start`` or a neighbour; fewest flips and tears, then nearest."""
    around = context.around[i]
    faces = context.source.faces[around[around >= 0]]
    choices = np.unique(context.rings[start])
    trial = np.repeat(vertex[faces][None], len(choices), axis=0)  # (C, f, 3)
    trial[:, faces == i] = choices[:, None]
    target = context.target
    flips = flipped_triangles(trial.reshape(-1, 3), target, context.normals)
    neighbours = np.unique(faces[faces != i])
    gaps = np.linalg.norm(target.verts[choices][:, None] - target.verts[vertex[neighbours]][None], axis=2)
    tears = (gaps > context.allowed_length(np.full(len(neighbours), i), neighbours)).sum(axis=1)
    distance = np.linalg.norm(target.verts[choices] - point, axis=1) / context.local_edge[choices]
    cost = flips.reshape(len(choices), -1).sum(axis=1) + tears + DISTANCE_WEIGHT * distance
    return int(choices[np.argmin(cost)])
