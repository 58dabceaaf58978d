"""Solving strategies: how the SpiderMatch ILP is handed to HiGHS.

Every strategy returns a :class:`~spidermatch.solve.highs.SolveResult` whose solution
is one closed path and whose bound is valid for every such path.

``plain``: the full model to HiGHS's branch and cut, re-solved with connectivity
cuts (:mod:`spidermatch.solve.connectivity`) while its optimum has detached cycles.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import replace
from typing import Callable

from spidermatch.curve import SpiderCurve
from spidermatch.ilp import IlpModel
from spidermatch.product_graph import ProductGraph
from spidermatch.solve.connectivity import connectivity_cuts, detached_components
from spidermatch.solve.highs import HighsSession, SolveResult, SolverOptions

logger = logging.getLogger(__name__)

Strategy = Callable[[IlpModel, ProductGraph, SpiderCurve, SolverOptions], SolveResult]
MAX_CUT_ROUNDS = 100


def solve_plain(
    model: IlpModel, graph: ProductGraph, curve: SpiderCurve, options: SolverOptions
) -> SolveResult:
    """The full model to HiGHS, with lazy connectivity cuts."""
    start = time.perf_counter()
    session = HighsSession(model, options)
    result = session.run()
    rounds = 0
    for round_number in range(1, MAX_CUT_ROUNDS + 1):
        if result.x is None:
            break
        components = detached_components(graph, result.x)
        if not components:
            break
        if time.perf_counter() - start >= options.time_limit:
            return replace(
                result,
                status="no_solution",
                x=None,
                objective=math.inf,
                gap=math.nan,
                wall_time=time.perf_counter() - start,
                cut_rounds=rounds,
                message="time limit reached while separating detached cycles",
            )
        rows, lower, upper = connectivity_cuts(graph, components)
        logger.info(
            "cut round %d: %d detached cycles, %d connectivity cuts",
            round_number,
            len(components),
            rows.shape[0],
        )
        session.add_rows(rows, lower, upper)
        rounds = round_number
        result = session.run()  # HiGHS's time limit counts the session's runs together
    return replace(result, wall_time=time.perf_counter() - start, cut_rounds=rounds)


STRATEGIES: dict[str, Strategy] = {"plain": solve_plain}


def solve_with_strategy(
    name: str, model: IlpModel, graph: ProductGraph, curve: SpiderCurve, options: SolverOptions
) -> SolveResult:
    """Run the strategy called ``name``."""
    if name not in STRATEGIES:
        raise ValueError(f"unknown solving strategy {name!r}; choose from {sorted(STRATEGIES)}")
    return STRATEGIES[name](model, graph, curve, options)
