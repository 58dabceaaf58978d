"""``rcfix``: LP bound, restricted incumbent, reduced-cost fixing.

LP relaxation first; its duals give a certified bound and reduced costs
(:mod:`spidermatch.solve.fixing`). A MIP over the columns of small reduced cost,
stopped at a 1 % gap, gives an incumbent U; every column whose reduced-cost bound
exceeds U is provably unused by any better solution and dropped; the MIP over the
survivors, started from the incumbent, proves optimality for the full model.
Connectivity cuts for the intra-layer 2-cycles of self-intersection layers go in
up front (the detached cycles that otherwise cost a full re-solve), and a re-solve
after new cuts restarts from the best connected solution HiGHS has reported.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace

import numpy as np

from spidermatch.model.curve import SpiderCurve
from spidermatch.model.ilp import IlpModel
from spidermatch.model.product_graph import ProductGraph
from spidermatch.model.solution import LP_SUPPORT, used_columns
from spidermatch.shutdown import RunInterrupted
from spidermatch.solve.cuts import cut_pool, imposes_paths, solve_with_cuts
from spidermatch.solve.fixing import DualBound, dual_bound
from spidermatch.solve.highs import LP_EXTRA, HighsSession
from spidermatch.solve.progress import report_known
from spidermatch.solve.types import (
    LpNotSolved,
    SolveResult,
    SolverOptions,
    count_fractional,
    relative_gap,
    remaining,
)

logger = logging.getLogger(__name__)


SEED_GAP = 0.01  # first restricted MIP: columns within 1 % of the LP bound in reduced cost


SEED_FRACTION = 0.01  # ... and at least this fraction of all columns


SEED_MIP_GAP = 0.01  # the first restricted MIP is run only for an incumbent: it stops at this gap


MAX_PHASES = 4


@dataclass(frozen=True)
class LpSolve:
    """The LP relaxation's solution and the certified bound from its duals."""

    x: np.ndarray
    dual: DualBound
    wall_time: float


def solve_lp(model: IlpModel, options: SolverOptions) -> LpSolve | None:
    """LP relaxation by dual simplex without presolve; None if it is infeasible."""
    start = time.perf_counter()
    lp_options = replace(options, presolve="off", extra={**options.extra, **LP_EXTRA})
    session = HighsSession(model, lp_options, relax=True)
    result = session.run()
    if result.status == "infeasible":
        return None
    if result.status != "optimal":
        raise LpNotSolved(result)
    dual = dual_bound(model, session.row_duals())
    logger.info(
        "LP relaxation: value %.6g, certified bound %.6g, %d fractional values (%.1f s)",
        result.objective,
        dual.bound,
        count_fractional(result.x),
        time.perf_counter() - start,
    )
    return LpSolve(result.x, dual, time.perf_counter() - start)


def seed_columns(lp: LpSolve, scale: float) -> np.ndarray:
    """Columns for the first restricted MIP: the LP support and the smallest reduced costs."""
    reduced = lp.dual.reduced
    n_keep = min(reduced.size, max(1, int(SEED_FRACTION * scale * reduced.size)))
    threshold = max(SEED_GAP * scale * abs(lp.dual.bound), np.partition(reduced, n_keep - 1)[n_keep - 1])
    return np.flatnonzero((reduced <= threshold) | (lp.x > LP_SUPPORT))


def full_model_figures(incumbent: float | None, certified_bound: float) -> dict:
    """Bound and gap of an interrupted rcfix run, for the full model.

    The restricted MIP's own bound holds for its columns only; the LP's dual bound
    (``certified_bound``) holds for the full model.
    """
    gap = relative_gap(incumbent, certified_bound) if incumbent is not None else math.nan
    return {"bound": float(certified_bound), "gap": gap if math.isfinite(gap) else None}


def solve_reduced_cost_fixing(
    model: IlpModel, graph: ProductGraph, curve: SpiderCurve, options: SolverOptions
) -> SolveResult:
    """LP bound, incumbent from a restricted MIP, reduced-cost fixing, final MIP on survivors."""
    start = time.perf_counter()
    try:
        lp = solve_lp(model, options)
    except LpNotSolved as stopped:
        kind = "no_solution" if stopped.result.status in ("no_solution", "feasible") else "error"
        message = f"LP relaxation not solved: {stopped.result.message}"
        return replace(
            stopped.result, status=kind, x=None, objective=math.inf, bound=-math.inf, gap=math.nan,
            wall_time=time.perf_counter() - start, message=message,
        )  # fmt: skip
    if lp is None:
        return SolveResult(
            "infeasible", None, math.inf, math.inf, math.nan, time.perf_counter() - start,
            model.n_vars, model.n_rows, model.nnz, "LP relaxation infeasible",
        )  # fmt: skip
    report_known(bound=lp.dual.bound)
    intersection_layers = np.flatnonzero(curve.is_intersection_layer)
    pool = cut_pool(curve.first_layer, intersection_layers, options)
    columns = seed_columns(lp, 1.0)
    incumbent, result, scale, certified = None, None, 1.0, False
    for phase in range(1, MAX_PHASES + 1):
        gap = max(SEED_MIP_GAP, options.mip_rel_gap) if phase == 1 else options.mip_rel_gap
        logger.info(
            "rcfix phase %d: MIP over %d of %d columns, relative gap %.2g",
            phase,
            columns.size,
            model.n_vars,
            gap,
        )
        n_cuts = pool.add_two_cycle_cuts(graph, intersection_layers, columns) if imposes_paths(model) else 0
        logger.info("rcfix phase %d: %d connectivity cuts for 2-cycles added up front", phase, n_cuts)
        phase_options = replace(remaining(options, start), mip_rel_gap=gap)
        try:
            result = solve_with_cuts(model, graph, phase_options, columns, incumbent, pool)
        except RunInterrupted as stop:
            stop.known.update(full_model_figures(stop.known.get("incumbent_objective"), lp.dual.bound))
            raise
        if result.status == "infeasible":
            if columns.size == model.n_vars:
                break
            scale *= 8.0
            wider = seed_columns(lp, scale) if phase < MAX_PHASES - 1 else np.arange(model.n_vars)
            columns = np.union1d(columns, wider)
            continue
        if result.x is None:
            break
        incumbent = result.x
        fixing = lp.dual
        if imposes_paths(model):  # every solution is one closed path: fix by path reduced costs
            fixing = lp.dual.along_paths(graph, cutoff=result.objective - lp.dual.bound)
        outside = fixing.bound_outside(columns)
        # a run at the target gap certifies the sub-model, and the full model if nothing outside
        # is cheaper (a run at the seed gap proves only that gap: see certified_mip_bound)
        certified = result.status == "optimal" and gap == options.mip_rel_gap and outside >= result.bound
        bound = min(result.bound, outside)
        result = replace(result, bound=bound, gap=relative_gap(result.objective, bound))
        report_known(result.objective, bound, used_columns(incumbent))
        logger.info(
            "rcfix phase %d: objective %.6g, bound for the full model %.6g", phase, result.objective, bound
        )
        if certified or result.status != "optimal":
            break  # certified for the full model, or the time limit stopped the phase
        columns = np.union1d(columns, fixing.surviving_columns(result.objective))
    if result.status == "optimal" and not certified:
        result = replace(result, status="feasible", message="gap not closed within the rcfix phases")
    return replace(result, wall_time=time.perf_counter() - start, n_vars=model.n_vars)
