"""The SpiderMatch ILP without its full matrix: costs, columns and reduced costs on demand.

:func:`spidermatch.model.ilp.build_model` stores every product edge (3.7 M columns at 1000
faces, ~15 M at 2000). A :class:`LazyModel` stores only what defines them (the product
graph, the curve, the vertex positions and the feature cost matrix R) and produces, for
any set of edges, their costs and their constraint columns, with exactly the rows, row
order and coefficients of ``build_model``: row ``i`` here is row ``i`` there. It also
computes reduced costs ``r = c - A^T y`` for any row multipliers ``y`` one block of
layers at a time, which is what column generation and reduced-cost fixing need, without
ever holding more than one block of columns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from spidermatch.model.curve import SpiderCurve
from spidermatch.model.ilp import FAMILIES, IlpModel
from spidermatch.model.product_graph import INTRA, STAY, ProductGraph

COST_BLOCK_COLUMNS = 1_000_000  # edges whose costs are computed at once


@dataclass(frozen=True, eq=False)
class LazyModel:
    """The ILP of :func:`~spidermatch.model.ilp.build_model`, columns produced on demand.

    Attributes
    ----------
    graph : ProductGraph
    curve : SpiderCurve
        ``graph.n_layers`` positions.
    source_verts : np.ndarray, shape (V_X, 3)
    target_verts : np.ndarray, shape (V_Y, 3)
    vertex_costs : np.ndarray, shape (V_X, V_Y)
        R of :func:`spidermatch.model.costs.feature_cost_matrix`.
    families : tuple of str
        Constraint families, a subset of ``FAMILIES`` (rows in ``FAMILIES`` order).
    void_vertex : int or None
        The target's void vertex (:mod:`spidermatch.model.void`): the "no partner" state of a
        partial-to-partial matching. Its edges have no target length, and no ANS row counts it
        (any number of curve vertices may have no partner). None: a plain target.

    """

    graph: ProductGraph
    curve: SpiderCurve
    source_verts: np.ndarray
    target_verts: np.ndarray
    vertex_costs: np.ndarray
    families: tuple = FAMILIES
    void_vertex: int | None = None

    def __post_init__(self) -> None:
        if self.curve.length != self.graph.n_layers:
            raise ValueError(
                f"curve has {self.curve.length} positions, product graph {self.graph.n_layers} layers"
            )
        unknown = set(self.families) - set(FAMILIES)
        if unknown:
            raise ValueError(f"unknown constraint families {sorted(unknown)}; choose from {FAMILIES}")

    @property
    def n_vars(self) -> int:
        """Columns of the full model, |E_P|."""
        return self.graph.n_edges

    @cached_property
    def row_families(self) -> dict:
        """Row range [start, stop) of each family, as in ``build_model``."""
        sizes = {
            "CYC": self.graph.n_layers,
            "CON": self.graph.n_nodes,
            "PES": self.curve.duplicate_layers.size * self.graph.n_target,
            "ANS": self.graph.n_target,
        }
        ranges, start = {}, 0
        for name in FAMILIES:
            if name in self.families:
                ranges[name] = (start, start + sizes[name])
                start += sizes[name]
        return ranges

    @property
    def n_rows(self) -> int:
        """Rows of the full model."""
        return max((stop for _, stop in self.row_families.values()), default=0)

    @cached_property
    def row_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(row_lower, row_upper), each shape (n_rows,): equalities, ANS rows ``<= 1``, CYC ``= 1``."""
        lower, upper = np.zeros(self.n_rows), np.zeros(self.n_rows)
        if "CYC" in self.row_families:
            start, stop = self.row_families["CYC"]
            lower[start:stop] = upper[start:stop] = 1.0
        if "ANS" in self.row_families:
            start, stop = self.row_families["ANS"]
            lower[start:stop], upper[start:stop] = -np.inf, 1.0
        return lower, upper

    @cached_property
    def _layer_tables(self) -> dict:
        """Per-layer lookups: duplicate index, first-occurrence lists, ANS-free flags."""
        duplicates = self.curve.duplicate_layers
        first = self.curve.first_layer[duplicates]
        dup_index = np.full(self.graph.n_layers, -1, dtype=np.int64)
        dup_index[duplicates] = np.arange(duplicates.size)
        by_first = np.argsort(first, kind="stable")
        first_starts = np.searchsorted(first[by_first], np.arange(self.graph.n_layers + 1))
        free = ~self.curve.is_intersection_layer
        return {
            "duplicates": duplicates,
            "first": first,
            "dup_index": dup_index,
            "by_first": by_first,
            "first_starts": first_starts,
            "free": free,
            "free_inter": free & np.roll(free, -1),
        }

    def split(self, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(layer, block entry, next layer) of edge ids, each shape (k,), int64."""
        layer, entry = np.divmod(np.asarray(columns, dtype=np.int64), self.graph.block_size)
        crossing = self.graph.block_kind[entry] != INTRA
        return layer, entry, (layer + crossing) % self.graph.n_layers

    def costs(self, columns: np.ndarray) -> np.ndarray:
        """Costs of edge ids (k,), equal to :func:`~spidermatch.model.costs.product_edge_costs` there."""
        return self.column_costs[np.asarray(columns, dtype=np.int64)]

    @cached_property
    def column_costs(self) -> np.ndarray:
        """Cost of every edge (n_vars,), float64, computed once one block of layers at a time.

        Pricing passes, the path seed and every submodel read it, so no cost is computed
        twice; it takes 8 bytes per column (30 MB at 1000 faces, 120 MB at 2000).
        """
        block = self.graph.block_size
        costs = np.empty(self.n_vars)
        for start, stop in self.layer_blocks(max(1, COST_BLOCK_COLUMNS // block)):
            layer, entry, next_layer = self._block_edges(start, stop)
            costs[start * block : stop * block] = self._costs(layer, entry, next_layer)
        return costs

    def _block_edges(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(layer, block entry, next layer) of every edge of layers [start, stop), in edge-id order."""
        graph = self.graph
        layer = np.repeat(np.arange(start, stop, dtype=np.int64), graph.block_size)
        entry = np.tile(np.arange(graph.block_size, dtype=np.int64), stop - start)
        crossing = graph.block_kind[entry] != INTRA
        return layer, entry, (layer + crossing) % graph.n_layers

    @cached_property
    def _squared_steps(self) -> tuple[np.ndarray, np.ndarray]:
        """Squared step lengths: of each layer along the curve (L,), of each block entry's target edge (B,).

        A product edge's length is the root of their sum (the curve step counts for crossings only).
        """
        c, graph = self.curve.vertices, self.graph
        source = ((self.source_verts[c] - self.source_verts[np.roll(c, -1)]) ** 2).sum(axis=-1)
        target = ((self.target_verts[graph.block_src] - self.target_verts[graph.block_dst]) ** 2).sum(axis=-1)
        if self.void_vertex is not None:  # leaving or entering the overlap is no step on the target
            target[(graph.block_src == self.void_vertex) | (graph.block_dst == self.void_vertex)] = 0.0
        return source, target

    def _costs(self, layer: np.ndarray, entry: np.ndarray, next_layer: np.ndarray) -> np.ndarray:
        source_sq, target_sq = self._squared_steps
        n = self.graph.n_target
        flat_costs = self.vertex_costs.reshape(-1)
        p, q = self.curve.vertices[layer], self.curve.vertices[next_layer]
        a, b = self.graph.block_src[entry], self.graph.block_dst[entry]
        length = np.sqrt(np.where(next_layer != layer, source_sq[layer], 0.0) + target_sq[entry])
        return length * (flat_costs.take(p * n + a) + flat_costs.take(q * n + b))

    def submodel(self, columns: np.ndarray) -> IlpModel:
        """The model over the sorted edge ids ``columns`` (k,) with every row of the full model.

        Column i of the result is edge ``columns[i]``; rows, their order and bounds are those
        of ``build_model`` (so row multipliers of the two are interchangeable).
        """
        columns = np.asarray(columns, dtype=np.int64)
        rows, cols, values = self.coefficients(columns)
        matrix = sp.csc_matrix((values, (rows, cols)), shape=(self.n_rows, columns.size))
        matrix.sum_duplicates()
        matrix.indices = matrix.indices.astype(np.int32)
        lower, upper = self.row_bounds
        return IlpModel(self.costs(columns), matrix, lower, upper, dict(self.row_families))

    def compact_submodel(self, columns: np.ndarray) -> IlpModel:
        """:meth:`submodel` without the rows that no column of ``columns`` touches and 0 satisfies.

        Such a row reads ``0`` for every x over ``columns``, so leaving it out changes no
        solution, bound or dual of the restricted model; rows keep their relative order and
        ``row_families`` gives each family's range among the kept rows. A row that 0 violates
        (a CYC row of a layer without columns) is kept, so an infeasible subset stays infeasible.
        """
        sub = self.submodel(columns)
        lower, upper = self.row_bounds
        keep = (lower > 0) | (upper < 0)
        keep[sub.matrix.indices] = True
        kept_before = np.concatenate([[0], np.cumsum(keep)])
        families = {
            name: (int(kept_before[a]), int(kept_before[b])) for name, (a, b) in self.row_families.items()
        }
        matrix = sp.csc_matrix(sub.matrix[keep])
        matrix.indices = matrix.indices.astype(np.int32)
        return IlpModel(sub.costs, matrix, lower[keep], upper[keep], families)

    def full_model(self, block_columns: int = 1_000_000) -> IlpModel:
        """Every column: the model of ``build_model``, assembled one block of layers at a time.

        Each block's columns go straight into compressed-column form with int32 row indices,
        so only one block's coordinates are ever held in int64 (``build_model`` holds them all).
        """
        block = self.graph.block_size
        indptr, indices, data, costs, nnz = [np.zeros(1, np.int64)], [], [], [], 0
        for start, stop in self.layer_blocks(max(1, block_columns // block)):
            part = self.submodel(np.arange(start * block, stop * block))
            indptr.append(part.matrix.indptr[1:].astype(np.int64) + nnz)
            indices.append(part.matrix.indices)
            data.append(part.matrix.data)
            costs.append(part.costs)
            nnz += part.matrix.nnz
        index_type = np.int32 if nnz < np.iinfo(np.int32).max else np.int64
        matrix = sp.csc_matrix(
            (np.concatenate(data), np.concatenate(indices), np.concatenate(indptr).astype(index_type)),
            shape=(self.n_rows, self.n_vars),
        )
        lower, upper = self.row_bounds
        return IlpModel(np.concatenate(costs), matrix, lower, upper, dict(self.row_families))

    def coefficients(self, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Non-zeros (row, position in ``columns``, value) of the constraint columns of ``columns``."""
        layer, entry, next_layer = self.split(columns)
        position = np.arange(layer.size)
        parts = []
        for name in self.row_families:
            start = self.row_families[name][0]
            rows, where, values = getattr(self, f"_{name.lower()}_entries")(layer, entry, next_layer)
            parts.append((rows + start, position[where], values))
        if not parts:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        return tuple(np.concatenate([part[i] for part in parts]) for i in range(3))

    def _cyc_entries(self, layer, entry, next_layer):
        crossing = np.flatnonzero(self.graph.block_kind[entry] != INTRA)
        return layer[crossing], crossing, np.ones(crossing.size)

    def _con_entries(self, layer, entry, next_layer):
        n = self.graph.n_target
        tail = layer * n + self.graph.block_src[entry]
        head = next_layer * n + self.graph.block_dst[entry]
        where = np.arange(layer.size)
        values = np.concatenate([np.ones(layer.size), -np.ones(layer.size)])
        return np.concatenate([tail, head]), np.concatenate([where, where]), values

    def _pes_entries(self, layer, entry, next_layer):
        tables, n = self._layer_tables, self.graph.n_target
        src = self.graph.block_src[entry]
        as_duplicate = np.flatnonzero(tables["dup_index"][layer] >= 0)
        dup_rows = tables["dup_index"][layer[as_duplicate]] * n + src[as_duplicate]
        starts = tables["first_starts"]
        count = starts[layer + 1] - starts[layer]  # duplicates whose first occurrence is this layer
        as_first = np.repeat(np.arange(layer.size), count)
        within = np.arange(as_first.size) - np.repeat(np.cumsum(count) - count, count)
        dup = tables["by_first"][starts[layer[as_first]] + within]
        first_rows = dup * n + src[as_first]
        rows = np.concatenate([first_rows, dup_rows])
        values = np.concatenate([np.ones(as_first.size), -np.ones(as_duplicate.size)])
        return rows, np.concatenate([as_first, as_duplicate]), values

    def _ans_entries(self, layer, entry, next_layer):
        tables, kind = self._layer_tables, self.graph.block_kind[entry]
        counted = ((kind == INTRA) & tables["free"][layer]) | (
            (kind != INTRA) & (kind != STAY) & tables["free_inter"][layer]
        )
        if self.void_vertex is not None:
            counted &= self.graph.block_dst[entry] != self.void_vertex
        where = np.flatnonzero(counted)
        return self.graph.block_dst[entry[where]], where, np.ones(where.size)

    def layer_blocks(self, block_layers: int):
        """Consecutive layer ranges (start, stop) covering all layers, ``block_layers`` at a time."""
        for start in range(0, self.graph.n_layers, block_layers):
            yield start, min(start + block_layers, self.graph.n_layers)

    def block_reduced_costs(self, start: int, stop: int, potentials: RowPotentials) -> np.ndarray:
        """``r = c - A^T y`` of every edge of layers [start, stop), shape ((stop - start) * B,).

        Entry ``i`` belongs to edge ``start * B + i``.
        """
        graph = self.graph
        layer, entry, next_layer = self._block_edges(start, stop)
        crossing = graph.block_kind[entry] != INTRA
        reduced = self.column_costs[start * graph.block_size : stop * graph.block_size].copy()
        src, dst = graph.block_src[entry], graph.block_dst[entry]
        tail, head = layer * graph.n_target + src, next_layer * graph.n_target + dst  # flat (layer, vertex)
        con, pes = potentials.con.reshape(-1), potentials.pes.reshape(-1)
        reduced -= np.where(crossing, potentials.cyc.take(layer), 0.0)
        reduced -= con.take(tail) - con.take(head)
        reduced -= pes.take(tail)
        if potentials.ans is not None:
            _, where, _ = self._ans_entries(layer, entry, next_layer)
            reduced[where] -= potentials.ans[dst[where]]
        return reduced

    def potentials(self, y: np.ndarray) -> RowPotentials:
        """Row multipliers ``y`` (n_rows,) rearranged per layer and target vertex for pricing."""
        graph, families = self.graph, self.row_families
        L, n = graph.n_layers, graph.n_target

        def part(name):
            start, stop = families[name]
            return y[start:stop]

        cyc = part("CYC") if "CYC" in families else np.zeros(L)
        con = part("CON").reshape(L, n) if "CON" in families else np.zeros((L, n))
        pes = np.zeros((L, n))
        if "PES" in families:
            tables = self._layer_tables
            per_duplicate = part("PES").reshape(-1, n)
            np.add.at(pes, tables["first"], per_duplicate)
            np.add.at(pes, tables["duplicates"], -per_duplicate)
        ans = part("ANS") if "ANS" in families else None
        return RowPotentials(cyc, con, pes, ans)

    def row_term(self, y: np.ndarray) -> float:
        """``sum_i y_i b_i(y)`` of :mod:`spidermatch.solve.fixing` for sign-corrected ``y`` (n_rows,)."""
        lower, upper = self.row_bounds
        selected = np.where(y > 0, lower, upper)
        return math.fsum(np.where(y != 0, y * np.where(np.isfinite(selected), selected, 0.0), 0.0))


@dataclass(frozen=True, eq=False)
class RowPotentials:
    """Row multipliers by family: cyc (L,), con (L, V_Y), pes (L, V_Y) summed per layer, ans (V_Y,)."""

    cyc: np.ndarray
    con: np.ndarray
    pes: np.ndarray
    ans: np.ndarray | None
