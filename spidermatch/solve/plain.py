"""``plain``: the full model to HiGHS's branch and cut.

Re-solved with connectivity cuts (:mod:`spidermatch.solve.connectivity`) while its optimum
has detached cycles; with ``flow_rows="intersections"`` the flow rows of every self-intersection
layer are in the model from the first solve on, as for ``colgen`` and ``rcfix``.
"""

from __future__ import annotations

import numpy as np

from spidermatch.model.curve import SpiderCurve
from spidermatch.model.ilp import IlpModel
from spidermatch.model.product_graph import ProductGraph
from spidermatch.solve.cuts import CutPool, cut_pool, solve_with_cuts
from spidermatch.solve.types import SolveResult, SolverOptions


def solve_plain(
    model: IlpModel, graph: ProductGraph, curve: SpiderCurve, options: SolverOptions
) -> SolveResult:
    """The full model to HiGHS, with lazy connectivity cuts (and flow rows as ``options.flow_rows`` says)."""
    if options.flow_rows == "found":
        pool = CutPool()  # flow rows only where a solution showed detached cycles, in those layers alone
    else:
        pool = cut_pool(curve.first_layer, np.flatnonzero(curve.is_intersection_layer), options)
    return solve_with_cuts(model, graph, options, pool=pool)
