"""A cheap closed path through the product graph, to seed column generation near the optimum.

Without PES and ANS, the SpiderMatch ILP asks for the cheapest closed path through every layer
of the product graph, a shortest-path problem: per layer, the cheapest ways to enter each target
vertex, closed under the layer's intra edges (a Dijkstra run), pushed through the crossing edges
into the next layer. :func:`cheapest_closed_path` sweeps once, from the target vertex of
lowest feature cost for the first curve vertex, back to that vertex. The result is a heuristic:
a closed path that satisfies CYC and CON but not necessarily PES or ANS, and not always the
cheapest closed one. Nothing is claimed about its cost; it only says
*where* a near-optimal path of the full model runs. :func:`path_plausible` turns it into a set of
plausible targets per source vertex (the targets the path visits at any layer of that vertex,
within a few layers, grown by a few rings of the target mesh), so that a seed holds a whole band
of good paths and the restricted LP starts with duals close to the final ones.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from spidermatch.model.lazy_model import LazyModel
from spidermatch.model.product_graph import INTRA

logger = logging.getLogger(__name__)

PATH_RINGS = 1  # rings of the target mesh around the path's vertices
PATH_WINDOW = 1  # the path's vertices at layers within this many positions count for a layer


UNREACHED = 1e15  # entering cost standing for "cannot enter here" (far above any path's cost)


class _Sweep:
    """The shortest-path sweep over all layers, with every per-layer table built once.

    Per layer, the intra edges and the edges from a super-source (one to each target vertex,
    weighted by the cost of entering there) form one fixed sparse graph whose weights alone
    change; a Dijkstra run from the super-source closes the entering costs under intra walks.
    """

    def __init__(self, lazy: LazyModel) -> None:
        graph, n = lazy.graph, lazy.graph.n_target
        self.lazy, self.n = lazy, n
        self.intra_entries = np.flatnonzero(graph.block_kind == INTRA)
        cross = np.flatnonzero(graph.block_kind != INTRA)
        self.cross = cross[np.argsort(graph.block_dst[cross], kind="stable")]  # grouped by head
        heads = graph.block_dst[self.cross]
        self.cross_starts = np.searchsorted(heads, np.arange(n))
        rows = np.concatenate([graph.block_src[self.intra_entries], np.full(n, n)])
        cols = np.concatenate([graph.block_dst[self.intra_entries], np.arange(n)])
        pattern = sp.csr_matrix((np.arange(1.0, rows.size + 1), (rows, cols)), shape=(n + 1, n + 1))
        pattern.sort_indices()
        self.pattern, self.slot_of = pattern, pattern.data.astype(np.int64) - 1
        self.cross_src = graph.block_src[self.cross]

    def _layer_costs(self, layer: int) -> tuple[np.ndarray, np.ndarray]:
        """Costs of the layer's intra edges and of its crossing edges (grouped by head)."""
        first = layer * self.lazy.graph.block_size
        return self.lazy.costs(first + self.intra_entries), self.lazy.costs(first + self.cross)

    def _closure(self, entering: np.ndarray, intra_costs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cheapest cost of reaching each target vertex after entering and walking intra edges.

        Returns the costs (V_Y,) and each vertex's predecessor on its walk (V_Y,), ``n`` (the
        super-source) where the walk enters the layer.
        """
        offset = entering.min() - 1.0  # super-source weights must stay positive to count as edges
        weights = np.concatenate([intra_costs + 1e-300, entering - offset])
        self.pattern.data = weights[self.slot_of]
        distance, previous = dijkstra(self.pattern, indices=self.n, return_predecessors=True)
        return distance[: self.n] + offset, previous[: self.n].astype(np.int32)

    def run(self, start: np.ndarray) -> tuple[np.ndarray, list, list]:
        """Sweep from entering costs ``start`` (V_Y,) at layer 0 back to layer 0.

        Returns the entering costs at layer L (V_Y,) and, per layer, the costs of reaching
        each vertex (V_Y,) and its predecessor within the layer (V_Y,).
        """
        entering, reached_by_layer, previous_by_layer = start, [], []
        for layer in range(self.lazy.graph.n_layers):
            intra_costs, cross_costs = self._layer_costs(layer)
            reached, previous = self._closure(entering, intra_costs)
            reached_by_layer.append(reached)
            previous_by_layer.append(previous)
            candidate = reached[self.cross_src] + cross_costs
            entering = np.minimum(np.minimum.reduceat(candidate, self.cross_starts), UNREACHED)
        return entering, reached_by_layer, previous_by_layer

    def trace(self, end: int, reached_by_layer: list, previous_by_layer: list) -> np.ndarray:
        """Edge ids of the swept path that enters layer 0 (= layer L) at ``end``, sorted.

        Walks back layer by layer: the crossing edge into the current vertex that attains its
        entering cost, then back along the layer's cheapest intra walk to where it was entered.
        """
        graph, block, n = self.lazy.graph, self.lazy.graph.block_size, self.n
        edges, vertex = [], end
        stops = np.append(self.cross_starts[1:], self.cross.size)
        for layer in range(graph.n_layers - 1, -1, -1):
            _, cross_costs = self._layer_costs(layer)
            into = slice(self.cross_starts[vertex], stops[vertex])
            options = reached_by_layer[layer][self.cross_src[into]] + cross_costs[into]
            pick = int(np.argmin(options))
            edges.append(layer * block + int(self.cross[into][pick]))
            vertex = int(self.cross_src[into][pick])
            previous = previous_by_layer[layer]
            while previous[vertex] != n:
                before = int(previous[vertex])
                edges.append(layer * block + self._intra_entry(before, vertex))
                vertex = before
        return np.unique(np.asarray(edges, dtype=np.int64))

    def _intra_entry(self, a: int, b: int) -> int:
        slot = self.pattern.indptr[a] + np.searchsorted(
            self.pattern.indices[self.pattern.indptr[a] : self.pattern.indptr[a + 1]], b
        )
        return int(self.intra_entries[self.slot_of[slot]])


def cheapest_closed_path(lazy: LazyModel, start_vertex: int | None = None) -> tuple[np.ndarray, float]:
    """A closed path through every layer (CYC and CON hold; PES, ANS not checked).

    It is the cheapest such path among those entering layer 0 at ``start_vertex`` (default:
    the target of lowest feature cost for the first curve vertex).

    Returns
    -------
    edges : np.ndarray, shape (k,)
        Sorted edge ids of the path.
    cost : float
        Its cost (an upper bound on nothing: the path may violate PES or ANS).

    """
    sweep = _Sweep(lazy)
    if start_vertex is None:
        start_vertex = int(np.argmin(lazy.vertex_costs[lazy.curve.vertices[0]]))
    start = np.full(lazy.graph.n_target, UNREACHED)
    start[start_vertex] = 0.0
    _, reached_by_layer, previous_by_layer = sweep.run(start)
    edges = sweep.trace(start_vertex, reached_by_layer, previous_by_layer)
    cost = float(lazy.costs(edges).sum())
    logger.info("closed path seed: %d edges, cost %.8g", edges.size, cost)
    return edges, cost


def path_plausible(
    lazy: LazyModel, path: np.ndarray, rings: int = PATH_RINGS, window: int = PATH_WINDOW
) -> np.ndarray:
    """Targets near ``path`` (edge ids) per source vertex, shape (V_X, V_Y), bool.

    Target y is plausible for source vertex p if the path visits y, or a vertex within
    ``rings`` target-mesh edges of y, at a layer within ``window`` positions of a layer of p.
    """
    graph, curve = lazy.graph, lazy.curve
    layer, entry, next_layer = lazy.split(path)
    visited = np.zeros((graph.n_layers, graph.n_target), dtype=bool)
    visited[layer, graph.block_src[entry]] = True
    visited[next_layer, graph.block_dst[entry]] = True
    near = visited.copy()
    for shift in range(1, window + 1):
        near |= np.roll(visited, shift, axis=0) | np.roll(visited, -shift, axis=0)
    edges = graph.target_edges
    adjacency = sp.csr_matrix(
        (np.ones(edges.shape[0]), (edges[:, 0], edges[:, 1])), shape=(graph.n_target,) * 2
    )
    adjacency = adjacency + sp.identity(graph.n_target, format="csr")
    source_of_layer = sp.csr_matrix(
        (np.ones(graph.n_layers), (curve.vertices, np.arange(graph.n_layers))),
        shape=(lazy.vertex_costs.shape[0], graph.n_layers),
    )
    plausible = source_of_layer @ sp.csr_matrix(near, dtype=np.float64)
    for _ in range(rings):
        plausible = plausible @ adjacency
    return plausible.toarray() > 0
