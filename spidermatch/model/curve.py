"""The SpiderCurve: one long, self-intersecting cyclic curve through every vertex of a mesh.

Christofides' metric-TSP approximation over the metric closure (shortest-path
distances) of the mesh graph; every tour step is then expanded back into its
mesh-edge shortest path (method.md section 2).

Christofides needs a perfect matching of the spanning tree's odd-degree vertices.
``matching="blossom"`` takes networkx's exact minimum-weight matching (pure Python,
cubic in the number of odd vertices: minutes at 2000 faces); ``matching="greedy"``
(the default) pairs the closest unmatched vertices first and then improves the
matching by 2-opt exchanges among near neighbours, in O(K^2 log K) for K odd vertices.
Any perfect matching makes the multigraph Eulerian, so the tour, and with it every
curve invariant, is valid either way; only the 3/2 approximation guarantee is lost.

``tour="two_opt"`` then shortens the tour by 2-opt exchanges in the mesh's hop metric
(the number of edges between two vertices), which is the number of curve positions each
tour step expands into: the curve gets fewer positions and far fewer self-intersections.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import minimum_spanning_tree, shortest_path

from spidermatch.geometry.mesh import Mesh

logger = logging.getLogger(__name__)


class CurveError(ValueError):
    """A SpiderCurve violates one of its invariants."""


@dataclass(frozen=True)
class SpiderCurve:
    """A cyclic vertex sequence c_0 ... c_{L-1} on a mesh with V vertices.

    Attributes
    ----------
    vertices : np.ndarray, shape (L,), int64
        Mesh vertex at each curve position (layer); c_L = c_0.
    n_mesh_verts : int
        V, the number of vertices of the mesh it traces.

    """

    vertices: np.ndarray
    n_mesh_verts: int

    @property
    def length(self) -> int:
        """Number of curve positions L."""
        return int(self.vertices.shape[0])

    @property
    def first_layer(self) -> np.ndarray:
        """For each layer, the first layer holding the same mesh vertex, shape (L,)."""
        _, first_index, inverse = np.unique(self.vertices, return_index=True, return_inverse=True)
        return first_index[inverse]

    @property
    def duplicate_layers(self) -> np.ndarray:
        """Layers that repeat an earlier layer's vertex (coupled by PES), shape (D,)."""
        return np.flatnonzero(self.first_layer != np.arange(self.length))

    @property
    def is_intersection_layer(self) -> np.ndarray:
        """Whether each layer's vertex occurs more than once on the curve, shape (L,) bool."""
        counts = np.bincount(self.vertices, minlength=self.n_mesh_verts)
        return counts[self.vertices] > 1

    @property
    def intersections(self) -> np.ndarray:
        """Mesh vertices the curve passes more than once (self-intersections), shape (S,)."""
        counts = np.bincount(self.vertices, minlength=self.n_mesh_verts)
        return np.flatnonzero(counts > 1)


def check_curve(curve: SpiderCurve, edges: np.ndarray) -> None:
    """Raise :class:`CurveError` unless the curve covers every vertex and steps along ``edges``.

    Parameters
    ----------
    curve : SpiderCurve
    edges : np.ndarray, shape (E, 2)
        Undirected edges the curve may step along.

    """
    c = curve.vertices
    missing = np.setdiff1d(np.arange(curve.n_mesh_verts), c)
    if missing.size:
        raise CurveError(f"curve misses {missing.size} vertices (first: {missing[0]})")
    steps = np.sort(np.stack([c, np.roll(c, -1)], axis=1), axis=1)
    allowed = {tuple(e) for e in np.sort(edges, axis=1).tolist()}
    bad = [i for i, step in enumerate(map(tuple, steps.tolist())) if step not in allowed]
    if bad:
        raise CurveError(
            f"curve step {bad[0]} -> {(bad[0] + 1) % len(c)} ({steps[bad[0]].tolist()}) is not an edge"
        )


MATCHINGS = ("greedy", "blossom")
TOURS = ("christofides", "two_opt")
AUTO_TOUR = "auto"
"""The setting that tries :data:`TOURS` in turn (resolved by :func:`spidermatch.pipeline.match`)."""
TOUR_SETTINGS = (*TOURS, AUTO_TOUR)


