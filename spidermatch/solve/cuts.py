"""Solving with connectivity cuts: re-solve while the optimum has detached cycles.

Shared by every strategy: the cuts (:mod:`spidermatch.solve.connectivity`) and the
layer flows (:mod:`spidermatch.solve.layer_flow`) go in lazily, a pool keeps them across
sub-solves, and a solution with detached cycles is repaired into one closed path
(:mod:`spidermatch.solve.repair`) when the time runs out.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp

from spidermatch.model.ilp import IlpModel, restrict_columns
from spidermatch.model.product_graph import ProductGraph
from spidermatch.model.solution import used_columns
from spidermatch.solve.connectivity import (
    connectivity_cuts,
    detached_components_of_edges,
    is_closed_path,
    two_cycle_components,
)
from spidermatch.solve.highs import HighsSession
from spidermatch.solve.layer_flow import SessionFlows
from spidermatch.solve.repair import REPAIR_TIME_S, REPAIR_TIME_SHARE, repair_detached, stop_reserve
from spidermatch.solve.types import SolveResult, SolverOptions, relative_gap, remaining

logger = logging.getLogger(__name__)


MAX_CUT_ROUNDS = 100


@dataclass(frozen=True)
class DetachedSolution:
    """A solution that connectivity cuts cut off: its edge ids (m,), its cost and its cycles' layers."""

    used: np.ndarray
    objective: float
    layers: set


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
    detached: DetachedSolution | None = None

    def note_detached_solution(self, used: np.ndarray, objective: float, layers: set) -> None:
        """Keep the cheapest solution with detached cycles seen (its edge ids), for a later repair."""
        if self.detached is None or objective < self.detached.objective:
            self.detached = DetachedSolution(used, float(objective), set(layers))

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


