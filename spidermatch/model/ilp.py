"""The SpiderMatch integer linear program (method.md section 5).

One binary variable x_e per product edge, minimise c^T x subject to the four
constraint families, each built by its own function as a sparse block with row
bounds. Blocks are stacked into one column-wise matrix for the solver.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from spidermatch.model.curve import SpiderCurve
from spidermatch.model.product_graph import INTRA, STAY, ProductGraph

logger = logging.getLogger(__name__)

FAMILIES = ("CYC", "CON", "PES", "ANS")


@dataclass(frozen=True, eq=False)
class ConstraintBlock:
    """Rows ``lower <= A x <= upper`` of one constraint family.

    Attributes
    ----------
    name : str
    rows, cols : np.ndarray, shape (nnz,)
        Coordinates of the non-zeros (row within the block, product edge).
    values : np.ndarray, shape (nnz,)
    lower, upper : np.ndarray, shape (n_rows,)

    """

    name: str
    rows: np.ndarray
    cols: np.ndarray
    values: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    @property
    def n_rows(self) -> int:
        """Number of constraints in the block."""
        return int(self.lower.shape[0])


@dataclass(frozen=True, eq=False)
class IlpModel:
    """``min c^T x  s.t.  row_lower <= A x <= row_upper,  x in {0, 1}^n``.

    Attributes
    ----------
    costs : np.ndarray, shape (n,)
    matrix : scipy.sparse.csc_matrix, shape (m, n)
    row_lower, row_upper : np.ndarray, shape (m,)
    row_families : dict[str, tuple[int, int]]
        Row range [start, stop) of each constraint family.

    """

    costs: np.ndarray
    matrix: sp.csc_matrix
    row_lower: np.ndarray
    row_upper: np.ndarray
    row_families: dict

    @property
    def n_vars(self) -> int:
        """Number of binary variables n."""
        return int(self.costs.shape[0])

    @property
    def n_rows(self) -> int:
        """Number of constraints m."""
        return int(self.row_lower.shape[0])

    @property
    def nnz(self) -> int:
        """Non-zeros of the constraint matrix."""
        return int(self.matrix.nnz)


def cyc_block(graph: ProductGraph) -> ConstraintBlock:
    """(CYC) every layer boundary is crossed once.

    For every layer l:  sum_{e inter or stay, leaving layer l} x_e = 1.   (L rows)
    """
    crossing = np.flatnonzero(graph.block_kind != INTRA)
    cols = (np.arange(graph.n_layers)[:, None] * graph.block_size + crossing[None, :]).ravel()
    rows = np.repeat(np.arange(graph.n_layers), crossing.size)
    ones = np.ones(graph.n_layers)
    return ConstraintBlock("CYC", rows, cols, np.ones(cols.size), ones, ones)


def con_block(graph: ProductGraph) -> ConstraintBlock:
    """(CON) flow conservation.

    For every product vertex v = (l, y):  sum_{e leaving v} x_e - sum_{e entering v} x_e = 0.
    (L |V_Y| rows; every edge has +1 at its tail and -1 at its head.)
    """
    edges = np.arange(graph.n_edges)
    tail = graph.layer * graph.n_target + graph.src
    head = graph.next_layer * graph.n_target + graph.dst
    rows = np.concatenate([tail, head])
    values = np.concatenate([np.ones(graph.n_edges), -np.ones(graph.n_edges)])
    zeros = np.zeros(graph.n_nodes)
    return ConstraintBlock("CON", rows, np.concatenate([edges, edges]), values, zeros, zeros)


def pes_block(graph: ProductGraph, curve: SpiderCurve) -> ConstraintBlock:
    """(PES) preserve the curve's self-intersections.

    For every duplicate layer q (c_q = c_p for its first occurrence p < q) and every y:
        sum_{e leaving (p, y)} x_e - sum_{e leaving (q, y)} x_e = 0.
    (D |V_Y| rows for the D duplicate layers.)
    """
    duplicates = curve.duplicate_layers
    first = curve.first_layer[duplicates]
    n_dup, block, n_target = duplicates.size, graph.block_size, graph.n_target
    block_cols = np.arange(block)
    row_of_src = np.arange(n_dup)[:, None] * n_target + graph.block_src[None, :]
    first_cols = first[:, None] * block + block_cols[None, :]
    dup_cols = duplicates[:, None] * block + block_cols[None, :]
    rows = np.concatenate([row_of_src.ravel(), row_of_src.ravel()])
    cols = np.concatenate([first_cols.ravel(), dup_cols.ravel()])
    values = np.concatenate([np.ones(first_cols.size), -np.ones(dup_cols.size)])
    zeros = np.zeros(n_dup * n_target)
    return ConstraintBlock("PES", rows, cols, values, zeros, zeros)


def ans_block(graph: ProductGraph, curve: SpiderCurve) -> ConstraintBlock:
    """(ANS) avoid new self-intersections.

    For every target vertex y:  sum x_e <= 1 over the non-degenerate edges
    (intra and inter, a != b) entering y whose source and destination layers both
    hold curve vertices that are not self-intersections.   (|V_Y| rows)
    """
    free_layer = ~curve.is_intersection_layer
    layers = np.arange(graph.n_layers)
    intra = np.flatnonzero(graph.block_kind == INTRA)
    inter = np.flatnonzero((graph.block_kind != INTRA) & (graph.block_kind != STAY))
    intra_layers = layers[free_layer]
    inter_layers = layers[free_layer & np.roll(free_layer, -1)]
    cols = np.concatenate(
        [
            (intra_layers[:, None] * graph.block_size + intra[None, :]).ravel(),
            (inter_layers[:, None] * graph.block_size + inter[None, :]).ravel(),
        ]
    )
    rows = graph.block_dst[cols % graph.block_size]
    lower = np.full(graph.n_target, -np.inf)
    return ConstraintBlock("ANS", rows, cols, np.ones(cols.size), lower, np.ones(graph.n_target))


def build_model(
    graph: ProductGraph,
    curve: SpiderCurve,
    costs: np.ndarray,
    families: tuple[str, ...] = FAMILIES,
) -> IlpModel:
    """Stack the chosen constraint families into one column-wise model.

    Parameters
    ----------
    graph : ProductGraph
    curve : SpiderCurve
        Must have ``graph.n_layers`` positions.
    costs : np.ndarray, shape (|E_P|,)
    families : tuple of str
        Subset of ("CYC", "CON", "PES", "ANS"), e.g. for ablations.

    """
    if curve.length != graph.n_layers:
        raise ValueError(f"curve has {curve.length} positions, product graph {graph.n_layers} layers")
    if costs.shape != (graph.n_edges,):
        raise ValueError(f"costs must have shape ({graph.n_edges},), got {costs.shape}")
    unknown = set(families) - set(FAMILIES)
    if unknown:
        raise ValueError(f"unknown constraint families {sorted(unknown)}; choose from {FAMILIES}")
    builders = {
        "CYC": lambda: cyc_block(graph),
        "CON": lambda: con_block(graph),
        "PES": lambda: pes_block(graph, curve),
        "ANS": lambda: ans_block(graph, curve),
    }
    blocks = [builders[name]() for name in FAMILIES if name in families]
    return stack_blocks(blocks, costs)


def stack_blocks(blocks: list[ConstraintBlock], costs: np.ndarray) -> IlpModel:
    """Concatenate constraint blocks row-wise into an :class:`IlpModel`."""
    offsets = np.cumsum([0] + [b.n_rows for b in blocks])
    rows = np.concatenate([b.rows + off for b, off in zip(blocks, offsets)])
    cols = np.concatenate([b.cols for b in blocks])
    values = np.concatenate([b.values for b in blocks])
    shape = (int(offsets[-1]), costs.shape[0])
    matrix = sp.csc_matrix((values, (rows, cols)), shape=shape)
    matrix.sum_duplicates()
    matrix.indices = matrix.indices.astype(np.int32)
    families = {b.name: (int(off), int(off + b.n_rows)) for b, off in zip(blocks, offsets)}
    return IlpModel(
        np.asarray(costs, dtype=np.float64),
        matrix,
        np.concatenate([b.lower for b in blocks]),
        np.concatenate([b.upper for b in blocks]),
        families,
    )


def restrict_columns(model: IlpModel, columns: np.ndarray) -> IlpModel:
    """The model on a subset of its variables (the others fixed to 0).

    Parameters
    ----------
    model : IlpModel
    columns : np.ndarray, shape (k,)
        Sorted indices of the variables kept; variable i of the result is ``columns[i]``.

    """
    matrix = model.matrix[:, columns].tocsc()
    matrix.indices = matrix.indices.astype(np.int32)
    return IlpModel(model.costs[columns], matrix, model.row_lower, model.row_upper, model.row_families)
