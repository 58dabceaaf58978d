"""Fold-free rounding of a dense map to target vertices.

A dense map in point form (an image point on the target for every source vertex) becomes a
vertex map by taking, for each source vertex, a target vertex near its image point. The
nearest vertex folds image triangles where neighbouring image points lie within about one
target edge of each other: rounding can put three nearby points' vertices in the wrong
order, and the image triangle then faces against the target (a flip, see
:mod:`spidermatch.eval.metrics`); rounding the two ends of an edge apart can tear it. Here the
vertices of flipped image triangles and of stretched image edges (longer than the tear
threshold and than :data:`STRETCH` times the source edge, measured as the tear figure
measures a vertex map: along the target's edges) may move to any vertex within two edges of
their nearest vertex, when that leaves fewer of their image triangles flipped plus image
edges stretched (the vertices choose group by group, no two of a group sharing an edge, so
that each choice sees its neighbours' current ones); among equally good choices the one nearest
to the image point wins, measured in local target edge lengths and weighted by
:data:`DISTANCE_WEIGHT`. On a mesh with long edges, two vertices close in space can be
far apart along the edges, and measuring in space alone leaves such tears in place
(docs/dense_maps.md). An image triangle whose corners share a target vertex is
degenerate, not flipped: such collapses are what any vertex map between meshes of similar
resolution has (the ground truth of FAUST_r has about a third), and they are counted apart.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from spidermatch.eval.metrics import DEGENERATE_AREA, TEAR_THRESHOLD, oriented_triangles
from spidermatch.geometry.graph_distance import distances_within, farther_than
from spidermatch.geometry.mesh import Mesh, mean_incident_edge_length
from spidermatch.geometry.operators import vertex_normals
from spidermatch.geometry.surface import vertex_face_table, vertex_rings

DISTANCE_WEIGHT = 0.5
"""Cost of one local target edge length between a vertex and its image point, in flipped triangles."""

STRETCH = 1.0
"""An image edge longer than the tear threshold and this many times its (scaled) source length is torn.

1: a source edge may keep its own length, however long (a coarse source is not compressed), but
not grow beyond it and the threshold. On the six held-out TOSCA_animals pairs (whose meshes have
1-3 % of their edges longer than the threshold) 1 instead of 2 lowered the vertex maps' tears from
3.1 % to 2.2 % at the same error (docs/dense_maps.md, "A tear is an edge that grows")."""

SWEEPS = 4
"""Passes over the vertices of flipped image triangles and torn image edges (2 left 0.1-0.2 % more tears).

A pass decides again only the vertices a neighbour of which moved since their last choice (the
others would choose the same), and the passes stop when one moves nothing."""

CHOICE_CELLS = 2_000_000
"""Choices times faces (or neighbours) weighed at once at most, when a group chooses its vertices."""


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
    progress: Callable[[float], None] | None = None,
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
    progress : callable, optional
        Called with the share of the work done so far (0 to 1; each sweep counts as
        1 / :data:`SWEEPS`, its groups by their sizes).

    Returns
    -------
    np.ndarray, shape (V_X,), int64
        Each entry ``vertex[i]`` or a target vertex within two edges of it.

    """
    nearest = np.asarray(vertex, dtype=np.int64)
    vertex = nearest.copy()
    context = _Rounding.between(source, target)
    movable = np.ones(source.n_verts, dtype=bool)
    if fixed is not None:
        movable[np.asarray(fixed, dtype=np.int64)] = False
    status = _MendStatus.of(vertex, context)
    ledger = _ChoiceLedger.empty(source.n_verts)
    for sweep in range(SWEEPS):
        candidates = status.vertices()
        candidates = candidates[movable[candidates]]
        changed = np.zeros(source.n_verts, dtype=bool)
        decided = 0
        for group in independent_groups(candidates, source.edges, source.n_verts):
            decided += len(group)
            group = group[ledger.stale(group)]
            if group.size:
                chosen = _best_choices(context, vertex, group, nearest[group], points[group])
                moved = group[chosen != vertex[group]]
                vertex[group] = chosen
                ledger.record(group, moved, context.neighbours)
                changed[moved] = True
            if progress is not None:
                progress((sweep + decided / len(candidates)) / SWEEPS)
        if not changed.any():
            break
        status.update(vertex, changed)
    return vertex


