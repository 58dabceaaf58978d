"""Shortest distances along a mesh's edges between given vertex pairs, up to a bound.

The tear figure of :mod:`spidermatch.eval.metrics` and the fold-free rounding of
:mod:`spidermatch.dense.unfold` ask, for many vertex pairs, whether the path along the
target's edges between them is longer than a bound. Pairs joined by an edge (most, for a
continuous map) take that edge's length. The others run Dijkstra, but only on the part of
the mesh that a path within the bound can reach: a path of length at most ``limit`` from a
vertex never leaves the ball of radius ``limit`` around it, so Dijkstra restricted to the
vertices inside the balls of a block of start vertices gives the exact distances up to the
bound. Blocks of nearby starts share most of their balls; each block's work and memory is
its starts times the vertices in their balls (at most :data:`BLOCK_CELLS`), whatever the
mesh's size.

Most questions are "farther apart than a bound or not?" (:func:`farther_than`), and most of
them have a cheap answer: two vertices farther apart in space than the bound are farther
along the edges too, and a greedy walk from one to the other (each step to the neighbour
nearest the goal) that arrives within the bound is a path, so their distance is at most its
length. Only the pairs both tests leave open are searched; on a fine mesh, where a bound
of a few per cent of the shape spans many edges, that is almost none. On a noisy scan the
walk stalls for most pairs, and a search up to the bound around each would cover thousands
of vertices: the searches start a few edges long and only the pairs still open search
farther.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.surface import vertex_rings

GREEDY_STEPS = 64
"""Steps of the greedy walk that bounds a distance from above before any search."""

BLOCK_CELLS = 4_000_000
"""Distances one Dijkstra block may hold (its starts times the vertices in their balls)."""

BLOCK_STARTS = 512
"""Start vertices per Dijkstra block at most."""

BLOCK_EXTENT = 4.0
"""A block's starts lie within a box of this many search limits across (its search covers the box:
consecutive starts in Z-order can lie far apart where few are asked, e.g. a short first search)."""

FIRST_SEARCH_EDGES = 4.0
"""Limit of :func:`farther_than`'s first search, in median edge lengths (each further one doubles it)."""