def spider_curve(
    mesh: Mesh, augmented: bool = False, seed: int = 0, matching: str = "greedy", tour: str = "christofides"
) -> SpiderCurve:
    """Trace ``mesh`` with a SpiderCurve (Christofides tour expanded into mesh paths).

    Parameters
    ----------
    mesh : Mesh
        The (low-resolution) source mesh, V vertices.
    augmented : bool
        Use the augmented edge graph (method.md section 2) instead of the mesh edges.
    seed : int
        Selects the vertex the Euler tour starts from; the result is deterministic.
    matching : str
        Perfect matching of the odd-degree vertices: "greedy" (fast) or "blossom" (exact, cubic).
    tour : str
        "christofides" (the paper's tour) or "two_opt" (that tour shortened by
        :func:`two_opt_tour` in the hop metric, then expanded along fewest-edge paths).

    Returns
    -------
    SpiderCurve
        L >= V positions; consecutive positions are adjacent in the chosen graph.

    """
    if matching not in MATCHINGS:
        raise ValueError(f"unknown curve matching {matching!r}; choose from {MATCHINGS}")
    if tour not in TOURS:
        raise ValueError(f"unknown curve tour {tour!r}; choose from {TOURS}")
    graph = mesh.edge_graph(augmented)
    distances, predecessors = shortest_path(graph, directed=False, return_predecessors=True)
    start = int(np.random.default_rng(seed).integers(mesh.n_verts))
    order = christofides_tour(distances, start, matching)
    if tour == "two_opt":
        hops, predecessors = shortest_path(graph, directed=False, return_predecessors=True, unweighted=True)
        order = two_opt_tour(order, hops)
    vertices = expand_tour(order, predecessors)
    curve = SpiderCurve(vertices, mesh.n_verts)
    check_curve(curve, mesh.augmented_edges if augmented else mesh.edges)
    logger.debug(
        "SpiderCurve: %d positions over %d vertices, %d self-intersections",
        curve.length,
        mesh.n_verts,
        curve.intersections.size,
    )
    return curve


def christofides_tour(distances: np.ndarray, start: int = 0, matching: str = "greedy") -> np.ndarray:
    """Christofides' 3/2-approximate TSP tour on a metric.

    Parameters
    ----------
    distances : np.ndarray, shape (N, N)
        Symmetric metric (shortest-path distances), positive off the diagonal.
    start : int
        First vertex of the tour.
    matching : str
        "greedy" (:func:`greedy_perfect_matching`) or "blossom" (exact minimum weight).

    Returns
    -------
    np.ndarray, shape (N,)
        Every vertex once, in tour order (the tour closes back to ``start``).

    """
    import networkx as nx

    n = distances.shape[0]
    if n <= 3:
        return np.roll(np.arange(n), -start)
    tree = minimum_spanning_tree(distances).tocoo()
    degree = np.bincount(np.concatenate([tree.row, tree.col]), minlength=n)
    odd = np.flatnonzero(degree % 2 == 1)
    multigraph = nx.MultiGraph()
    multigraph.add_nodes_from(range(n))
    multigraph.add_edges_from(zip(tree.row.tolist(), tree.col.tolist()))
    pair_up = _min_weight_perfect_matching if matching == "blossom" else greedy_perfect_matching
    multigraph.add_edges_from(pair_up(distances, odd))
    order, seen = [], np.zeros(n, dtype=bool)
    for u, _ in nx.eulerian_circuit(multigraph, source=start):
        if not seen[u]:
            seen[u] = True
            order.append(u)
    return np.asarray(order, dtype=np.int64)


def _min_weight_perfect_matching(distances: np.ndarray, odd: np.ndarray) -> list[tuple[int, int]]:
    """Minimum-weight perfect matching of the ``odd`` vertices under ``distances`` (blossom)."""
    import networkx as nx

    complete = nx.Graph()
    i, j = np.triu_indices(odd.size, k=1)
    complete.add_weighted_edges_from(
        zip(odd[i].tolist(), odd[j].tolist(), distances[odd[i], odd[j]].tolist())
    )
    return [(int(a), int(b)) for a, b in nx.min_weight_matching(complete)]


def greedy_perfect_matching(
    distances: np.ndarray, odd: np.ndarray, neighbours: int = 10, max_passes: int = 20
) -> list[tuple[int, int]]:
    """A short perfect matching of the ``odd`` vertices: greedy, then 2-opt exchanges.

    Pairs are taken in order of increasing distance while both ends are free; then, for
    every matched pair (a, b) and each of a's ``neighbours`` nearest odd vertices c with
    partner d, the pairs are exchanged to (a, c), (b, d) when that is shorter. Passes
    repeat until none improves (at most ``max_passes``).

    Parameters
    ----------
    distances : np.ndarray, shape (N, N)
        Symmetric metric.
    odd : np.ndarray, shape (K,)
        Vertices to pair up; K is even.

    Returns
    -------
    list of (int, int)
        K / 2 vertex pairs covering every entry of ``odd`` once.

    """
    sub = distances[np.ix_(odd, odd)]
    mate = _greedy_mates(sub)
    nearest = np.argsort(sub, axis=1)[:, 1 : neighbours + 1]
    for _ in range(max_passes):
        if not _two_opt_pass(sub, mate, nearest):
            break
    return [(int(odd[a]), int(odd[b])) for a, b in enumerate(mate.tolist()) if a < b]


