"""Lower bounds from LP duals, and reduced-cost fixing that never drops an optimal column.

For ``min c^T x  s.t.  lower <= A x <= upper,  0 <= x <= 1`` and *any* row multipliers
``y`` whose signs fit the row bounds (``y_i <= 0`` where only ``upper_i`` is finite,
``y_i >= 0`` where only ``lower_i`` is, free on equality rows), with reduced costs
``r = c - A^T y`` every feasible ``x`` satisfies

    c^T x = y^T A x + r^T x >= sum_i y_i b_i(y) + sum_j min(0, r_j) =: L(y)

where ``b_i(y)`` is the row bound the sign of ``y_i`` selects. So ``L(y)`` is a valid
lower bound whatever solver produced ``y`` and however inexact it is: multipliers are
sign-corrected and the bound is recomputed here, not taken from the solver. If
``x_j = 1`` the same argument gives ``c^T x >= L(y) + max(r_j, 0)``, hence no solution
of cost at most ``U`` uses a column with ``L(y) + r_j > U`` (reduced-cost fixing). Where
every solution is one closed path, :meth:`DualBound.along_paths` strengthens ``r_j`` to the
column's path reduced cost (:mod:`spidermatch.solve.path_costs`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from spidermatch.model.ilp import IlpModel
from spidermatch.model.product_graph import ProductGraph
from spidermatch.solve.path_costs import path_reduced_costs


@dataclass(frozen=True, eq=False)
class DualBound:
    """A certified lower bound and the reduced costs it comes with.

    Attributes
    ----------
    bound : float
        ``L(y)``, a lower bound on ``c^T x`` over every feasible ``x`` in [0, 1]^n.
    reduced : np.ndarray, shape (n,)
        Reduced costs ``r = c - A^T y``, or after :meth:`along_paths` partly path reduced
        costs: either way a solution that uses column j costs at least
        ``bound + max(reduced[j], 0)``.

    """

    bound: float
    reduced: np.ndarray

    def column_bounds(self) -> np.ndarray:
        """Lower bound on the cost of any solution that uses column j, shape (n,)."""
        return self.bound + np.maximum(self.reduced, 0.0)

    def surviving_columns(self, upper_bound: float) -> np.ndarray:
        """Indices of the columns a solution of cost <= ``upper_bound`` may use, shape (k,)."""
        return np.flatnonzero(self.column_bounds() <= upper_bound)

    def along_paths(self, graph: ProductGraph, cutoff: float) -> DualBound:
        """The same bound with the path reduced cost of every column of reduced cost <= ``cutoff``.

        Valid only for models whose solutions are single closed paths (CYC, CON and the
        connectivity cuts). Columns above the cutoff keep their reduced cost.
        """
        inside = np.flatnonzero(self.reduced <= cutoff)
        strengthened = self.reduced.copy()
        strengthened[inside] = path_reduced_costs(graph, inside, self.reduced[inside], cutoff)
        return DualBound(self.bound, strengthened)

    def bound_outside(self, columns: np.ndarray) -> float:
        """Lower bound on any solution that uses at least one column *not* in ``columns``."""
        outside = np.ones(self.reduced.shape[0], dtype=bool)
        outside[columns] = False
        if not outside.any():
            return math.inf
        return float(self.column_bounds()[outside].min())


def sign_corrected_duals(model: IlpModel, row_duals: np.ndarray) -> np.ndarray:
    """Row multipliers ``y`` (m,) with the signs the row bounds allow (others set to 0)."""
    y = np.asarray(row_duals, dtype=np.float64).copy()
    only_upper = np.isneginf(model.row_lower) & np.isfinite(model.row_upper)
    only_lower = np.isposinf(model.row_upper) & np.isfinite(model.row_lower)
    free = np.isneginf(model.row_lower) & np.isposinf(model.row_upper)
    y[only_upper] = np.minimum(y[only_upper], 0.0)
    y[only_lower] = np.maximum(y[only_lower], 0.0)
    y[free] = 0.0
    return y


def dual_bound(model: IlpModel, row_duals: np.ndarray) -> DualBound:
    """The certified bound ``L(y)`` and reduced costs for (sign-corrected) row multipliers.

    Parameters
    ----------
    model : IlpModel
    row_duals : np.ndarray, shape (m,)
        Any multipliers, e.g. the row duals of an LP solve.

    """
    y = sign_corrected_duals(model, row_duals)
    selected = np.where(y > 0, model.row_lower, model.row_upper)
    row_terms = np.where(y != 0, y * np.where(np.isfinite(selected), selected, 0.0), 0.0)
    reduced = model.costs - model.matrix.T @ y
    bound = math.fsum(row_terms) + math.fsum(np.minimum(reduced, 0.0))
    return DualBound(bound, reduced)
