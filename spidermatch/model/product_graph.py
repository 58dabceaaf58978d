"""The product graph P = C x Y of a SpiderCurve and a target mesh (method.md section 3).

Product vertex (l, y) has index ``l * V_Y + y``. Edges are stored layer by layer;
each layer's block is [intra edges (E_dir) | inter edges (E_dir, then any crossing-only
edges) | stay edges (V_Y)], so edge ``l * B + k`` (B = 2 E_dir + V_Y without crossing-only
edges) is entry k of layer l's block.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spidermatch.geometry.mesh import directed_edges
from spidermatch.model.solution import FRACTIONAL

INTRA, INTER, STAY = 0, 1, 2
KIND_NAMES = ("intra", "inter", "stay")


@dataclass(frozen=True, eq=False)
class ProductGraph:
    """Edges of the product graph of a cyclic curve with L layers and a graph on V_Y vertices.

    Attributes
    ----------
    n_layers : int
        L.
    n_target : int
        V_Y.
    target_edges : np.ndarray, shape (E_dir, 2)
        Directed target edges (both orientations of every undirected edge).
    block_src, block_dst : np.ndarray, shape (B,)
        Target vertex an edge of one layer block leaves / enters.
    block_kind : np.ndarray, shape (B,), int8
        INTRA, INTER or STAY for each entry of a layer block.

    """

    n_layers: int
    n_target: int
    target_edges: np.ndarray
    block_src: np.ndarray
    block_dst: np.ndarray
    block_kind: np.ndarray

    @property
    def block_size(self) -> int:
        """Edges per layer B = 2 E_dir + V_Y (plus the crossing-only edges, both ways)."""
        return int(self.block_kind.shape[0])

    @property
    def n_edges(self) -> int:
        """|E_P| = L (2 |E_Y^dir| + |V_Y|)."""
        return self.n_layers * self.block_size

    @property
    def n_nodes(self) -> int:
        """|V_P| = L |V_Y|."""
        return self.n_layers * self.n_target

    @property
    def layer(self) -> np.ndarray:
        """Layer each edge leaves, shape (|E_P|,)."""
        return np.repeat(np.arange(self.n_layers, dtype=np.int64), self.block_size)

    @property
    def src(self) -> np.ndarray:
        """Target vertex each edge leaves, shape (|E_P|,)."""
        return np.tile(self.block_src, self.n_layers)

    @property
    def dst(self) -> np.ndarray:
        """Target vertex each edge enters, shape (|E_P|,)."""
        return np.tile(self.block_dst, self.n_layers)

    @property
    def kind(self) -> np.ndarray:
        """INTRA / INTER / STAY of each edge, shape (|E_P|,)."""
        return np.tile(self.block_kind, self.n_layers)

    @property
    def next_layer(self) -> np.ndarray:
        """Layer each edge enters, shape (|E_P|,)."""
        step = (self.kind != INTRA).astype(np.int64)
        return (self.layer + step) % self.n_layers

    def edge_tuples(self, edge_ids: np.ndarray) -> np.ndarray:
        """(layer, src, next layer, dst, kind) of chosen edges, shape (N, 5)."""
        edge_ids = np.asarray(edge_ids, dtype=np.int64)
        layer, k = np.divmod(edge_ids, self.block_size)
        kind = self.block_kind[k].astype(np.int64)
        next_layer = (layer + (kind != INTRA)) % self.n_layers
        return np.stack([layer, self.block_src[k], next_layer, self.block_dst[k], kind], axis=1)


def split_layers(graph: ProductGraph, x: np.ndarray, tolerance: float = FRACTIONAL) -> np.ndarray:
    """Layers whose crossing to the next layer is shared by more than one edge.

    An integer solution crosses every layer boundary on exactly one inter or stay edge;
    an LP solution that mixes several paths spreads the crossing over several edges.

    Parameters
    ----------
    graph : ProductGraph
    x : np.ndarray, shape (|E_P|,)
        Edge values, e.g. an LP solution.
    tolerance : float
        Values at or below this count as zero.

    Returns
    -------
    np.ndarray, shape (L,), bool
        True for layer l if more than one edge from layer l to layer l+1 carries flow.

    """
    crossing = graph.block_kind != INTRA
    per_layer = np.asarray(x).reshape(graph.n_layers, graph.block_size)[:, crossing]
    return (per_layer > tolerance).sum(axis=1) > 1


def cyclic_runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of True in a cyclic boolean sequence, as (start, length) pairs.

    Sorted by start. A run that wraps from the end to the start is reported once,
    starting at its first position before the wrap. All True gives one run of the full length.
    """
    flags = np.asarray(flags, dtype=bool)
    n = flags.size
    if not flags.any():  # also the empty sequence
        return []
    if flags.all():
        return [(0, n)]
    shift = int(np.flatnonzero(~flags)[-1]) + 1  # start right after the last False
    rolled = np.roll(flags, -shift)
    edges = np.diff(np.concatenate([[0], rolled.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return sorted((int((start + shift) % n), int(stop - start)) for start, stop in zip(starts, stops))


def build_product_graph(
    n_layers: int, n_target: int, target_edges: np.ndarray, crossing_edges: np.ndarray | None = None
) -> ProductGraph:
    """Product graph of a cyclic curve with ``n_layers`` positions and a target graph.

    Parameters
    ----------
    n_layers : int
        L, the curve length.
    n_target : int
        V_Y.
    target_edges : np.ndarray, shape (E, 2)
        Undirected target edges (plain or augmented).
    crossing_edges : np.ndarray, shape (E_c, 2), optional
        Undirected edges taken only while the curve advances (inter edges, both ways, after
        those of ``target_edges``; no intra edge). The void vertex of a partial-to-partial
        matching is joined to the target's boundary this way (:mod:`spidermatch.model.void`).
        ``target_edges`` stays the graph's ``target_edges``.

    """
    directed = directed_edges(np.asarray(target_edges, dtype=np.int64))
    crossing = directed
    if crossing_edges is not None and len(crossing_edges):
        crossing = np.concatenate([directed, directed_edges(np.asarray(crossing_edges, dtype=np.int64))])
    stay = np.arange(n_target, dtype=np.int64)
    block_src = np.concatenate([directed[:, 0], crossing[:, 0], stay])
    block_dst = np.concatenate([directed[:, 1], crossing[:, 1], stay])
    block_kind = np.concatenate(
        [np.full(len(directed), INTRA), np.full(len(crossing), INTER), np.full(n_target, STAY)]
    ).astype(np.int8)
    for array in (directed, block_src, block_dst, block_kind):
        array.setflags(write=False)
    return ProductGraph(n_layers, n_target, directed, block_src, block_dst, block_kind)
