"""Single-commodity flow rows that keep a layer's stretch of the path in one piece.

The connectivity cuts of :mod:`spidermatch.solve.connectivity` remove one detached node
set at a time, and a MIP can answer each with another one nearby, re-solve after re-solve
(measurements: bench/README.md, solver constants). For a chosen layer ``l`` the rows below
exclude every detached cycle of that layer at once.

A single closed path crosses each layer boundary once, so inside layer ``l`` it is one walk
``e_1, ..., e_m`` of intra edges from the vertex where it enters the layer to the vertex
where it leaves. Give each intra edge ``e`` of the layer a continuous variable ``g_e``, on
the walk ``g_{e_i} = m - i + 1`` (the walk's edges from ``e_i`` on) and 0 elsewhere. Then,
with ``K`` the number of intra columns of the layer and ``z_v`` the flow entering ``(l, v)``
from layer ``l - 1``,

    (FLOW-CAP)  g_e - K x_e <= 0                                       for every intra edge e
    (FLOW-BAL)  sum_{e out of v} g_e - sum_{e into v} (g_e - x_e) - K z_v <= 0   for every v

hold: along the walk the out-going ``g`` equals the in-coming ``g`` minus one at every
inner visit, and only the entry vertex (``z_v = 1``) sends out more (``m <= K``). A detached
cycle ``C`` cannot satisfy them: summing FLOW-BAL over its vertices, which nothing enters
from the previous layer, leaves ``sum_{e in C} x_e <= 0``. So the rows are valid for every
single closed path of the full model and cut off every solution with a detached cycle in
the layer; a MIP with them needs no re-solve for that layer. Their LP relaxation is weak
(big-M), so they are added only for layers where a detached cycle has been seen, together
with the other layers of the same source vertex (PES couples their out-flows).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from spidermatch.model.product_graph import INTRA, ProductGraph
from spidermatch.model.solution import used_columns
from spidermatch.solve.connectivity import walk_through_layer_0


@dataclass(frozen=True, eq=False)
class LayerFlow:
    """The flow variables and rows of some layers over a restricted column set.

    Attributes
    ----------
    layers : np.ndarray, shape (k_l,)
        The layers covered, sorted.
    flow_of : np.ndarray, shape (n_flow,)
        Position in the restricted column set of the intra edge each flow variable follows.
    flow_upper : np.ndarray, shape (n_flow,)
        Upper bound ``K`` of each flow variable (the big-M of its layer).
    rows_x : scipy.sparse.csr_matrix, shape (n_rows, k)
        Coefficients of the rows on the restricted columns (k of them).
    rows_flow : scipy.sparse.csr_matrix, shape (n_rows, n_flow)
        Coefficients of the rows on the flow variables.
    upper : np.ndarray, shape (n_rows,)
        Right-hand sides (all 0; every row is ``<=``).

    """

    layers: np.ndarray
    flow_of: np.ndarray
    flow_upper: np.ndarray
    rows_x: sp.csr_matrix
    rows_flow: sp.csr_matrix
    upper: np.ndarray

    @property
    def n_flow(self) -> int:
        """Number of flow variables."""
        return int(self.flow_of.size)


def layer_flow(graph: ProductGraph, columns: np.ndarray, layers: np.ndarray) -> LayerFlow:
    """FLOW-CAP and FLOW-BAL (module docstring) for ``layers`` over the sorted edge ids ``columns``.

    Parameters
    ----------
    graph : ProductGraph
    columns : np.ndarray, shape (k,)
        Sorted full-model edge ids of the restricted model.
    layers : np.ndarray, shape (k_l,)
        Layers to cover.

    """
    columns = np.asarray(columns, dtype=np.int64)
    layers = np.unique(np.asarray(layers, dtype=np.int64))
    layer, entry = np.divmod(columns, graph.block_size)
    intra = graph.block_kind[entry] == INTRA
    chosen = np.isin(layer, layers)
    flow_of = np.flatnonzero(intra & chosen)
    per_layer = np.bincount(layer[flow_of], minlength=graph.n_layers)
    big_m = np.maximum(per_layer, 1).astype(np.float64)
    into = np.flatnonzero(~intra & np.isin((layer + 1) % graph.n_layers, layers))  # crossings into them
    n, k, n_flow = graph.n_target, columns.size, flow_of.size
    # node rows: one per (layer, vertex) an intra flow edge touches
    tail = layer[flow_of] * n + graph.block_src[entry[flow_of]]
    head = layer[flow_of] * n + graph.block_dst[entry[flow_of]]
    nodes, node_index = np.unique(np.concatenate([tail, head]), return_inverse=True)
    tail_row, head_row = node_index[:n_flow], node_index[n_flow:]
    entered = ((layer[into] + 1) % graph.n_layers) * n + graph.block_dst[entry[into]]
    enters_node = np.isin(entered, nodes)
    into, entered = into[enters_node], entered[enters_node]
    entered_row = np.searchsorted(nodes, entered)
    n_nodes = nodes.size
    flow = np.arange(n_flow)
    # FLOW-CAP rows 0..n_flow-1, FLOW-BAL rows n_flow..n_flow+n_nodes-1
    cap_x = (flow, flow_of, -big_m[layer[flow_of]])
    bal_x_head = (n_flow + head_row, flow_of, np.ones(n_flow))
    bal_x_entry = (n_flow + entered_row, into, -big_m[(layer[into] + 1) % graph.n_layers])
    rows_x = _coo([cap_x, bal_x_head, bal_x_entry], (n_flow + n_nodes, k))
    cap_g = (flow, flow, np.ones(n_flow))
    bal_g_out = (n_flow + tail_row, flow, np.ones(n_flow))
    bal_g_in = (n_flow + head_row, flow, -np.ones(n_flow))
    rows_flow = _coo([cap_g, bal_g_out, bal_g_in], (n_flow + n_nodes, n_flow))
    return LayerFlow(layers, flow_of, big_m[layer[flow_of]], rows_x, rows_flow, np.zeros(n_flow + n_nodes))


def _coo(parts, shape) -> sp.csr_matrix:
    rows, cols, values = (np.concatenate([part[i] for part in parts]) for i in range(3))
    matrix = sp.coo_matrix((values, (rows, cols)), shape=shape).tocsr()
    matrix.sum_duplicates()
    return matrix


def flow_values(graph: ProductGraph, columns: np.ndarray, x_sub: np.ndarray, flow: LayerFlow) -> np.ndarray:
    """The flow variables (n_flow,) of a single closed path x_sub (k,) over ``columns``.

    Each intra edge of a covered layer gets the number of edges of the path's walk in that
    layer from it on (module docstring); edges off the path get 0. Raises ``ValueError`` if
    x_sub is not one closed walk crossing every boundary once.
    """
    used = used_columns(x_sub)
    tuples = graph.edge_tuples(columns[used])
    order = walk_through_layer_0(tuples)
    if order is None:
        raise ValueError("the solution does not cross into layer 0 exactly once")
    if len(order) != len(tuples):
        raise ValueError("the solution is not one closed walk")
    walk = used[np.asarray(order, dtype=np.int64)]
    walk_layer, walk_kind = tuples[order, 0], tuples[order, 4]
    covered = np.isin(walk_layer, flow.layers) & (walk_kind == INTRA)
    # remaining intra edges of the same layer's stretch, counted from the end of the walk
    stretch = np.cumsum(np.concatenate([[0], walk_kind[:-1] != INTRA]))  # one id per layer stretch
    remaining = np.zeros(walk.size)
    for stretch_id in np.unique(stretch[covered]):
        where = np.flatnonzero(covered & (stretch == stretch_id))
        remaining[where] = np.arange(where.size, 0, -1)
    position_of = np.full(columns.size, -1, dtype=np.int64)
    position_of[flow.flow_of] = np.arange(flow.n_flow)
    result = np.zeros(flow.n_flow)
    result[position_of[walk[covered]]] = remaining[covered]
    return result


class SessionFlows:
    """The flow rows of a growing set of layers in one HiGHS session over ``columns``.

    The session's first ``columns.size`` variables are the restricted model's edges; each
    :meth:`cover` appends the flow variables of some more layers after whatever the session
    already holds, and its rows.

    Parameters
    ----------
    graph : ProductGraph
    columns : np.ndarray, shape (k,)
        Sorted full-model edge ids of the session's first k variables.
    session : spidermatch.solve.highs.HighsSession

    """

    def __init__(self, graph: ProductGraph, columns: np.ndarray, session) -> None:
        self.graph = graph
        self.columns = np.asarray(columns, dtype=np.int64)
        self.session = session
        self.blocks: list[LayerFlow] = []
        self.covered: set[int] = set()

    def cover(self, layers) -> int:
        """Add the flow rows of those ``layers`` not covered yet; returns the flow variables added."""
        new = np.array(sorted(set(int(layer) for layer in layers) - self.covered), dtype=np.int64)
        if new.size == 0:
            return 0
        flow = layer_flow(self.graph, self.columns, new)
        before = self.session.n_vars
        self.session.add_continuous_columns(np.zeros(flow.n_flow), flow.flow_upper)
        padding = sp.csr_matrix((flow.upper.size, before - self.columns.size))
        rows = sp.hstack([flow.rows_x, padding, flow.rows_flow], format="csr")
        self.session.add_rows(rows, np.full(flow.upper.size, -np.inf), flow.upper)
        self.blocks.append(flow)
        self.covered.update(new.tolist())
        return flow.n_flow

    def start_vector(self, x_sub: np.ndarray) -> np.ndarray:
        """A path x_sub (k,) with the values of every flow variable appended (session order)."""
        parts = [np.asarray(x_sub, dtype=np.float64)]
        parts += [flow_values(self.graph, self.columns, x_sub, block) for block in self.blocks]
        return np.concatenate(parts)