def entries_on(rows: sp.spmatrix, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The non-zeros of ``rows`` (k, n) in ``columns`` (m,): (row, position in ``columns``, value).

    Never indexes ``rows`` by column: at 4000 faces the full model has 60 M columns, and
    scipy's column slicing allocates an array as long as the matrix is wide.
    """
    entries = sp.coo_matrix(rows)
    if columns.size == 0 or entries.nnz == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0)
    order = np.argsort(columns, kind="stable")
    where = np.searchsorted(columns[order], entries.col)
    where = np.minimum(where, columns.size - 1)
    hit = columns[order][where] == entries.col
    return entries.row[hit].astype(np.int64), order[where[hit]], entries.data[hit]


def rows_on_columns(rows: sp.spmatrix, columns: np.ndarray) -> sp.csr_matrix:
    """``rows[:, columns]`` (k, m) for rows over the full model's columns, via :func:`entries_on`."""
    row, position, value = entries_on(rows, columns)
    return sp.csr_matrix((value, (row, position)), shape=(rows.shape[0], columns.size))


def cut_pool(first_layer: np.ndarray, intersection_layers: np.ndarray, options: SolverOptions) -> CutPool:
    """An empty pool for the solves over one SpiderCurve, its flow layers as ``options.flow_rows`` says.

    Parameters
    ----------
    first_layer : np.ndarray, shape (L,)
        The curve's first layer of each layer's source vertex (ties the layers of one vertex).
    intersection_layers : np.ndarray, shape (k,)
        The curve's self-intersection layers: where a detached cycle can pay (PES), so where
        ``flow_rows="intersections"`` puts flow rows from the first MIP on.
    options : SolverOptions
    """
    pool = CutPool(first_layer=first_layer)
    if options.flow_rows == "intersections":
        pool.flow_layers |= {int(layer) for layer in intersection_layers}
    return pool


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
    repair_wider=None,
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
    repair_wider : callable, optional
        ``repair_wider(options) -> (x (n,), objective) or None``: a closed path near the solution
        with detached cycles just noted in ``pool`` (``pool.detached``), over columns that
        ``columns`` may lack, within ``options.time_limit``. Asked between cut rounds when no
        re-routing within ``columns`` mends that solution; the path it finds cannot start the
        re-solve (its columns may be outside), but it is the result if nothing cheaper follows.

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
        session.add_rows(rows if columns is None else rows_on_columns(rows, columns), lower, upper)

    if pool.rows is not None:
        add_cuts(pool.rows, pool.lower, pool.upper)
    if pool.flow_layers and imposes_paths(sub):  # like the cuts, flow rows hold for closed paths only
        _add_flow_rows(flows, pool.flow_layers)
    if incumbent is not None:
        offer_start_path(session, flows, incumbent if columns is None else incumbent[columns])
    result = session.run()
    best_bound = result.bound
    rounds = 0
    wider = None  # (x (n,), objective): the cheapest closed path found by ``repair_wider``
    # connectivity cuts are valid for closed paths, which only flow conservation (CON) makes
    max_rounds = MAX_CUT_ROUNDS if imposes_paths(sub) else 0
    for round_number in range(1, max_rounds + 1):
        if result.x is None:
            break
        used = column_ids[used_columns(result.x[: column_ids.size])]  # full-model edge ids
        components = detached_components_of_edges(graph, used)
        if not components:
            break
        rows, lower, upper = connectivity_cuts(graph, components)
        pool.add(rows, lower, upper)  # for this session's next run and for later solves
        affected = pool.note_detached(graph, components)
        pool.note_detached_solution(used, result.objective, affected)
        left = remaining(options, start)
        if left.time_limit <= 0:
            stopped = _stopped_while_separating(result, graph, session, columns, n_vars, start, rounds)
            return _with_wider_path(stopped, wider)
        # a run stopped early (or out of memory: no re-solve) may spend what is left on the
        # repair; otherwise a share of it
        last_run = session.stopped_early or result.out_of_memory
        budget = _repair_budget(options, start, 1.0 if last_run else REPAIR_TIME_SHARE)
        repaired = _repaired(sub, graph, column_ids, result.x, affected, pool, budget)
        if repaired is None and repair_wider is not None and not last_run:  # after a last run: the caller's
            wider = _cheaper(wider, repair_wider(_repair_budget(options, start)))
        if last_run:  # the caller has what it needs, the time is the repair's, or memory is short
            message = "stopped early (on request, or to leave time for the repair); detached cycles cut off"
            if result.out_of_memory:  # a re-solve with the cuts would need more memory still
                message = f"{result.message}; detached cycles cut off, no re-solve"
            stopped = _stopped_while_separating(
                result, graph, session, columns, n_vars, start, rounds, message, repaired
            )
            return _with_wider_path(stopped, wider)
        logger.info(
            "cut round %d: %d detached cycles, %d connectivity cuts",
            round_number,
            len(components),
            rows.shape[0],
        )
        add_cuts(rows, lower, upper)
        _add_flow_rows(flows, pool.flow_layers)
        rounds = round_number
        restart = _cheapest_start(graph, session, columns, n_vars, repaired)
        if restart is not None:
            restart_sub = restart if columns is None else restart[columns]
            logger.info("restarting from the best closed path known, %.6g", sub.costs @ restart_sub)
            offer_start_path(session, flows, restart_sub)
        result = session.run()  # the session gives each run only the time left
        best_bound = max(best_bound, result.bound)
        result = with_best_bound(result, best_bound)
    x = expand(result.x, columns, n_vars)
    result = replace(result, x=x, wall_time=time.perf_counter() - start, cut_rounds=rounds)
    return _with_wider_path(result, wider)


def _repair_budget(options: SolverOptions, start: float, share: float = REPAIR_TIME_SHARE) -> SolverOptions:
    """``options`` with a repair's time: ``share`` of what is left since ``start``, at most REPAIR_TIME_S."""
    left = remaining(options, start)
    return replace(left, time_limit=min(REPAIR_TIME_S, share * left.time_limit))


def _cheaper(known, found):
    """The cheaper of two (x, objective) pairs, either of which may be None."""
    if found is None or (known is not None and known[1] <= found[1]):
        return known
    return found


def _with_wider_path(result: SolveResult, wider) -> SolveResult:
    """``result``, or the closed path ``wider`` = (x (n,), objective) of a wider repair if cheaper.

    That path only replaces the solution: the bound stays the (sub-)model's, which the path
    does not touch; the status is "feasible" (the path proves nothing).
    """
    if wider is None or (result.x is not None and result.objective <= wider[1]):
        return result
    x, objective = wider
    message = f"a closed path from a wider repair, cheaper than the sub-model's answer ({result.message})"
    return replace(
        result, status="feasible", x=x, objective=objective,
        gap=relative_gap(objective, min(result.bound, objective)), message=message,
    )  # fmt: skip


def with_best_bound(result: SolveResult, best_bound: float) -> SolveResult:
    """``result`` with the best bound of every run of a cut loop (its gap recomputed).

    Each run adds rows that only cut off solutions with detached cycles, so an earlier run's
    bound (over more solutions) still holds for a later one; a later run stopped before its
    root bound (HiGHS then reports -inf) keeps the earlier one. Never above the objective.
    """
    bound = max(result.bound, best_bound)
    if math.isfinite(result.objective):
        bound = min(bound, result.objective)
    if bound == result.bound:
        return result
    return replace(result, bound=bound, gap=relative_gap(result.objective, bound))


def _leaving_time_to_repair(session: HighsSession, stop_when, options: SolverOptions, start: float):
    """``stop_when``, and a stop in time for a repair when the limit nears with detached cycles.

    When HiGHS's cheapest solution has detached cycles and is cheaper than any closed path it
    has found, a run that ends at the time limit would have to fall back on the latter, often
    the stay path at many times the cost of that solution (measurements: bench/README.md, solver
    constants). So the run stops when only the repair's share of the limit is left, and the
    repair (:mod:`spidermatch.solve.repair`) turns that solution into a closed path.
    """
    if not math.isfinite(options.time_limit):
        return stop_when
    deadline = start + options.time_limit - stop_reserve(options.time_limit)

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


def _add_flow_rows(flows: SessionFlows, layers) -> None:
    added = flows.cover(layers)
    if added:
        logger.info(
            "flow rows keep the path in one piece in %d layers (%d flow variables added)",
            len(flows.covered),
            added,
        )


def offer_start_path(session: HighsSession, flows: SessionFlows, x_sub: np.ndarray) -> None:
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
