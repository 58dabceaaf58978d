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

import logging
import math
import time
from dataclasses import replace

import numpy as np

from spidermatch.model.curve import SpiderCurve
from spidermatch.model.lazy_model import LazyModel
from spidermatch.model.product_graph import ProductGraph
from spidermatch.model.solution import used_columns
from spidermatch.solve.colgen import solve_column_generation
from spidermatch.solve.plain import solve_plain
from spidermatch.solve.rcfix import solve_reduced_cost_fixing
from spidermatch.solve.types import (
    ROUNDING_GAP,
    SolveResult,
    SolverOptions,
    Strategy,
    relative_gap,
    remaining,
)

STRATEGIES: dict[str, Strategy] = {"plain": solve_plain, "rcfix": solve_reduced_cost_fixing}
"""Strategies that take the full model (an IlpModel)."""


LAZY_STRATEGIES = ("colgen",)  # strategies that take a LazyModel (spidermatch.solve.colgen)


AUTO = "auto"  # chosen by the features: see strategy_for

logger = logging.getLogger(__name__)

HIGHS_TOLERANCE = 1e-7  # HiGHS's default primal and dual feasibility tolerances (absolute)
NOISE_FACTOR = 10.0  # a certificate whose cost per path edge is below this many tolerances is noise


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
    """Run the strategy called ``name`` on ``model`` (an IlpModel, or a LazyModel for any strategy).

    A certificate whose costs are within HiGHS's absolute tolerances (a mesh matched to a copy
    of itself: the identity costs about 0) proves nothing: HiGHS calls any solution optimal
    whose reduced costs are within 1e-7 of it. Such a run is solved again with the costs scaled
    up inside HiGHS (``user_objective_scale``), and is called optimal only if that run proves it.
    """
    start = time.perf_counter()
    result = _run_strategy(name, model, graph, curve, options)
    if not certified_within_noise(result):
        return result
    exponent = cost_scale_exponent(result.objective)
    logger.warning(
        "the certified cost %.3g is within HiGHS's tolerances (%.0e per edge): solving again with "
        "the costs scaled by 2^%d",
        result.objective,
        HIGHS_TOLERANCE,
        exponent,
    )
    scaled = replace(remaining(options, start), extra={**options.extra, "user_objective_scale": exponent})
    rescaled = _run_strategy(name, model, graph, curve, scaled)
    if rescaled.status == "optimal":
        return replace(rescaled, wall_time=time.perf_counter() - start)
    best = rescaled if rescaled.x is not None and rescaled.objective < result.objective else result
    # the first run's bound is what was distrusted; the costs are not negative, so 0 bounds every path
    bound = max(rescaled.bound, 0.0) if math.isfinite(rescaled.bound) else 0.0
    best = replace(best, bound=bound, gap=relative_gap(best.objective, bound))
    message = (
        "not certified: the costs are within HiGHS's tolerances, and the solve with scaled costs "
        f"did not prove it ({rescaled.message})"
    )
    return replace(best, status="feasible", message=message, wall_time=time.perf_counter() - start)


def certified_within_noise(result: SolveResult) -> bool:
    """True if ``result`` is called optimal at a cost per path edge below HiGHS's tolerance noise.

    A cost of about 0 (at most :data:`~spidermatch.solve.types.ROUNDING_GAP`) is no such case:
    the costs are not negative, so 0 bounds every path.
    """
    if result.status != "optimal" or result.x is None:
        return False
    edges = max(1, used_columns(result.x).size)
    return ROUNDING_GAP < abs(result.objective) < NOISE_FACTOR * HIGHS_TOLERANCE * edges


def cost_scale_exponent(objective: float) -> int:
    """The k (0 to 60) with 2^k ``objective`` about 1: lifts a tiny optimum above the tolerances."""
    return int(np.clip(math.ceil(-math.log2(abs(objective))), 0, 60))


def _run_strategy(name: str, model, graph: ProductGraph, curve: SpiderCurve, options: SolverOptions):
    if name in LAZY_STRATEGIES:
        return solve_column_generation(model, graph, curve, options)
    if name not in STRATEGIES:
        choices = sorted([*STRATEGIES, *LAZY_STRATEGIES])
        raise ValueError(f"unknown solving strategy {name!r}; choose from {choices}")
    if isinstance(model, LazyModel):
        model = model.full_model()
    return STRATEGIES[name](model, graph, curve, options)
