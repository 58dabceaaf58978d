"""The void vertex: a partial-to-partial matching whose overlap is part of the solution.

Two scans that each miss part of one surface share an overlap that neither shows by its
topology. The SpiderCurve runs through all of the source, so some of its positions have no
partner on the target. The target graph gets one more vertex, the **void** (index V_Y): a
curve position matched to it has no partner. The void is joined to the target's boundary
vertices by edges that only a step along the curve takes (inter edges; no intra edge, so one
curve position cannot enter and leave the void and jump along the boundary in between), and
it has a stay edge like every target vertex. So the matched target path may leave the target
only where the target ends, which is where a surface the source still shows has no partner.

Costs, with R the feature cost matrix and lambda the void cost (method.md 4 otherwise):

- R[p, void] = lambda_p (one lambda for every source vertex, or one per vertex): a curve step of
  length |dx| spent in the void costs (lambda_p + lambda_q) |dx|, a matched one about
  sqrt(|dx|^2 + |dy|^2) (R[p, a] + R[q, b]).
- An edge into or out of the void has no target length (it is no step on the target).
- No ANS row counts the void: any number of curve vertices may have no partner.

CYC, CON and PES are unchanged: a self-intersection of the curve is matched to one target
vertex or to the void on both of its passes. The all-void path (every layer at the void) is a
closed path (of cost 2 lambda times the curve length for one lambda): "nothing overlaps". The
solve certifies the matching and the overlap together: no consistent matching of some of the
source onto the target, with the rest in the void, is cheaper for these costs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spidermatch.model.product_graph import ProductGraph

VOID_FACTOR = 8.0
"""The void cost lambda in units of the median over source vertices of their cheapest R[p, :]."""

OUTSIDE_WEIGHT = 0.1
"""With an estimate of the overlap: the void's cost outside it, as a share of lambda."""


@dataclass(frozen=True, eq=False)
class VoidTarget:
    """A target graph with its void vertex.

    Attributes
    ----------
    verts : np.ndarray, shape (V_Y + 1, 3)
        The target's vertices, then the void's (a placeholder at the origin: no length is
        measured to it).
    vertex_costs : np.ndarray, shape (V_X, V_Y + 1)
        R with the void's column (lambda).
    crossing_edges : np.ndarray, shape (n_boundary, 2)
        (boundary vertex, void) pairs, taken only while the curve advances.
    void : int
        The void's index, V_Y.

    """

    verts: np.ndarray
    vertex_costs: np.ndarray
    crossing_edges: np.ndarray
    void: int

    @property
    def n_target(self) -> int:
        """Vertices of the target graph, the void included."""
        return self.void + 1


def void_cost(vertex_costs: np.ndarray, factor: float = VOID_FACTOR) -> float:
    """The void cost: ``factor`` times the median over source vertices of their cheapest R[p, :] (V_X, V_Y).

    A source vertex whose feature partner costs much more than a typical vertex's is cheaper
    in the void; ``factor`` says how much more. Tied to R's own scale, it does not depend on
    the robust loss's parameters or the descriptors' dimension.
    """
    if factor <= 0:
        raise ValueError(f"the void factor must be positive, got {factor}")
    cheapest = np.asarray(vertex_costs).min(axis=1)
    return float(factor * max(np.median(cheapest), np.finfo(float).tiny))


def with_void(target_verts: np.ndarray, boundary: np.ndarray, vertex_costs: np.ndarray, cost) -> VoidTarget:
    """The target of ``target_verts`` (V_Y, 3) with a void vertex joined to ``boundary`` (n_b,).

    ``vertex_costs`` (V_X, V_Y) gets the void's column: ``cost`` (lambda), a float for every
    source vertex or one per source vertex (V_X,).
    """
    target_verts = np.asarray(target_verts, dtype=np.float64)
    void = target_verts.shape[0]
    verts = np.vstack([target_verts, np.zeros((1, 3))])
    column = np.broadcast_to(np.asarray(cost, dtype=np.float64), (vertex_costs.shape[0],))
    costs = np.hstack([vertex_costs, column[:, None]])
    boundary = np.asarray(boundary, dtype=np.int64)
    edges = np.column_stack([boundary, np.full(boundary.size, void, dtype=np.int64)])
    return VoidTarget(verts, costs, edges, void)


def void_layers(graph: ProductGraph, x: np.ndarray, void: int, tolerance: float = 0.5) -> np.ndarray:
    """Layers whose curve position an integer solution ``x`` (|E_P|,) matches to the void, shape (L,), bool.

    A position is in the void when its path leaves that layer from the void: the void has no
    intra edge, so such a position is matched to nothing else.
    """
    chosen = np.flatnonzero(np.asarray(x) > tolerance)
    tuples = graph.edge_tuples(chosen)
    in_void = np.zeros(graph.n_layers, dtype=bool)
    in_void[tuples[tuples[:, 1] == void, 0]] = True
    return in_void


def matched_curve_vertices(curve_vertices: np.ndarray, in_void: np.ndarray, n_source: int) -> np.ndarray:
    """Source vertices (n_source,) bool that a layer matches to the target (not all in the void).

    Parameters
    ----------
    curve_vertices : np.ndarray, shape (L,)
    in_void : np.ndarray, shape (L,), bool
        :func:`void_layers`.
    n_source : int

    """
    matched = np.zeros(n_source, dtype=bool)
    matched[np.asarray(curve_vertices)[~np.asarray(in_void, dtype=bool)]] = True
    return matched
