"""The first restricted model of column generation: cheap, feasible, near the optimum.

The stay seed alone satisfies every constraint (so every restricted model is feasible); the
feature seed and the band around a cheap closed path put the likely optimum's edges in from
the start. A seed is only a start: the pricing, never the seed, makes the bound valid.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from spidermatch.model.lazy_model import LazyModel
from spidermatch.model.product_graph import INTRA
from spidermatch.solve.path_seed import cheapest_closed_path, path_plausible
from spidermatch.solve.pricing import BLOCK_COLUMNS

SEED_NEIGHBOURS = 6  # per source vertex: targets of lowest feature cost whose edges (and 1-ring) seed the LP


def stay_seed(lazy: LazyModel) -> np.ndarray:
    """Stay edges at the target vertex y0 of cheapest all-stay path, one per layer, shape (L,).

    Together they satisfy CYC, CON, PES, ANS and every connectivity cut.
    """
    graph, c = lazy.graph, lazy.curve.vertices
    step = np.linalg.norm(lazy.source_verts[c] - lazy.source_verts[np.roll(c, -1)], axis=1)
    totals = step @ (lazy.vertex_costs[c] + lazy.vertex_costs[np.roll(c, -1)])  # (V_Y,)
    y0 = int(np.argmin(totals))
    stay_entry = int(
        np.flatnonzero((graph.block_kind != INTRA) & (graph.block_src == y0) & (graph.block_dst == y0))[0]
    )
    return np.arange(graph.n_layers, dtype=np.int64) * graph.block_size + stay_entry


def feature_plausible(lazy: LazyModel, neighbours: int = SEED_NEIGHBOURS) -> np.ndarray:
    """Targets plausible by features per source vertex, shape (V_X, V_Y), bool.

    Target y is plausible for source vertex p if it is among p's ``neighbours`` of lowest
    feature cost R[p] or adjacent to one of them.
    """
    graph, costs = lazy.graph, lazy.vertex_costs
    k = min(neighbours, graph.n_target)
    nearest = np.argpartition(costs, k - 1, axis=1)[:, :k]
    plausible = np.zeros(costs.shape, dtype=bool)
    plausible[np.arange(costs.shape[0])[:, None], nearest] = True
    edges = graph.target_edges
    adjacency = sp.csr_matrix(
        (np.ones(edges.shape[0]), (edges[:, 0], edges[:, 1])), shape=(graph.n_target,) * 2
    )
    plausible |= (sp.csr_matrix(plausible, dtype=np.float64) @ adjacency).toarray() > 0
    return plausible


def edges_between_plausible(lazy: LazyModel, plausible: np.ndarray) -> np.ndarray:
    """Sorted edge ids (k,) whose two ends are plausible targets of their curve vertices.

    ``plausible`` has shape (V_X, V_Y): edge ((l, a), (l', b)) is kept if a is plausible for
    the curve vertex of layer l and b for that of layer l'.
    """
    graph, chosen, block = lazy.graph, [], lazy.graph.block_size
    for start, stop in lazy.layer_blocks(max(1, BLOCK_COLUMNS // block)):
        layer, entry, next_layer = lazy.split(np.arange(start * block, stop * block))
        p, q = lazy.curve.vertices[layer], lazy.curve.vertices[next_layer]
        keep = plausible[p, graph.block_src[entry]] & plausible[q, graph.block_dst[entry]]
        chosen.append(np.flatnonzero(keep) + start * block)
    return np.concatenate(chosen)


def feature_seed(lazy: LazyModel, neighbours: int = SEED_NEIGHBOURS) -> np.ndarray:
    """Edges between feature-plausible targets of consecutive curve vertices, sorted edge ids (k,)."""
    return edges_between_plausible(lazy, feature_plausible(lazy, neighbours))


def path_band_seed(lazy: LazyModel, neighbours: int = SEED_NEIGHBOURS) -> np.ndarray:
    """The feature seed plus a band around a cheap closed path, sorted edge ids (k,).

    See :mod:`spidermatch.solve.path_seed`: the path satisfies CYC and CON only, but its
    band (a few layers and rings around it, per source vertex) usually holds a near-optimal
    path of the full model, so column generation starts close to the LP's optimum.
    """
    path, _ = cheapest_closed_path(lazy)
    plausible = feature_plausible(lazy, neighbours) | path_plausible(lazy, path)
    return np.union1d(edges_between_plausible(lazy, plausible), path)