def edge_lengths_between(mesh: Mesh, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Length of the edge joining ``a[n]`` and ``b[n]`` (0 if equal, nan if not adjacent), shape (N,)."""
    edges = mesh.edges  # sorted rows, i < j
    keys = edges[:, 0] * mesh.n_verts + edges[:, 1]
    low, high = np.minimum(a, b), np.maximum(a, b)
    wanted = low * mesh.n_verts + high
    where = np.minimum(np.searchsorted(keys, wanted), len(keys) - 1)
    adjacent = keys[where] == wanted
    out = np.full(len(a), np.nan)
    out[adjacent] = np.linalg.norm(
        mesh.verts[edges[where[adjacent], 0]] - mesh.verts[edges[where[adjacent], 1]], axis=1
    )
    out[a == b] = 0.0
    return out


def graph_distances_between(mesh: Mesh, a: np.ndarray, b: np.ndarray, limit: float) -> np.ndarray:
    """Shortest edge-graph distance from ``a[n]`` to ``b[n]``, inf beyond ``limit``.

    Parameters
    ----------
    mesh : Mesh
    a, b : np.ndarray, shape (N,), int
        Vertex pairs.
    limit : float
        Distances above it are reported as inf (and cost nothing to rule out when the
        two vertices are farther apart in space).

    Returns
    -------
    np.ndarray, shape (N,)
        Exact distances along the mesh's edges (Euclidean edge lengths) up to ``limit``.

    """
    a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
    out = edge_lengths_between(mesh, a, b)
    unknown = np.isnan(out)
    out[unknown | (out > limit)] = np.inf
    if not unknown.any():
        return out
    gap = np.linalg.norm(mesh.verts[a[unknown]] - mesh.verts[b[unknown]], axis=1)
    far = np.flatnonzero(unknown)[gap <= limit]
    if far.size:
        out[far] = _local_dijkstra(mesh, a[far], b[far], limit)
    return out


def _local_dijkstra(mesh: Mesh, a: np.ndarray, b: np.ndarray, limit: float) -> np.ndarray:
    """:func:`graph_distances_between` for pairs that need a search, block by block of nearby starts."""
    graph, tree = mesh.edge_graph(), mesh.vertex_tree
    starts, inverse = np.unique(a, return_inverse=True)
    order = _spatial_order(mesh.verts[starts], limit)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    pair_rank = rank[inverse]  # each pair's start, in spatial order
    by_start = np.argsort(pair_rank, kind="stable")
    out = np.full(len(a), np.inf)
    begin = 0
    while begin < len(starts):
        block, local = _next_block(tree, mesh.verts, starts[order], begin, limit)
        if len(local) == mesh.n_verts:
            position, subgraph = np.arange(mesh.n_verts), graph
        else:
            position = np.full(mesh.n_verts, -1, dtype=np.int64)
            position[local] = np.arange(len(local))
            subgraph = graph[local][:, local]
        rows = dijkstra(
            subgraph, directed=True, indices=position[block], limit=limit
        )  # the graph is symmetric
        lo, hi = np.searchsorted(pair_rank[by_start], [begin, begin + len(block)])
        members = by_start[lo:hi]
        column = position[b[members]]
        inside = column >= 0
        out[members[inside]] = rows[pair_rank[members[inside]] - begin, column[inside]]
        begin += len(block)
    return out


def _spatial_order(points: np.ndarray, cell: float) -> np.ndarray:
    """An order of ``points`` (N, 3) along a Z-order curve over grid cells of side ``cell``."""
    cells = np.floor((points - points.min(axis=0)) / max(cell, np.finfo(float).tiny)).astype(np.uint64)
    cells = np.minimum(cells, np.uint64(2**21 - 1))
    code = _spread_bits(cells[:, 0]) | _spread_bits(cells[:, 1]) << np.uint64(1)
    code |= _spread_bits(cells[:, 2]) << np.uint64(2)
    return np.argsort(code, kind="stable")


def _spread_bits(values: np.ndarray) -> np.ndarray:
    """The 21 low bits of each value moved to every third bit (for a 3-D Z-order code), uint64."""
    x = values.astype(np.uint64) & np.uint64(0x1FFFFF)
    for shift, mask in (
        (32, 0x1F00000000FFFF),
        (16, 0x1F0000FF0000FF),
        (8, 0x100F00F00F00F00F),
        (4, 0x10C30C30C30C30C3),
        (2, 0x1249249249249249),
    ):
        x = (x | (x << np.uint64(shift))) & np.uint64(mask)
    return x


def _next_block(
    tree: cKDTree, verts: np.ndarray, ordered_starts: np.ndarray, begin: int, limit: float
) -> tuple[np.ndarray, np.ndarray]:
    """The starts from ``begin`` on whose surroundings fit :data:`BLOCK_CELLS`, and those surroundings.

    Returns
    -------
    block : np.ndarray, shape (S,)
        Start vertices (at least one).
    local : np.ndarray, shape (L,)
        Sorted vertices within ``limit`` of the block's bounding box (all of them for a
        small mesh, where finding them would cost more than it saves).

    """
    size = min(BLOCK_STARTS, len(ordered_starts) - begin)
    if size * len(verts) <= BLOCK_CELLS:
        return ordered_starts[begin : begin + size], np.arange(len(verts))
    size = _compact_run(verts[ordered_starts[begin : begin + size]], BLOCK_EXTENT * limit)
    while True:
        block = ordered_starts[begin : begin + size]
        low, high = verts[block].min(axis=0), verts[block].max(axis=0)
        radius = 0.5 * float(np.linalg.norm(high - low)) + limit * (1 + 1e-9)
        centre = 0.5 * (low + high)
        if size > 1 and size * tree.query_ball_point(centre, r=radius, return_length=True) > BLOCK_CELLS:
            size //= 2  # counted, not listed: a ball of 100 000 vertices takes long to list
            continue
        return block, np.sort(np.asarray(tree.query_ball_point(centre, r=radius), dtype=np.int64))


def _compact_run(points: np.ndarray, extent: float) -> int:
    """How many of ``points`` (N, 3), from the first on, fit a box of diagonal ``extent`` (at least 1)."""
    low, high = np.minimum.accumulate(points, axis=0), np.maximum.accumulate(points, axis=0)
    wide = np.linalg.norm(high - low, axis=1) > extent
    return max(1, int(np.argmax(wide)) if wide.any() else len(points))


def farther_than(
    mesh: Mesh, a: np.ndarray, b: np.ndarray, bound: np.ndarray, at_least: np.ndarray | None = None
) -> np.ndarray:
    """Whether ``a[n]`` and ``b[n]`` lie farther apart along the mesh's edges than ``bound[n]``.

    Parameters
    ----------
    mesh : Mesh
    a, b : np.ndarray, shape (N,), int
    bound : np.ndarray, shape (N,) (or a float)
    at_least : np.ndarray, shape (N,), optional
        Known lower bounds of the distances (:func:`distances_within`).

    Returns
    -------
    np.ndarray, shape (N,), bool
        Exactly ``graph_distances_between(mesh, a, b, bound.max()) > bound``.

    """
    a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
    bound = np.broadcast_to(np.asarray(bound, dtype=np.float64), a.shape)
    far = np.linalg.norm(mesh.verts[a] - mesh.verts[b], axis=1) > bound
    near = np.flatnonzero(~far)
    open_ = near[greedy_path_lengths(mesh, a[near], b[near], bound[near]) > bound[near]]
    at_least = None if at_least is None else at_least[open_]
    far[open_] = distances_within(mesh, a[open_], b[open_], bound[open_], at_least) > bound[open_]
    return far


def distances_within(
    mesh: Mesh, a: np.ndarray, b: np.ndarray, bound: np.ndarray, at_least: np.ndarray | None = None
) -> np.ndarray:
    """Shortest edge-graph distance from ``a[n]`` to ``b[n]`` where at most ``bound[n]``, else inf.

    :func:`graph_distances_between` with a bound per pair, searched a few edges far first and
    doubling (:func:`_search_limits`): each pair costs the search its own distance needs.

    Parameters
    ----------
    mesh : Mesh
    a, b : np.ndarray, shape (N,), int
    bound : np.ndarray, shape (N,) (or a float)
    at_least : np.ndarray, shape (N,), optional
        What the caller knows the distances to be at least: searches shorter than all of them
        cannot settle a pair and are skipped.

    Returns
    -------
    np.ndarray, shape (N,)

    """
    a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
    bound = np.broadcast_to(np.asarray(bound, dtype=np.float64), a.shape)
    out = np.full(len(a), np.inf)
    open_ = np.flatnonzero(np.linalg.norm(mesh.verts[a] - mesh.verts[b], axis=1) <= bound)
    floor = 0.0 if at_least is None or not open_.size else float(at_least[open_].min())
    for limit in _search_limits(mesh, bound[open_], floor):
        distance = graph_distances_between(mesh, a[open_], b[open_], limit)
        found = np.isfinite(distance)
        out[open_[found]] = distance[found]
        open_ = open_[~found & (bound[open_] > limit)]
    out[out > bound] = np.inf
    return out


def _search_limits(mesh: Mesh, bounds: np.ndarray, floor: float = 0.0) -> list[float]:
    """The search limits of :func:`farther_than`'s rounds: doubling from a few edges to the largest bound.

    A search up to a limit costs about the vertices within it around each start, which grows
    with the limit squared (on a crumpled, noisy surface faster still). Most open pairs are
    joined by a short path that the greedy walk missed (on a noisy scan it stalls after a step
    or two) and are settled by a short search; only the pairs left go on to a longer one. Each
    round is exact up to its limit, so the answers are those of one search up to the largest bound.
    No pair is nearer than ``floor``: the first search goes at least that far.
    """
    if not bounds.size:
        return []
    largest = float(bounds.max())
    limit = max(FIRST_SEARCH_EDGES * mesh.median_edge_length, floor)
    limits = []
    while limit < largest:
        limits.append(limit)
        limit *= 2.0
    return limits + [largest]


def greedy_path_lengths(mesh: Mesh, a: np.ndarray, b: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """Length of a path along the edges from ``a[n]`` to ``b[n]`` found by walking greedily, shape (N,).

    Each step goes to the neighbour nearest to ``b[n]`` in space. A walk that stops short (no
    neighbour nearer than where it stands), outgrows ``limit[n]`` or takes more than
    :data:`GREEDY_STEPS` steps gives inf. The result is an upper bound of the shortest
    distance (exact for neighbours and for equal vertices).

    Parameters
    ----------
    mesh : Mesh
    a, b : np.ndarray, shape (N,), int
    limit : np.ndarray, shape (N,) (or a float)

    Returns
    -------
    np.ndarray, shape (N,)

    """
    rings = vertex_rings(mesh)
    verts = mesh.verts
    limit = np.broadcast_to(np.asarray(limit, dtype=np.float64), np.shape(a))
    here = np.array(a, dtype=np.int64)
    length = np.zeros(len(here))
    walking = np.flatnonzero(here != b)
    for _ in range(GREEDY_STEPS):
        if not walking.size:
            break
        options = rings[here[walking]]  # (n, K), each vertex first
        gap = np.linalg.norm(verts[options] - verts[b[walking], None], axis=2)
        step = options[np.arange(len(walking)), np.argmin(gap, axis=1)]
        length[walking] += np.linalg.norm(verts[step] - verts[here[walking]], axis=1)
        stuck = (step == here[walking]) | (length[walking] > limit[walking])
        length[walking[stuck]] = np.inf
        here[walking] = step
        walking = walking[~stuck & (step != b[walking])]
    length[walking] = np.inf
    return length
