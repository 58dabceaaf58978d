"""Path reduced costs: a lower bound per column that sees the whole closed path.

Reduced-cost fixing (:mod:`spidermatch.solve.fixing`, :mod:`spidermatch.solve.colgen`)
rests on one inequality: for row multipliers y (sign-corrected) with reduced costs
``r = c - A^T y`` and the Lagrangian bound ``L(y) = sum_i y_i b_i(y) + sum_j min(0, r_j)``,
every feasible 0/1 vector x satisfies

    c^T x  =  y^T A x + r^T x  >=  sum_i y_i b_i(y) + sum_j min(0, r_j) + sum_j max(0, r_j) x_j
           =  L(y) + sum_j r+_j x_j,                       r+ = max(r, 0).

Fixing by reduced cost keeps only the one term ``r+_j`` of a column j. But a feasible
solution is one closed walk in the product graph that crosses every layer boundary exactly
once (CYC, CON and the connectivity cuts), so a walk that uses j = (u -> v) also pays r+ on
the rest of the walk: one edge e0 from layer L-1 into layer 0, a walk from e0's head to u,
and a walk from v to e0's tail in layer L-1. With shortest distances d under the
non-negative weights r+ (no edge into layer 0 on the way),

    F(u) = min_{e0} r+_{e0} + d(head(e0), u),      B(v) = min_{w in layer L-1} d(v, w),

every solution using a column j that does not enter layer 0 costs at least
``L(y) + F(u) + r+_j + B(v)``, and one using an edge j into layer 0 at least
``L(y) + r+_j + B(v)`` (relaxing that both ends belong to the same e0 only lowers the
bound). These *path reduced costs* (Irnich, Desaulniers, Desrosiers and Hadjar, 2010, for
routing) are never below ``r+`` and often far above it, so far fewer columns stay below a given
threshold (such as the LP's gap to the optimum) and the MIPs that must hold them are smaller
(measurements: bench/README.md, solver constants).

Distances are computed over the columns of one pricing pass only (reduced cost at most its
cutoff): a path that uses any other column costs more than the cutoff, so distances capped
at the cutoff are still lower bounds, and so is every path reduced cost built from them.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from spidermatch.model.product_graph import INTRA, ProductGraph


def _min_weight_matrix(tails: np.ndarray, heads: np.ndarray, weights: np.ndarray, size: int) -> sp.csr_matrix:
    """Adjacency (size, size) with the least weight of parallel edges; zero weights stay edges."""
    order = np.lexsort((weights, heads, tails))
    tails, heads, weights = tails[order], heads[order], weights[order]
    first = np.ones(tails.size, dtype=bool)
    first[1:] = (tails[1:] != tails[:-1]) | (heads[1:] != heads[:-1])
    return sp.csr_matrix((weights[first], (tails[first], heads[first])), shape=(size, size))


def _distances_from(tails, heads, weights, starts, start_weights, size, cap) -> np.ndarray:
    """Least ``start_weights[k] + d(starts[k], v)`` over k for every node v (size,), capped at ``cap``.

    A virtual node ``size`` carries the start weights as edges to the start nodes.
    """
    virtual = np.full(starts.size, size, dtype=np.int64)
    matrix = _min_weight_matrix(
        np.concatenate([tails, virtual]),
        np.concatenate([heads, starts]),
        np.concatenate([weights, start_weights]),
        size + 1,
    )
    distances = dijkstra(matrix, directed=True, indices=size, limit=cap)[:size]
    return np.minimum(distances, cap)


def path_reduced_costs(
    graph: ProductGraph, columns: np.ndarray, reduced: np.ndarray, cutoff: float
) -> np.ndarray:
    """Path reduced costs of the columns of one pricing pass.

    Parameters
    ----------
    graph : ProductGraph
    columns : np.ndarray, shape (k,)
        Edge ids: every column of reduced cost at most ``cutoff`` (and possibly others).
    reduced : np.ndarray, shape (k,)
        Their reduced costs ``r = c - A^T y`` for sign-corrected multipliers y.
    cutoff : float
        Every column of the full model not in ``columns`` has reduced cost above it.

    Returns
    -------
    np.ndarray, shape (k,)
        ``R_j >= max(r_j, 0)``: every feasible solution that uses column j costs at least
        ``L(y) + R_j``.

    """
    columns = np.asarray(columns, dtype=np.int64)
    positive = np.maximum(np.asarray(reduced, dtype=np.float64), 0.0)
    cap = max(float(cutoff), 0.0)
    layer, entry = np.divmod(columns, graph.block_size)
    crossing = graph.block_kind[entry] != INTRA
    next_layer = (layer + crossing) % graph.n_layers
    tails = layer * graph.n_target + graph.block_src[entry]
    heads = next_layer * graph.n_target + graph.block_dst[entry]
    into_layer_0 = crossing & (layer == graph.n_layers - 1)
    inner = ~into_layer_0
    size = graph.n_nodes
    forward = _distances_from(
        tails[inner], heads[inner], positive[inner], heads[into_layer_0], positive[into_layer_0], size, cap
    )
    last_layer = (graph.n_layers - 1) * graph.n_target + np.arange(graph.n_target, dtype=np.int64)
    backward = _distances_from(  # on the reversed graph, from every node of layer L-1
        heads[inner], tails[inner], positive[inner], last_layer, np.zeros(last_layer.size), size, cap
    )
    before = np.where(into_layer_0, 0.0, forward[tails])
    return before + positive + backward[heads]
