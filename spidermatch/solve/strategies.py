"""Solving strategies by name: how the SpiderMatch ILP is handed to HiGHS.

Every strategy returns a :class:`~spidermatch.solve.types.SolveResult` whose solution
is one closed path and whose bound is valid for every such path of the **full** model.

``plain`` (:mod:`spidermatch.solve.plain`)
    The full model with lazy connectivity cuts.
``rcfix`` (:mod:`spidermatch.solve.rcfix`)
    LP bound, reduced-cost fixing, a final MIP over the surviving columns.
``colgen`` (:mod:`spidermatch.solve.colgen`)
    Column generation: the full model is never built.
"""

from __future__ import annotations

from spidermatch.model.curve import SpiderCurve
from spidermatch.model.lazy_model import LazyModel
from spidermatch.model.product_graph import ProductGraph
from spidermatch.solve.colgen import solve_column_generation
from spidermatch.solve.plain import solve_plain
from spidermatch.solve.rcfix import solve_reduced_cost_fixing
from spidermatch.solve.types import SolveResult, SolverOptions, Strategy

STRATEGIES: dict[str, Strategy] = {"plain": solve_plain, "rcfix": solve_reduced_cost_fixing}
"""Strategies that take the full model (an IlpModel)."""


LAZY_STRATEGIES = ("colgen",)  # strategies that take a LazyModel (spidermatch.solve.colgen)


AUTO = "auto"  # chosen by the features: see strategy_for


def strategy_for(name: str, feature_name: str) -> str:
    """The strategy to run for ``name`` (``"auto"`` or a strategy) and features called ``feature_name``.

    ``"auto"`` is ``colgen`` for learned (or any non-WKS) features: on the five FAUST_r
    validation pairs at 1000 faces it certifies the same optima as ``rcfix`` in a fraction of
    the time and memory. WKS keeps ``rcfix``, for how it fails: with WKS's weak LP relaxation
    ``colgen`` certified all five pairs at 500 faces within 300 s (``rcfix`` three, and
    matchings within 2.7 and 4.4 % of the bound on the others), but at 1000 faces its only
    closed path at the limit was the stay path (gap > 99 %, two pairs) where ``rcfix`` returned
    matchings within 3.6 and 5.4 % of the bound. Any other name is returned unchanged.
    """
    if name != AUTO:
        return name
    return "rcfix" if feature_name == "wks" else "colgen"


def solve_with_strategy(
    name: str, model, graph: ProductGraph, curve: SpiderCurve, options: SolverOptions
) -> SolveResult:
    """Run the strategy called ``name`` on ``model`` (an IlpModel, or a LazyModel for any strategy)."""
    if name in LAZY_STRATEGIES:
        return solve_column_generation(model, graph, curve, options)
    if name not in STRATEGIES:
        choices = sorted([*STRATEGIES, *LAZY_STRATEGIES])
        raise ValueError(f"unknown solving strategy {name!r}; choose from {choices}")
    if isinstance(model, LazyModel):
        model = model.full_model()
    return STRATEGIES[name](model, graph, curve, options)
