"""Connectivity cuts: keep the SpiderMatch solution one closed path.

The ILP of method.md admits, besides the path through all layers, detached
cycles of intra-layer edges: in a self-intersection layer they can pad the
out-flows that (PES) compares, which ANS does not count. A single closed walk
never has them, so for every node set S inside one layer and every intra edge e
with both ends in S

    sum_{f leaving S} x_f  -  x_e  >=  0

holds for every single closed walk: a walk that uses e must leave S afterwards,
since its stretch in this layer ends with the one edge to the next layer. (The
node form ``out(S) - out(v) >= 0`` is *not* valid here: a walk may pass through v
twice in one layer, a -> b -> a, and then out(v) = 2 > out(S) = 1.) The cuts are
added lazily, only for the detached cycles a solution actually has, and up front
for 2-cycles (:func:`two_cycle_components`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from spidermatch.model.correspondence import _euler_walk, active_edges
from spidermatch.model.product_graph import INTRA, ProductGraph
from spidermatch.model.solution import used_columns


def detached_components(graph: ProductGraph, x: np.ndarray) -> list[np.ndarray]:
    """Node sets of the active edges not on the closed walk through layer 0's entry.

    Returns
    -------
    list of np.ndarray
        Each array holds product vertex ids ``layer * V_Y + y`` of one detached component.

    """
    if np.shape(x) != (graph.n_edges,):
        active_edges(graph, x)  # raises SolutionError naming both sizes
    return detached_components_of_edges(graph, used_columns(x))


def detached_components_of_edges(graph: ProductGraph, edge_ids: np.ndarray) -> list[np.ndarray]:
    """:func:`detached_components` of the solution that uses exactly the edges ``edge_ids`` (k,)."""
    tuples = graph.edge_tuples(edge_ids)
    walk = walk_through_layer_0(tuples)
    if walk is None:
        return []  # not a CYC-feasible solution; nothing to separate here
    rest = np.setdiff1d(np.arange(len(tuples)), walk)
    if rest.size == 0:
        return []
    tails = tuples[rest, 0] * graph.n_target + tuples[rest, 1]
    heads = tuples[rest, 2] * graph.n_target + tuples[rest, 3]
    nodes, index = np.unique(np.concatenate([tails, heads]), return_inverse=True)
    adjacency = sp.coo_matrix(
        (np.ones(rest.size), (index[: rest.size], index[rest.size :])), shape=(nodes.size, nodes.size)
    )
    n_components, labels = connected_components(adjacency, directed=False)
    return [nodes[labels == c] for c in range(n_components)]


def walk_through_layer_0(tuples: np.ndarray) -> list[int] | None:
    """Indices of ``tuples`` (N, 5) on the closed walk through the one entry of layer 0, in order.

    None if the edges do not cross into layer 0 exactly once. Edges off that walk (detached
    cycles) are not in the list.
    """
    crossing_into_0 = tuples[(tuples[:, 4] != INTRA) & (tuples[:, 2] == 0)]
    if len(crossing_into_0) != 1:
        return None
    return _euler_walk(tuples, (0, int(crossing_into_0[0, 3])))


def is_closed_path(graph: ProductGraph, x_sub: np.ndarray, columns: np.ndarray | None = None) -> bool:
    """Whether x_sub (k,) over the edge ids ``columns`` (k,; all edges if None) has no detached cycle."""
    used = used_columns(x_sub)
    return not detached_components_of_edges(graph, used if columns is None else columns[used])


def connectivity_cuts(
    graph: ProductGraph, components: list[np.ndarray]
) -> tuple[sp.csr_matrix, np.ndarray, np.ndarray]:
    """Rows cutting off the given detached components (one per intra edge inside each).

    Returns
    -------
    rows : scipy.sparse.csr_matrix, shape (k, |E_P|)
    lower, upper : np.ndarray, shape (k,)
        ``0 <= rows @ x <= inf``.

    """
    order = np.argsort(graph.block_src, kind="stable")
    starts = np.searchsorted(graph.block_src[order], np.arange(graph.n_target + 1))
    row_ids, col_ids, values = [], [], []
    n_rows = 0
    for nodes in components:
        layer = int(nodes[0] // graph.n_target)
        members = nodes % graph.n_target
        inside = np.zeros(graph.n_target, dtype=bool)
        inside[members] = True
        entries = np.concatenate([order[starts[y] : starts[y + 1]] for y in members])
        stays_inside = (graph.block_kind[entries] == INTRA) & inside[graph.block_dst[entries]]
        leaving = entries[~stays_inside] + layer * graph.block_size
        for edge in entries[stays_inside] + layer * graph.block_size:
            row_ids.append(np.full(leaving.size + 1, n_rows))
            col_ids.append(np.append(leaving, edge))
            values.append(np.append(np.ones(leaving.size), -1.0))
            n_rows += 1
    rows = sp.coo_matrix(
        (np.concatenate(values), (np.concatenate(row_ids), np.concatenate(col_ids))),
        shape=(n_rows, graph.n_edges),
    ).tocsr()
    rows.sum_duplicates()
    return rows, np.zeros(n_rows), np.full(n_rows, np.inf)


def two_cycle_components(graph: ProductGraph, layers: np.ndarray, columns: np.ndarray) -> list[np.ndarray]:
    """Node pairs {(l, a), (l, b)} with both intra edges a->b and b->a among ``columns``.

    Parameters
    ----------
    graph : ProductGraph
    layers : np.ndarray, shape (k,)
        Layers to look in.
    columns : np.ndarray, shape (m,)
        Full-model edge ids.

    Returns
    -------
    list of np.ndarray
        Product vertex ids ``[l * V_Y + a, l * V_Y + b]`` (a < b), one array per pair.

    """
    layer, k = np.divmod(np.asarray(columns, dtype=np.int64), graph.block_size)
    keep = (graph.block_kind[k] == INTRA) & np.isin(layer, layers)
    layer, src, dst = layer[keep], graph.block_src[k[keep]], graph.block_dst[k[keep]]
    n = graph.n_target
    forward = (layer * n + src) * n + dst
    backward = (layer * n + dst) * n + src
    both = (src < dst) & np.isin(forward, backward)
    first, second = layer[both] * n + src[both], layer[both] * n + dst[both]
    return [np.array(pair) for pair in zip(first.tolist(), second.tolist())]