@dataclass
class _MendStatus:
    """Which image triangles are flipped and which image edges are stretched, kept up to date."""

    context: _Rounding
    flipped: np.ndarray  # (F_X,) bool, per source face
    stretched: np.ndarray  # (E_X,) bool, per source edge

    @classmethod
    def of(cls, vertex: np.ndarray, context: _Rounding) -> _MendStatus:
        """The status of the vertex map ``vertex`` (V_X,)."""
        source = context.source
        return cls(
            context,
            flipped_triangles(vertex[source.faces], context.target, context.normals),
            _stretched_edges(source.edges, vertex, context),
        )

    def vertices(self) -> np.ndarray:
        """Source vertices of flipped image triangles and stretched image edges, sorted (N,)."""
        source = self.context.source
        return np.union1d(source.faces[self.flipped], source.edges[self.stretched])

    def update(self, vertex: np.ndarray, changed: np.ndarray) -> None:
        """Re-score the triangles and edges with a corner in ``changed`` (V_X,) bool; the rest keep theirs."""
        context = self.context
        faces, edges = context.source.faces, context.source.edges
        faces_hit = np.flatnonzero(changed[faces].any(axis=1))
        self.flipped[faces_hit] = flipped_triangles(vertex[faces[faces_hit]], context.target, context.normals)
        edges_hit = np.flatnonzero(changed[edges].any(axis=1))
        self.stretched[edges_hit] = _stretched_edges(edges[edges_hit], vertex, context)


@dataclass
class _ChoiceLedger:
    """When each source vertex last chose its target vertex, and when its neighbourhood last moved.

    A choice reads only the vertex's own start and image point and the current target
    vertices of its source neighbours (:func:`_best_choices`). A vertex whose neighbours have
    not moved since it chose would choose the same again, so it is skipped: the result is that
    of re-deciding every candidate in every sweep, with only the work that can change it.
    """

    chose_at: np.ndarray  # (V_X,) int64, the step of the last choice, -1 before any
    moved_at: np.ndarray  # (V_X,) int64, the last step a neighbour moved, 0 before any
    step: int = 0

    @classmethod
    def empty(cls, n_verts: int) -> _ChoiceLedger:
        return cls(np.full(n_verts, -1, dtype=np.int64), np.zeros(n_verts, dtype=np.int64))

    def stale(self, vertices: np.ndarray) -> np.ndarray:
        """Whether each of ``vertices`` (N,) has a neighbour that moved since its last choice, bool (N,)."""
        return self.moved_at[vertices] > self.chose_at[vertices]

    def record(self, chosen: np.ndarray, moved: np.ndarray, neighbours: np.ndarray) -> None:
        """Note a group's choice: ``chosen`` (N,) chose, ``moved`` (M,) of them took a new vertex.

        ``neighbours`` (V_X, 1 + max degree) holds each source vertex and its neighbours.
        """
        self.step += 1
        self.chose_at[chosen] = self.step
        self.moved_at[neighbours[moved].ravel()] = self.step


def independent_groups(vertices: np.ndarray, edges: np.ndarray, n_verts: int) -> list[np.ndarray]:
    """``vertices`` split into groups of which no two members share an edge, in the order to decide them.

    Each round takes the vertices that outrank every neighbour still left (a fixed random
    rank), so a group's members can choose at once: none of them looks at another's choice.

    Parameters
    ----------
    vertices : np.ndarray, shape (N,), int
    edges : np.ndarray, shape (E, 2), int
    n_verts : int

    Returns
    -------
    list of np.ndarray
        Disjoint groups whose union is ``vertices``.

    """
    left = np.zeros(n_verts, dtype=bool)
    left[vertices] = True
    rank = np.random.default_rng(0).permutation(n_verts)
    edges = edges[left[edges[:, 0]] & left[edges[:, 1]]]
    groups = []
    while left.any():
        edges = edges[left[edges[:, 0]] & left[edges[:, 1]]]
        outranked = np.zeros(n_verts, dtype=bool)
        first_lower = rank[edges[:, 0]] < rank[edges[:, 1]]
        outranked[edges[first_lower, 0]] = True
        outranked[edges[~first_lower, 1]] = True
        group = np.flatnonzero(left & ~outranked)
        groups.append(group)
        left[group] = False
    return groups