def _greedy_mates(sub: np.ndarray) -> np.ndarray:
    """Greedy matching on a (K, K) distance matrix: ``mate[a]`` is a's partner, shape (K,)."""
    n = sub.shape[0]
    i, j = np.triu_indices(n, k=1)
    order = np.argsort(sub[i, j], kind="stable")
    mate = np.full(n, -1, dtype=np.int64)
    left = n
    for a, b in zip(i[order].tolist(), j[order].tolist()):
        if mate[a] < 0 and mate[b] < 0:
            mate[a], mate[b] = b, a
            left -= 2
            if left == 0:
                break
    return mate


def _two_opt_pass(sub: np.ndarray, mate: np.ndarray, nearest: np.ndarray) -> bool:
    """One pass of pair exchanges (a, b), (c, d) -> (a, c), (b, d); True if any improved."""
    improved = False
    for a in range(sub.shape[0]):
        for c in nearest[a].tolist():
            b, d = int(mate[a]), int(mate[c])
            if c == b:
                continue
            if sub[a, c] + sub[b, d] < sub[a, b] + sub[c, d] - 1e-12:
                mate[a], mate[c], mate[b], mate[d] = c, a, d, b
                improved = True
    return improved


def two_opt_tour(
    tour: np.ndarray, distances: np.ndarray, neighbours: int = 12, max_passes: int = 50
) -> np.ndarray:
    """Shorten a cyclic tour by 2-opt exchanges with each vertex's nearest neighbours.

    For tour edges (a, b) and (c, d), with c among a's ``neighbours`` nearest vertices, the
    tour between b and c is reversed when d(a, c) + d(b, d) < d(a, b) + d(c, d). Passes
    repeat until none improves (at most ``max_passes``). The first vertex stays first.

    Parameters
    ----------
    tour : np.ndarray, shape (N,)
        Every vertex once, in tour order.
    distances : np.ndarray, shape (N, N)
        Symmetric metric.

    Returns
    -------
    np.ndarray, shape (N,)
        The same vertices in an order at most as long as ``tour``'s.

    """
    order = np.array(tour, dtype=np.int64)
    n = order.size
    if n < 5:
        return order
    nearest = np.argsort(distances, axis=1, kind="stable")[:, 1 : neighbours + 1]
    position = np.empty(n, dtype=np.int64)
    position[order] = np.arange(n)
    for _ in range(max_passes):
        if not _two_opt_tour_pass(order, position, distances, nearest):
            break
    return order


def _two_opt_tour_pass(
    order: np.ndarray, position: np.ndarray, distances: np.ndarray, nearest: np.ndarray
) -> bool:
    """One pass of segment reversals over every tour edge, in place; True if any shortened it."""
    n = order.size
    improved = False
    for i in range(n - 1):
        for c in nearest[order[i]].tolist():
            a, b = int(order[i]), int(order[i + 1])
            j = int(position[c])
            if j <= i + 1:  # only forward segments, so that order[0] never moves
                continue
            d = int(order[(j + 1) % n])
            if distances[a, c] + distances[b, d] < distances[a, b] + distances[c, d] - 1e-9:
                order[i + 1 : j + 1] = order[i + 1 : j + 1][::-1].copy()
                position[order[i + 1 : j + 1]] = np.arange(i + 1, j + 1)
                improved = True
    return improved


def expand_tour(tour: np.ndarray, predecessors: np.ndarray) -> np.ndarray:
    """Replace each tour step by its shortest path in the graph.

    Parameters
    ----------
    tour : np.ndarray, shape (N,)
        Cyclic vertex order.
    predecessors : np.ndarray, shape (N, N)
        ``predecessors[a, v]``: the vertex before v on a shortest path from a.

    Returns
    -------
    np.ndarray, shape (L,)
        Cyclic sequence in which consecutive entries are graph-adjacent.

    """
    sequence: list[int] = []
    for a, b in zip(tour.tolist(), np.roll(tour, -1).tolist()):
        path = [b]
        while path[-1] != a:
            path.append(int(predecessors[a, path[-1]]))
        sequence.extend(reversed(path[1:]))  # a ... (excluding b, which starts the next step)
    return np.asarray(sequence, dtype=np.int64)
