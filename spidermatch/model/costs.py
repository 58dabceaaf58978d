"""Product-edge costs: line integral times a robust loss of feature differences (method.md 4)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from spidermatch import defaults
from spidermatch.model.product_graph import ProductGraph

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RobustLoss:
    """Barron's general robust loss with an adjustable bowl exponent.

    ``rho(x) = |a-2|/a * ((z/|a-2| + 1)^(a/2) - 1)`` with ``z = (|x|/c)^p``;
    ``p = 2`` is Barron's loss, the SpiderMatch default ``p = 4`` flattens the
    bowl so that small feature differences matter less. ``a = 2`` gives ``z/2``,
    ``a = 0`` gives ``log(z/2 + 1)`` and ``a = -inf`` gives ``1 - exp(-z/2)``.

    Attributes
    ----------
    alpha : float
        Shape parameter a.
    scale : float
        Scale c > 0.
    bowl_exponent : float
        Exponent p > 0.

    """

    alpha: float = float(defaults.option("costs/default", "alpha"))
    scale: float = float(defaults.option("costs/default", "scale"))
    bowl_exponent: float = float(defaults.option("costs/default", "bowl_exponent"))

    def __post_init__(self) -> None:
        if self.scale <= 0 or self.bowl_exponent <= 0:
            raise ValueError(f"robust loss needs scale > 0 and bowl_exponent > 0, got {self}")

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Elementwise loss of an array of any shape."""
        z = (np.abs(x) / self.scale) ** self.bowl_exponent
        a = self.alpha
        if a == 2.0:
            return 0.5 * z
        if a == 0.0:
            return np.log1p(0.5 * z)
        if np.isneginf(a):
            return -np.expm1(-0.5 * z)
        b = abs(a - 2.0)
        return b / a * ((z / b + 1.0) ** (a / 2.0) - 1.0)


def feature_cost_matrix(
    source_features: np.ndarray, target_features: np.ndarray, loss: RobustLoss, chunk: int = 64
) -> np.ndarray:
    """``R[i, j] = sum_d rho(F_X[i, d] - F_Y[j, d])``.

    Parameters
    ----------
    source_features : np.ndarray, shape (V_X, D)
    target_features : np.ndarray, shape (V_Y, D)

    Returns
    -------
    np.ndarray, shape (V_X, V_Y)

    """
    if source_features.shape[1] != target_features.shape[1]:
        raise ValueError(
            f"feature dimensions differ: source {source_features.shape[1]}, target {target_features.shape[1]}"
        )
    out = np.empty((source_features.shape[0], target_features.shape[0]))
    for start in range(0, source_features.shape[0], chunk):
        diff = source_features[start : start + chunk, None, :] - target_features[None, :, :]
        out[start : start + chunk] = loss(diff).sum(axis=2)
    return out


def product_edge_costs(
    graph: ProductGraph,
    curve_vertices: np.ndarray,
    source_verts: np.ndarray,
    target_verts: np.ndarray,
    vertex_costs: np.ndarray,
) -> np.ndarray:
    """Cost of every product edge e = ((l, a), (l', b)) with curve vertices p = c_l, q = c_l'.

    ``c(e) = sqrt(|x_p - x_q|^2 + |y_a - y_b|^2) * (R[p, a] + R[q, b])``

    Parameters
    ----------
    graph : ProductGraph
    curve_vertices : np.ndarray, shape (L,)
    source_verts : np.ndarray, shape (V_X, 3)
    target_verts : np.ndarray, shape (V_Y, 3)
    vertex_costs : np.ndarray, shape (V_X, V_Y)
        R from :func:`feature_cost_matrix`.

    Returns
    -------
    np.ndarray, shape (|E_P|,)

    """
    p = curve_vertices[graph.layer]
    q = curve_vertices[graph.next_layer]
    a, b = graph.src, graph.dst
    length = np.sqrt(
        ((source_verts[p] - source_verts[q]) ** 2).sum(axis=1)
        + ((target_verts[a] - target_verts[b]) ** 2).sum(axis=1)
    )
    return length * (vertex_costs[p, a] + vertex_costs[q, b])


def unit_rows(features: np.ndarray) -> np.ndarray:
    """Rows of ``features`` (N, D) scaled to unit L2 norm (zero rows stay zero), as float64 (N, D).

    Each row is first divided by its largest magnitude, so that descriptors of any scale
    (1e-200 or 1e200) normalise without underflow or overflow.
    """
    rows = np.asarray(features, dtype=np.float64)
    largest = np.max(np.abs(rows), axis=1, keepdims=True) if rows.size else np.ones((len(rows), 1))
    rows = rows / np.where(largest > 0, largest, 1.0)
    return rows / np.maximum(np.linalg.norm(rows, axis=1, keepdims=True), 1e-12)