@dataclass(frozen=True)
class _Rounding:
    """What choosing a source vertex's target vertex reads: the meshes and their tables."""

    source: Mesh
    target: Mesh
    normals: np.ndarray  # (V_Y, 3) target vertex normals
    rings: np.ndarray  # (V_Y, 1 + max degree) each target vertex and its neighbours
    around: np.ndarray  # (V_X, max faces) source faces at each source vertex, -1 padded
    neighbours: np.ndarray  # (V_X, 1 + max degree) each source vertex and its neighbours
    local_edge: np.ndarray  # (V_Y,) mean edge length at each target vertex
    target_degree: np.ndarray  # (V_Y,) neighbours of each target vertex (real entries of its ``rings`` row)
    source_degree: np.ndarray  # (V_X,) neighbours of each source vertex
    source_face_count: np.ndarray  # (V_X,) faces at each source vertex (real entries of its ``around`` row)

    @classmethod
    def between(cls, source: Mesh, target: Mesh) -> _Rounding:
        """The tables of a map from ``source`` to ``target``."""
        rings, around, neighbours = vertex_rings(target), vertex_face_table(source), vertex_rings(source)
        return cls(
            source,
            target,
            vertex_normals(target.verts, target.faces),
            rings,
            around,
            neighbours,
            mean_incident_edge_length(target),
            _row_degrees(rings),
            _row_degrees(neighbours),
            (around >= 0).sum(axis=1),
        )

    def allowed_length(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """How long the images of source edges (a, b) may be: the tear threshold or STRETCH times theirs.

        An edge that is long on the source too (a coarse mesh) is not torn by a long image.
        """
        scale = np.sqrt(self.target.area / self.source.area)
        own = np.linalg.norm(self.source.verts[a] - self.source.verts[b], axis=-1) * scale
        return np.maximum(self.threshold, STRETCH * own)

    @property
    def threshold(self) -> float:
        """The tear threshold on the target."""
        return TEAR_THRESHOLD * np.sqrt(self.target.area)


def _row_degrees(rings: np.ndarray) -> np.ndarray:
    """Neighbours in each row of a ring table (V, 1 + max degree) padded with the row's own vertex."""
    return (rings[:, 1:] != rings[:, :1]).sum(axis=1)


def _stretched_edges(edges: np.ndarray, vertex: np.ndarray, context: _Rounding) -> np.ndarray:
    """Source edges (E, 2) whose image vertices lie farther apart along the target than allowed, bool (E,)."""
    allowed = context.allowed_length(edges[:, 0], edges[:, 1])
    return farther_than(context.target, vertex[edges[:, 0]], vertex[edges[:, 1]], allowed)


def _best_choices(
    context: _Rounding, vertex: np.ndarray, group: np.ndarray, start: np.ndarray, points: np.ndarray
) -> np.ndarray:
    """Target vertices for a group of source vertices no two of which are neighbours.

    Each member takes, among the target vertices within two edges of its ``start``, the one
    with the fewest flipped image triangles plus stretched image edges, then the nearest to
    its image point; a chunk of members of about the same valences at a time
    (:func:`_chunks_by_width`, :data:`CHOICE_CELLS`).

    Parameters
    ----------
    context : _Rounding
    vertex : np.ndarray, shape (V_X,), int64
        The current vertex map (its entries at ``group`` are not read).
    group : np.ndarray, shape (G,), int
    start : np.ndarray, shape (G,), int
        Each member's nearest target vertex.
    points : np.ndarray, shape (G, 3)
        Each member's image point.

    Returns
    -------
    np.ndarray, shape (G,), int64

    """
    out = np.empty(len(group), dtype=np.int64)
    for part in _chunks_by_width(context, group, start):
        mine = _TwoRings.around(context.target, context.rings, start[part], context.target_degree)
        cost = _flip_counts(context, vertex, group[part], mine.vertex)
        cost += _tear_counts(context, vertex, group[part], start[part], mine)
        distance = np.linalg.norm(context.target.verts[mine.vertex] - points[part, None], axis=2)
        cost = np.where(
            mine.valid, cost + DISTANCE_WEIGHT * distance / context.local_edge[mine.vertex], np.inf
        )
        out[part] = mine.vertex[np.arange(len(cost)), np.argmin(cost, axis=1)]
    return out


def _chunks_by_width(context: _Rounding, group: np.ndarray, start: np.ndarray) -> list[np.ndarray]:
    """Positions in ``group`` (G,) split into chunks of members whose tables are about as wide.

    A member weighs at most (1 + its start's degree) x (1 + its start's neighbours' largest
    degree) choices against its faces or neighbours. Tables padded to the widest member of a
    whole group (65 x 65 two-ring entries on a mesh whose faces were split at their centroids,
    against 7 x 7 for a regular vertex) cost most of the work there: members are sorted by that count
    and each chunk is as wide as its own widest member, with at most :data:`CHOICE_CELLS` cells.
    """
    degree = context.target_degree
    second = degree[context.rings[start]].max(axis=1)
    own = np.maximum(context.source_face_count[group], context.source_degree[group])
    cells = (1 + degree[start]) * (1 + second) * np.maximum(own, 1)
    order = np.argsort(cells, kind="stable")
    cells = cells[order]
    chunks, begin = [], 0
    while begin < len(order):
        # The widest member of a chunk is its last: the longest run from ``begin`` within the cap.
        sizes = np.arange(1, len(order) - begin + 1)
        fits = cells[begin:] * sizes <= CHOICE_CELLS
        size = max(1, int(np.flatnonzero(fits)[-1]) + 1) if fits.any() else 1
        chunks.append(order[begin : begin + size])
        begin += size
    return chunks


@dataclass(frozen=True)
class _TwoRings:
    """The target vertices within two edges of each of N start vertices, sorted, one row per start.

    Rows shorter than the longest are padded with their start and marked invalid.
    """

    vertex: np.ndarray  # (N, C) int64
    length: np.ndarray  # (N, C) the shortest path of at most two edges from the start
    valid: np.ndarray  # (N, C) bool

    @classmethod
    def around(cls, target: Mesh, rings: np.ndarray, start: np.ndarray, degree: np.ndarray) -> _TwoRings:
        """The rows of ``start`` (N,); ``degree`` (V,) of each target vertex trims the padded ``rings``."""
        start = np.asarray(start, dtype=np.int64)
        middle = rings[start][:, : 1 + int(degree[start].max())]  # (N, K1)
        ends = rings[middle][:, :, : 1 + int(degree[middle].max())]  # (N, K1, K2)
        verts = target.verts
        first = np.linalg.norm(verts[middle] - verts[start][:, None], axis=2)
        length = (
            first[:, :, None] + np.linalg.norm(verts[ends] - verts[middle][:, :, None], axis=3)
        ).reshape(len(start), -1)
        ends = ends.reshape(len(start), -1)
        order = np.lexsort((length, ends))  # by vertex, then shortest first
        ends, length = np.take_along_axis(ends, order, 1), np.take_along_axis(length, order, 1)
        fresh = np.ones(ends.shape, dtype=bool)
        fresh[:, 1:] = ends[:, 1:] != ends[:, :-1]
        order = np.argsort(~fresh, axis=1, kind="stable")  # each row's distinct vertices first, in order
        ends, length, fresh = (np.take_along_axis(a, order, 1) for a in (ends, length, fresh))
        width = int(fresh.sum(axis=1).max())
        ends, length, fresh = ends[:, :width], length[:, :width], fresh[:, :width]
        return cls(np.where(fresh, ends, start[:, None]), np.where(fresh, length, 0.0), fresh)


def _flip_counts(
    context: _Rounding, vertex: np.ndarray, members: np.ndarray, choices: np.ndarray
) -> np.ndarray:
    """Flipped image triangles around each member (M,) for each of its choices (M, C), shape (M, C).

    A face's image with the member's corner at c and its other corners u, w (in the face's
    order from the member's) has the normal (u - c) x (w - c) = u x w + c x (u - w): per face
    one vector and one product with each choice, instead of each trial triangle put together
    (on a mesh of needle triangles most of the rounding's time). Positions are taken from one
    of the member's choices (near its triangles), so that the terms stay as small as the
    triangles whatever the coordinates' origin and unit. As
    :func:`flipped_triangles`: degenerate (no area) is not flipped.
    """
    around = context.around[members][:, : max(1, int(context.source_face_count[members].max()))]  # (M, f)
    real = around >= 0
    faces = context.source.faces[np.where(real, around, 0)]  # (M, f, 3)
    position = np.argmax(faces == members[:, None, None], axis=2)  # the member's corner in each face
    rows = np.arange(len(members))[:, None]
    after = vertex[faces[rows, np.arange(faces.shape[1]), (position + 1) % 3]]  # (M, f) image of u
    before = vertex[faces[rows, np.arange(faces.shape[1]), (position + 2) % 3]]  # (M, f) image of w
    verts, normals = context.target.verts, context.normals
    origin = verts[choices[:, 0]][:, None]  # (M, 1, 3): a choice, within two edges of the start
    u, w, c = verts[after] - origin, verts[before] - origin, verts[choices] - origin
    fixed_part = np.cross(u, w)  # (M, f, 3)
    normal = fixed_part[:, None] + np.cross(c[:, :, None], (u - w)[:, None])  # (M, C, f, 3)
    reference = normals[choices][:, :, None] + (normals[after] + normals[before])[:, None]
    degenerate = (
        0.5 * np.linalg.norm(normal, axis=3) <= DEGENERATE_AREA * context.target.area / context.target.n_faces
    )
    flips = ~degenerate & (np.einsum("mcfd,mcfd->mcf", normal, reference) < 0)
    return (flips & real[:, None, :]).sum(axis=2)


def _tear_counts(
    context: _Rounding, vertex: np.ndarray, members: np.ndarray, start: np.ndarray, choices: _TwoRings
) -> np.ndarray:
    """Stretched image edges at each member (M,) for each of its choices, shape (M, C).

    With s the member's start, c a choice and v a neighbour's image: c lies within
    ``length(c)`` of s (a path of at most two edges), so the distance from c to v lies between
    d(s, v) - length(c) and d(s, v) + length(c), and is at least their distance in space.
    d(s, v) is searched once per neighbour (up to the allowed length plus the longest choice,
    inf beyond), not once per choice; only the pairs these bounds leave undecided go to
    :func:`~spidermatch.geometry.graph_distance.farther_than`. (A greedy walk in place of the
    search stalls on a noisy scan, and then every choice of every member was searched.)
    """
    neighbours = context.neighbours[
        members, 1 : 1 + max(1, int(context.source_degree[members].max()))
    ]  # (M, d)
    real = neighbours != members[:, None]
    allowed = context.allowed_length(np.broadcast_to(members[:, None], neighbours.shape), neighbours)
    images = vertex[neighbours]
    longest_choice = np.where(choices.valid, choices.length, 0.0).max(axis=1)  # (M,)
    from_start = np.full(neighbours.shape, np.inf)
    from_start[real] = distances_within(
        context.target,
        np.broadcast_to(start[:, None], real.shape)[real],
        images[real],
        (allowed + longest_choice[:, None])[real],
    )
    shape = (len(members), choices.vertex.shape[1], neighbours.shape[1])
    verts = context.target.verts
    apart = np.linalg.norm(verts[choices.vertex][:, :, None] - verts[images][:, None], axis=3)
    allowed = np.broadcast_to(allowed[:, None, :], shape)
    length = choices.length[:, :, None]
    far = (apart > allowed) | (from_start[:, None, :] - length > allowed)
    near = length + from_start[:, None, :] <= allowed
    open_ = np.flatnonzero((~far & ~near & real[:, None, :] & choices.valid[:, :, None]).ravel())
    if open_.size:
        a = np.broadcast_to(choices.vertex[:, :, None], shape).ravel()[open_]
        b = np.broadcast_to(images[:, None, :], shape).ravel()[open_]
        at_least = np.maximum(apart, from_start[:, None, :] - length).ravel()[open_]
        # Searched from the neighbours' images: fewer of them than of choices.
        far.reshape(-1)[open_] = farther_than(context.target, b, a, allowed.ravel()[open_], at_least)
    return (far & real[:, None, :]).sum(axis=2)
