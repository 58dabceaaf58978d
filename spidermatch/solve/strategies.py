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

    ``"auto"`` is ``colgen`` for learned (or any non-WKS) features: their LP relaxation is
    tight, and ``colgen`` certifies the same optima as ``rcfix`` without building the full
    model, in a fraction of the time and memory. WKS keeps ``rcfix``, for how it fails: WKS's
    LP relaxation is weak, its gap far above ``colgen``'s first thresholds (tuned for learned
    features), and where neither certifies in time ``colgen``'s only closed path can be the
    stay path while ``rcfix`` still returns a matching within a few percent of the bound, even
    though ``colgen`` certifies more pairs at low resolution (measurements: bench/README.md,
    solver constants). Any other name is returned unchanged.
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
