"""``plain``: the full model to HiGHS's branch and cut.

Re-solved with connectivity cuts (:mod:`spidermatch.solve.connectivity`) while its optimum
has detached cycles.
"""

from __future__ import annotations

from spidermatch.model.curve import SpiderCurve
from spidermatch.model.ilp import IlpModel
from spidermatch.model.product_graph import ProductGraph
from spidermatch.solve.cuts import solve_with_cuts
from spidermatch.solve.types import SolveResult, SolverOptions


def solve_plain(
    model: IlpModel, graph: ProductGraph, curve: SpiderCurve, options: SolverOptions
) -> SolveResult:
    """The full model to HiGHS, with lazy connectivity cuts."""
    return solve_with_cuts(model, graph, options)
