"""Connectivity cuts in the LP relaxation: separated on fractional solutions, priced exactly.

The connectivity cuts of :mod:`spidermatch.solve.connectivity`,

    sum_{f leaving S} x_f  -  x_e  >=  0        (S a node set inside one layer, e an intra edge in S)

hold for every single closed path, so they are valid rows of the LP relaxation too. The plain
LP can violate them: its solution may send a fraction of a unit round a cycle inside a
self-intersection layer, where PES pays for the out-flow and nothing forces it on to the next
layer. Column generation (:mod:`spidermatch.solve.colgen`) therefore adds the violated ones
between its pricing rounds, which raises the LP bound ``L`` and with it shrinks every restricted
MIP that certifies against it (measured: docs/solver_failures.md, "Connectivity cuts in the LP
relaxation").

Separation is exact for the support of a solution ``x``: for an intra edge ``e = (a, b)`` of
layer ``l`` with ``x_e > 0`` the least ``sum_{f leaving S} x_f`` over the sets S holding a and
b is a minimum cut between {a, b} and the layer's exits (edges to the next layer), in the
layer's support graph with capacities ``x``; the cut is violated exactly when that minimum is
below ``x_e``, and the source side of the cut is the set S to use.

Pricing sees a cut through its dual ``mu >= 0``: a column ``j`` has reduced cost
``c_j - y^T A_j - sum_k mu_k G_kj``, so the columns leaving some S get cheaper and the edges e
dearer. :class:`CutDuals` holds that correction, sparse over the full model's columns. The
Lagrangian bound keeps its form: the cut rows have right-hand side 0, and for any closed path
``mu^T G x >= 0`` (:mod:`spidermatch.solve.fixing`'s argument with the cut rows among the rows).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, maximum_flow

from spidermatch.model.product_graph import INTRA, ProductGraph

FLOW_SCALE = 1_000_000  # capacities are x scaled to integers (scipy's maximum_flow wants int32)
MIN_VIOLATION = 1e-4  # a cut counts as violated when x_e exceeds the minimum cut by this much
SUPPORT = 1e-6  # edges with x above this form the support graph
LP_CUT_ROUNDS = 20  # separations of connectivity cuts in the LP at most (each then solved again) ...
LP_CUT_MIN_GAIN = 2e-5  # ... while the last one raised the LP's value by at least this (relative)
LP_CUT_TIME_SHARE = 0.25  # ... and the LP has used at most this share of the time limit (the MIPs need it)


@dataclass(frozen=True, eq=False)
class CutDuals:
    """What cut duals subtract from reduced costs: ``G^T mu``, sparse over the full model.

    Attributes
    ----------
    columns : np.ndarray, shape (k,)
        Sorted edge ids with a non-zero correction.
    values : np.ndarray, shape (k,)
        ``sum_k mu_k G_kj`` for each of them.

    """

    columns: np.ndarray
    values: np.ndarray

    @classmethod
    def none(cls) -> CutDuals:
        """No cuts: no correction."""
        return cls(np.zeros(0, dtype=np.int64), np.zeros(0))

    @classmethod
    def of(cls, rows: sp.csr_matrix | None, mu: np.ndarray) -> CutDuals:
        """The correction of cut rows (k, n_edges) with duals ``mu`` (k,)."""
        if rows is None or rows.shape[0] == 0:
            return cls.none()
        entries = rows.tocoo()
        columns, where = np.unique(entries.col.astype(np.int64), return_inverse=True)
        values = np.zeros(columns.size)
        np.add.at(values, where, mu[entries.row] * entries.data)
        nonzero = values != 0.0
        return cls(columns[nonzero], values[nonzero])

    def subtract_from(self, reduced: np.ndarray, first_column: int) -> None:
        """Subtract the correction in place from ``reduced`` (m,).

        ``reduced`` holds the reduced costs of the columns ``first_column .. first_column + m - 1``.
        """
        lo, hi = np.searchsorted(self.columns, [first_column, first_column + reduced.size])
        reduced[self.columns[lo:hi] - first_column] -= self.values[lo:hi]


def violated_cut_sets(graph: ProductGraph, columns: np.ndarray, x: np.ndarray) -> list[np.ndarray]:
    """Node sets S of connectivity cuts that ``x`` violates, found by minimum cuts layer by layer.

    Parameters
    ----------
    graph : ProductGraph
    columns : np.ndarray, shape (k,)
        Edge ids of the restricted LP's columns.
    x : np.ndarray, shape (k,)
        Its solution.

    Returns
    -------
    list of np.ndarray
        Product vertex ids ``layer * V_Y + y`` of each set (one layer each), as
        :func:`~spidermatch.solve.connectivity.connectivity_cuts` takes them.

    """
    active = x > SUPPORT
    tuples = graph.edge_tuples(np.asarray(columns)[active])
    values = np.asarray(x)[active]
    intra = tuples[:, 4] == INTRA
    sets = []
    for layer in np.unique(tuples[intra, 0]):
        inside, leaving = (tuples[:, 0] == layer) & intra, (tuples[:, 0] == layer) & ~intra
        found = _violated_in_layer(tuples[inside], values[inside], tuples[leaving], values[leaving])
        sets.extend(layer * graph.n_target + nodes for nodes in found)
    return sets


def _violated_in_layer(
    intra: np.ndarray, x_intra: np.ndarray, leaving: np.ndarray, x_leaving: np.ndarray
) -> list[np.ndarray]:
    """Target vertex sets of violated cuts in one layer (intra edges (m, 5), edges to the next (p, 5))."""
    nodes = np.unique(np.concatenate([intra[:, 1], intra[:, 3], leaving[:, 1]]))
    n = nodes.size
    sink, source = n, n + 1
    tails, heads = np.searchsorted(nodes, intra[:, 1]), np.searchsorted(nodes, intra[:, 3])
    exits = np.searchsorted(nodes, leaving[:, 1])
    base_rows = np.concatenate([tails, exits])
    base_cols = np.concatenate([heads, np.full(exits.size, sink)])
    base_caps = np.rint(np.concatenate([x_intra, x_leaving]) * FLOW_SCALE)
    unbounded = np.iinfo(np.int32).max // 4
    covered = np.zeros(n, dtype=bool)  # inside a set found already: its edges' cuts come with it
    sets = []
    for edge in np.argsort(-x_intra, kind="stable"):
        a, b = tails[edge], heads[edge]
        if covered[a] and covered[b]:
            continue
        capacities = sp.csr_matrix(
            (np.append(base_caps, [unbounded, unbounded]).astype(np.int64),
             (np.append(base_rows, [source, source]), np.append(base_cols, [a, b]))),
            shape=(n + 2, n + 2),
        )  # fmt: skip
        capacities.sum_duplicates()
        capacities.data = np.minimum(capacities.data, unbounded)
        capacities = capacities.astype(np.int32)
        flow = maximum_flow(capacities, source, sink)
        if flow.flow_value >= (x_intra[edge] - MIN_VIOLATION) * FLOW_SCALE:
            continue
        side = _source_side(capacities, flow.flow, source)
        side = side[side < n]
        covered[side] = True
        sets.append(nodes[side])
    return sets


def _source_side(capacities: sp.csr_matrix, flow: sp.csr_matrix, source: int) -> np.ndarray:
    """Vertices reachable from ``source`` in the residual graph of a maximum flow."""
    residual = (capacities.astype(np.int64) - flow.astype(np.int64)).tocsr()
    residual.data = (residual.data > 0).astype(np.int8)
    residual.eliminate_zeros()
    return np.sort(breadth_first_order(residual, source, directed=True, return_predecessors=False))
