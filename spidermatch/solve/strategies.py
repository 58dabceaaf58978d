"""Solving strategies: how the SpiderMatch ILP is handed to HiGHS.

Every strategy returns a :class:`~spidermatch.solve.highs.SolveResult` whose solution
is one closed path and whose bound is valid for every such path of the **full** model.

``plain``
    The full model to HiGHS's branch and cut, re-solved with connectivity cuts
    (:mod:`spidermatch.solve.connectivity`) while its optimum has detached cycles.
``rcfix``
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
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
import scipy.sparse as sp

from spidermatch.model.curve import SpiderCurve
from spidermatch.model.ilp import IlpModel, restrict_columns
from spidermatch.model.product_graph import ProductGraph
from spidermatch.shutdown import RunInterrupted
from spidermatch.solve.connectivity import (
    connectivity_cuts,
    detached_components,
    is_closed_path,
    two_cycle_components,
)
from spidermatch.solve.fixing import DualBound, dual_bound
from spidermatch.solve.highs import HighsSession, LpNotSolved, SolveResult, SolverOptions, relative_gap
from spidermatch.solve.layer_flow import SessionFlows
from spidermatch.solve.progress import report_known
from spidermatch.solve.repair import REPAIR_TIME_S, REPAIR_TIME_SHARE, repair_detached

logger = logging.getLogger(__name__)

Strategy = Callable[[IlpModel, ProductGraph, SpiderCurve, SolverOptions], SolveResult]
MAX_CUT_ROUNDS = 100


@dataclass
class CutPool:
    """Connectivity cuts found so far, in full-model columns (shared between sub-solves).

    ``two_cycles`` holds the product vertex pairs whose 2-cycle cuts are already in the pool.
    """

    rows: sp.csr_matrix | None = None
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    two_cycles: set = field(default_factory=set)
    flow_layers: set = field(default_factory=set)
    first_layer: np.ndarray | None = None

    def note_detached(self, graph: ProductGraph, components: list[np.ndarray]) -> set:
        """Remember the layers of detached components for flow rows; returns these layers.

        With ``first_layer`` (the curve's, shape (L,)) every layer of the same source vertex
        is added too: PES ties their out-flows, so a cycle cut off in one may move to another.
        """
        layers = {int(nodes[0] // graph.n_target) for nodes in components}
        if self.first_layer is not None:
            firsts = self.first_layer[sorted(layers)]
            layers |= set(np.flatnonzero(np.isin(self.first_layer, firsts)).tolist())
        self.flow_layers |= layers
        return layers

    def add(self, rows: sp.csr_matrix, lower: np.ndarray, upper: np.ndarray) -> None:
        """Remember new cut rows."""
        if self.rows is None:
            self.rows, self.lower, self.upper = rows, lower, upper
        else:
            self.rows = sp.vstack([self.rows, rows]).tocsr()
            self.lower = np.concatenate([self.lower, lower])
            self.upper = np.concatenate([self.upper, upper])

    def add_two_cycle_cuts(self, graph: ProductGraph, layers: np.ndarray, columns: np.ndarray) -> int:
        """Add the cuts of every 2-cycle among ``columns`` in ``layers`` not yet in the pool.

        Returns the number of rows added.
        """
        pairs = [p for p in two_cycle_components(graph, layers, columns) if tuple(p) not in self.two_cycles]
        if not pairs:
            return 0
        self.two_cycles.update(tuple(p) for p in pairs)
        rows, lower, upper = connectivity_cuts(graph, pairs)
        self.add(rows, lower, upper)
        return rows.shape[0]


def expand(x_sub: np.ndarray | None, columns: np.ndarray | None, n_vars: int) -> np.ndarray | None:
    """A sub-model solution (k,) as a full-model vector (n,), zeros elsewhere.

    Entries after the first k (flow variables of :mod:`spidermatch.solve.layer_flow`) are dropped.
    """
    if x_sub is None:
        return None
    if columns is None:
        return x_sub[:n_vars]
    x = np.zeros(n_vars)
    x[columns] = x_sub[: columns.size]
    return x


def cheapest_connected(
    graph: ProductGraph, session: HighsSession, columns: np.ndarray | None, n_vars: int
) -> np.ndarray | None:
    """The cheapest improving solution of ``session`` that is one closed walk, as a full vector (n,).

    Such a solution satisfies every connectivity cut, so it stays feasible when cuts are
    added and can restart the next run of the session as its incumbent.
    """
    for _, x_sub in sorted(session.improving, key=lambda found: found[0]):
        k = n_vars if columns is None else columns.size
        if is_closed_path(graph, x_sub[:k], columns):  # checked on the sub-model, expanded once
            return np.round(expand(x_sub, columns, n_vars))
    return None


def solve_with_cuts(
    model: IlpModel,
    graph: ProductGraph,
    options: SolverOptions,
    columns: np.ndarray | None = None,
    incumbent: np.ndarray | None = None,
    pool: CutPool | None = None,
    restricted: IlpModel | None = None,
    stop_when=None,
) -> SolveResult:
    """Branch and cut on (a column subset of) the model, with lazy connectivity cuts.

    Parameters
    ----------
    model : IlpModel or None
        The full model (None when ``restricted`` is given: the full one is never built).
    graph : ProductGraph
    options : SolverOptions
        Its ``time_limit`` bounds all HiGHS runs of this call together.
    columns : np.ndarray, shape (k,), optional
        Sorted variables to keep (the others are fixed to 0); all when omitted.
    incumbent : np.ndarray, shape (n,), optional
        A feasible full-model 0/1 vector that uses only ``columns``, offered as a start.
    pool : CutPool, optional
        Cuts known from earlier solves (used and extended).
    restricted : IlpModel, optional
        The model over ``columns`` (the rows of the full model that matter there), when it
        was built directly.
    stop_when : callable, optional
        ``stop_when(incumbent, dual_bound) -> bool``, asked at HiGHS's progress reports: True
        stops the MIP (status "feasible", or "no_solution"), for a caller that has what it
        can use from this MIP. ``incumbent`` is the cheapest *closed path* known (the start
        or an improving solution without detached cycles), not HiGHS's own incumbent, which
        may have detached cycles that a re-solve would cut off. A run it stops is not
        re-solved for detached cycles: their cuts and flow rows go to ``pool`` for later solves.

    Returns
    -------
    SolveResult
        With ``x`` in full-model columns and the bound of the (sub-)model.

    """
    start = time.perf_counter()
    pool = pool if pool is not None else CutPool()
    n_vars = graph.n_edges
    if restricted is not None:
        sub = restricted
    else:
        sub = model if columns is None else restrict_columns(model, columns)
    session = HighsSession(sub, options)
    column_ids = np.arange(n_vars) if columns is None else columns
    session.full_columns = column_ids
    flows = SessionFlows(graph, column_ids, session)
    if imposes_paths(sub):  # only one closed path counts as an incumbent (for stop_when and the repair)
        session.usable = lambda x_sub: is_closed_path(graph, x_sub[: column_ids.size], columns)
    session.stop_when = _leaving_time_to_repair(session, stop_when, options, start)

    def add_cuts(rows, lower, upper):
        session.add_rows(rows if columns is None else rows[:, columns], lower, upper)

    if pool.rows is not None:
        add_cuts(pool.rows, pool.lower, pool.upper)
    if pool.flow_layers:
        _cover(flows, pool.flow_layers)
    if incumbent is not None:
        _offer(session, flows, incumbent if columns is None else incumbent[columns])
    result = session.run()
    rounds = 0
    # connectivity cuts are valid for closed paths, which only flow conservation (CON) makes
    max_rounds = MAX_CUT_ROUNDS if imposes_paths(sub) else 0
    for round_number in range(1, max_rounds + 1):
        x = expand(result.x, columns, n_vars)
        if x is None:
            break
        components = detached_components(graph, x)
        if not components:
            break
        rows, lower, upper = connectivity_cuts(graph, components)
        pool.add(rows, lower, upper)  # for this session's next run and for later solves
        affected = pool.note_detached(graph, components)
        left = remaining(options, start)
        if left.time_limit <= 0:
            return _stopped_while_separating(result, graph, session, columns, n_vars, start, rounds)
        # a run stopped early may spend what is left on the repair; otherwise a share of it
        budget = left.time_limit if session.stopped_early else REPAIR_TIME_SHARE * left.time_limit
        left = replace(left, time_limit=min(REPAIR_TIME_S, budget))
        repaired = _repaired(sub, graph, column_ids, result.x, affected, pool, left)
        if session.stopped_early:  # the caller has what it needs, or the time is the repair's
            message = "stopped early (on request, or to leave time for the repair); detached cycles cut off"
            return _stopped_while_separating(
                result, graph, session, columns, n_vars, start, rounds, message, repaired
            )
        logger.info(
            "cut round %d: %d detached cycles, %d connectivity cuts",
            round_number,
            len(components),
            rows.shape[0],
        )
        add_cuts(rows, lower, upper)
        _cover(flows, pool.flow_layers)
        rounds = round_number
        restart = _cheapest_start(graph, session, columns, n_vars, repaired)
        if restart is not None:
            restart_sub = restart if columns is None else restart[columns]
            logger.info("restarting from the best closed path known, %.6g", sub.costs @ restart_sub)
            _offer(session, flows, restart_sub)
        result = session.run()  # the session gives each run only the time left
    x = expand(result.x, columns, n_vars)
    return replace(result, x=x, wall_time=time.perf_counter() - start, cut_rounds=rounds)


def _leaving_time_to_repair(session: HighsSession, stop_when, options: SolverOptions, start: float):
    """``stop_when``, and a stop in time for a repair when the limit nears with detached cycles.

    When HiGHS's cheapest solution has detached cycles and is cheaper than any closed path it
    has found, a run that ends at the time limit would have to fall back on the latter (on
    FAUST_r 076->077 at 4000 faces: the stay path, 415.2, for a solution of 2.0115 whose bound
    was 2.0067). So the run stops when only the repair's share of the limit is left, and the
    repair (:mod:`spidermatch.solve.repair`) turns that solution into a closed path.
    """
    if not math.isfinite(options.time_limit):
        return stop_when
    deadline = start + options.time_limit - min(REPAIR_TIME_S, REPAIR_TIME_SHARE * options.time_limit)

    def stop(incumbent: float, dual_bound: float) -> bool:
        if stop_when is not None and stop_when(incumbent, dual_bound):
            return True
        return session.best_unusable < session.best_usable and time.perf_counter() > deadline

    return stop


def _repaired(sub, graph, column_ids, x_sub, affected, pool, options) -> np.ndarray | None:
    """:func:`~spidermatch.solve.repair.repair_detached` as a full-model vector (n,), or None."""
    if x_sub is None or options.time_limit <= 0:
        return None
    repaired = repair_detached(sub, graph, column_ids, x_sub, affected, pool, options)
    return expand(repaired, column_ids, graph.n_edges)


def _cheapest_start(graph, session, columns, n_vars, repaired) -> np.ndarray | None:
    """The cheaper of the best connected improving solution and ``repaired`` (full vectors, n)."""
    candidates = [x for x in (cheapest_connected(graph, session, columns, n_vars), repaired) if x is not None]
    if not candidates:
        return None
    cost = session.costs[: graph.n_edges if columns is None else columns.size]
    return min(candidates, key=lambda x: float(cost @ (x if columns is None else x[columns])))


def _cover(flows: SessionFlows, layers) -> None:
    added = flows.cover(layers)
    if added:
        logger.info(
            "flow rows keep the path in one piece in %d layers (%d flow variables added)",
            len(flows.covered),
            added,
        )


def _offer(session: HighsSession, flows: SessionFlows, x_sub: np.ndarray) -> None:
    """Offer a single closed path x_sub (k,) as the start, with its flow values.

    A vector that is not one closed walk has no flow values; it is not offered (HiGHS would
    reject it under the flow rows anyway).
    """
    try:
        start = flows.start_vector(x_sub)
    except ValueError as error:
        logger.warning("start solution not offered: %s", error)
        return
    session.set_solution(start)


def _stopped_while_separating(
    result, graph, session, columns, n_vars, start, rounds,
    message: str = "time limit reached while separating detached cycles", repaired=None,
) -> SolveResult:  # fmt: skip
    """A run ended with detached cycles and gets no re-solve: the cheapest connected solution known.

    That is the case when the time limit came between cut rounds, or when ``stop_when`` stopped
    the run. HiGHS's bound stays valid (it holds without the newest cuts, so with them too); the
    solution is the cheapest of the improving ones that are one closed walk and ``repaired``
    (a full vector, see :mod:`spidermatch.solve.repair`), or the start solution.
    """
    connected = _cheapest_start(graph, session, columns, n_vars, repaired)
    if connected is None and session.offered is not None:
        connected = expand(session.offered[1], columns, n_vars)
    if connected is None:
        return replace(
            result, status="no_solution", x=None, objective=math.inf, gap=math.nan,
            wall_time=time.perf_counter() - start, cut_rounds=rounds, message=message,
        )  # fmt: skip
    used = connected if columns is None else connected[columns]
    objective = float(session.costs[: used.size] @ used)
    return replace(
        result, status="feasible", x=connected, objective=objective,
        gap=relative_gap(objective, result.bound), wall_time=time.perf_counter() - start,
        cut_rounds=rounds, message=message,
    )  # fmt: skip


def imposes_paths(model: IlpModel) -> bool:
    """True if the model imposes closed paths (CYC and CON), so that connectivity cuts apply."""
    return {"CYC", "CON"} <= set(model.row_families)


def solve_plain(
    model: IlpModel, graph: ProductGraph, curve: SpiderCurve, options: SolverOptions
) -> SolveResult:
    """The full model to HiGHS, with lazy connectivity cuts."""
    return solve_with_cuts(model, graph, options)


# ---------------------------------------------------------------------------------------
# rcfix: LP bound, restricted incumbent, reduced-cost fixing


LP_EXTRA = {"solver": "simplex", "simplex_strategy": 1}  # dual simplex: ~5x faster here than IPM
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


def count_fractional(x: np.ndarray, tolerance: float = 1e-6) -> int:
    """How many entries of an LP solution x (n,) are more than ``tolerance`` away from 0 and 1."""
    return int(np.sum((x > tolerance) & (x < 1 - tolerance)))


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
    return np.flatnonzero((reduced <= threshold) | (lp.x > 1e-9))


def full_model_figures(incumbent: float | None, certified_bound: float) -> dict:
    """Bound and gap of an interrupted rcfix run, for the full model.

    The restricted MIP's own bound holds for its columns only; the LP's dual bound
    (``certified_bound``) holds for the full model.
    """
    gap = relative_gap(incumbent, certified_bound) if incumbent is not None else math.nan
    return {"bound": float(certified_bound), "gap": gap if math.isfinite(gap) else None}


def remaining(options: SolverOptions, start: float) -> SolverOptions:
    """The options with the time limit reduced by what has elapsed since ``start``."""
    left = max(options.time_limit - (time.perf_counter() - start), 0.0)
    return replace(options, time_limit=left)


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
    pool = CutPool(first_layer=curve.first_layer)
    intersection_layers = np.flatnonzero(curve.is_intersection_layer)
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
        report_known(result.objective, bound, np.flatnonzero(incumbent > 0.5))
        logger.info(
            "rcfix phase %d: objective %.6g, bound for the full model %.6g", phase, result.objective, bound
        )
        if certified or result.status != "optimal":
            break  # certified for the full model, or the time limit stopped the phase
        columns = np.union1d(columns, fixing.surviving_columns(result.objective))
    if result.status == "optimal" and not certified:
        result = replace(result, status="feasible", message="gap not closed within the rcfix phases")
    return replace(result, wall_time=time.perf_counter() - start, n_vars=model.n_vars)


STRATEGIES: dict[str, Strategy] = {"plain": solve_plain, "rcfix": solve_reduced_cost_fixing}
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
    from spidermatch.model.lazy_model import LazyModel

    if name in LAZY_STRATEGIES:
        from spidermatch.solve.colgen import solve_column_generation

        return solve_column_generation(model, graph, curve, options)
    if name not in STRATEGIES:
        choices = sorted([*STRATEGIES, *LAZY_STRATEGIES])
        raise ValueError(f"unknown solving strategy {name!r}; choose from {choices}")
    if isinstance(model, LazyModel):
        model = model.full_model()
    return STRATEGIES[name](model, graph, curve, options)
