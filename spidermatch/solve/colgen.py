"""``colgen``: certify the SpiderMatch ILP without ever building its full model.

Design
------
The full model has one column per product edge (3.7 M at 1000 faces, ~15 M at 2000),
but an optimal path uses about one per curve position, and the LP relaxation needs
few more. ``colgen`` works on a :class:`~spidermatch.model.lazy_model.LazyModel`, which
holds only what defines the columns and produces any of them on demand:

1. **Seed.** Per curve position the edges among the ``SEED_NEIGHBOURS`` targets of
   lowest feature cost and their 1-ring, and a band around a cheap closed path
   (:mod:`spidermatch.solve.path_seed`: without it, column generation needs many rounds
   wherever the features alone miss the optimal path), plus the *stay seed*: the stay edges at one
   target vertex y0 in every layer. Alone, the stay seed is a solution of every
   constraint family (one boundary crossing per layer, a closed flow, equal out-flows
   in every layer, no counted edge for ANS) and of every connectivity cut (it has no
   intra edges), so every restricted LP and MIP below is feasible.
2. **Column generation for the LP.** Solve the restricted LP (the columns built so
   far, the rows they touch); price *every* column of the full model with the LP's row duals,
   one block of layers at a time (:meth:`LazyModel.block_reduced_costs`); add the
   most negative ones; repeat until no column outside has a negative reduced cost or
   the Lagrangian bound L(y) meets the restricted LP's value.
3. **Growing MIPs.** With the final duals y and bound L = L(y) (if the LP solution is
   integral, one closed path and within the target gap of L, it is certified at once), the
   last round's pricing pass keeps the columns of reduced cost up to ``PRICED_SPAN |L|``
   (:func:`~spidermatch.solve.pricing.up_to` slices it for each step) and replaces each
   reduced cost by the column's *path reduced cost* R_j >= r_j
   (:mod:`spidermatch.solve.path_costs`: the least reduced cost of a whole closed path
   through j); a MIP at the target gap over the columns of
   path reduced cost at most a threshold t (plus the LP support, the stay seed and the
   incumbent's columns), started from the incumbent U.
4. **Certify or widen.** If U <= L + t, every column that a solution of cost <= U could
   use is in the MIP (reduced-cost fixing against U) and its proof covers the full model.
   Otherwise t grows to U - L if that is at most ``JUMP`` t (8 t), else to ``GROWTH`` t
   (4 t), and the next MIP starts from U: step by step, never all at once.

The certificate
---------------
The restricted LP's duals, extended by zeros to the rows it leaves out and sign-corrected
(:mod:`spidermatch.solve.fixing`), are multipliers y for every row of the full model, and
``L(y) = sum_i y_i b_i(y) + sum_j min(0, r_j)``, summed over *all* columns of the full model
(built or not), is a lower bound on every feasible x in [0, 1]^n; a solution that uses column j
costs at least ``L(y) + R_j``. A MIP over a column set C that holds every column with
``R_j <= t`` has a bound B_C for the solutions over C, and every other solution costs at least
``O = L(y) + min_{j not in C} max(R_j, 0) > L(y) + t``. So ``max(L(y), min(B_C, O))`` is a
lower bound for the full model (HiGHS's bound entering through :func:`certified_mip_bound`,
as for ``rcfix``), and the incumbent is certified when ``O`` is at least B_C, which holds as
soon as ``U <= L(y) + t``, or when it is within the target gap of that bound. The proof, with
every step: ``docs/method.md``, section 7 ("Column generation: why the certificate holds").
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from spidermatch.memory import GIB, available_memory
from spidermatch.model.curve import SpiderCurve
from spidermatch.model.ilp import IlpModel
from spidermatch.model.lazy_model import LazyModel
from spidermatch.model.product_graph import ProductGraph
from spidermatch.model.solution import LP_SUPPORT, used_columns
from spidermatch.shutdown import RunInterrupted
from spidermatch.solve.connectivity import connectivity_cuts, detached_components
from spidermatch.solve.cuts import cut_pool, entries_on, imposes_paths, rows_on_columns, solve_with_cuts
from spidermatch.solve.fixing import sign_corrected_duals
from spidermatch.solve.highs import LP_EXTRA, HighsSession
from spidermatch.solve.lp_cuts import (
    LP_CUT_MIN_GAIN,
    LP_CUT_ROUNDS,
    LP_CUT_TIME_SHARE,
    CutDuals,
    violated_cut_sets,
)
from spidermatch.solve.pricing import Pricing, price, up_to, with_path_reduced_costs
from spidermatch.solve.progress import report_known
from spidermatch.solve.repair import (
    REPAIR_TIME_S,
    REPAIR_TIME_SHARE,
    repair_with_nearby_columns,
    stop_reserve,
)
from spidermatch.solve.seeds import path_band_seed, stay_seed
from spidermatch.solve.types import (
    LpNotSolved,
    SolveResult,
    SolverOptions,
    count_fractional,
    relative_gap,
    remaining,
)

logger = logging.getLogger(__name__)

MAX_ADD = 100_000  # columns added per pricing round at most (the most negative ones)
LP_REL_GAP = 1e-7  # column generation stops when the Lagrangian bound is this close to the LP value
MAX_LP_ROUNDS = 200
FIRST_STEP = 4e-3  # first MIP: columns with reduced cost <= this times |L(y)| (about the LP's gap with
# learned features at the default resolution) ...
FIRST_STEP_LAYERS = 600  # ... up to this many curve positions (about the curves' length there); see
# first_threshold
FIRST_STEP_MAX_SCALE = 2.0  # ... and at most twice that on longer curves
PRICED_SPAN = 0.02  # one pricing pass keeps the columns up to this times |L(y)| for all the MIPs
GROWTH = 4.0  # each further MIP: the threshold grows by at most this factor (or to U - L(y))
JUMP = 8.0  # ... unless U - L(y) is within this factor: then straight to U - L(y)
MAX_STEPS = 10
MIP_BYTES_PER_COLUMN = 5 * 1024  # a restricted MIP's peak memory in HiGHS, per column (with cuts, flows,
# the root's analytic-centre copy), rounded up from measurements (bench/README.md, solver constants)
LAST_STEP_MIN_S = 5.0  # a further MIP starts only with at least this much time left ...
LAST_STEP_MIN_SHARE = 0.05  # ... and this share of the time limit: building and loading a wider MIP
# does not stop at the time limit (measurements: bench/README.md, solver constants)


@dataclass(frozen=True, eq=False)
class ColgenLp:
    """The LP relaxation solved by column generation.

    Attributes
    ----------
    y : np.ndarray, shape (n_rows,)
        Sign-corrected row multipliers of the last restricted LP.
    bound : float
        ``L(y)`` over every column of the full model.
    value : float
        The last restricted LP's optimum (an upper bound on the full LP's).
    columns : np.ndarray, shape (k,)
        Sorted edge ids built.
    x : np.ndarray, shape (k,)
        The restricted LP's solution on ``columns``.
    rounds : int
    pricing : Pricing
        The last pricing pass, for ``y``: the columns of reduced cost up to its cutoff.
    n_rows : int
        Rows of the last restricted LP (those its columns touch, and its cuts).
    cut_duals : CutDuals
        The correction of reduced costs by the duals of the cuts (part of the multipliers).
    cuts : scipy.sparse.csr_matrix, shape (k, n_vars)
        The connectivity cuts in the LP (``>= 0`` rows over the full model's columns).

    """

    y: np.ndarray
    bound: float
    value: float
    columns: np.ndarray
    x: np.ndarray
    rounds: int
    pricing: Pricing
    n_rows: int
    cut_duals: CutDuals
    cuts: sp.csr_matrix

    def support(self, tolerance: float = LP_SUPPORT) -> np.ndarray:
        """Edge ids the LP solution uses, sorted."""
        return self.columns[self.x > tolerance]


def _bounds_only(lazy: LazyModel) -> IlpModel:
    lower, upper = lazy.row_bounds
    return IlpModel(np.zeros(0), sp.csc_matrix((lazy.n_rows, 0)), lower, upper, {})


class RestrictedLp:
    """The LP over the columns built so far, the rows they touch and the cuts added, in one HiGHS session.

    A row that no built column touches is ``0 = 0`` or ``0 <= 1``; leaving it out changes
    neither the LP's optimum nor its other duals, and 0 is an optimal dual for it. Rows are
    added (empty) when a new column first touches them, before the column itself. Connectivity
    cuts (:mod:`spidermatch.solve.lp_cuts`) are rows too, over every column of the full model;
    a column added later gets its coefficients in them.
    """

    def __init__(self, lazy: LazyModel, seed: np.ndarray, options: SolverOptions) -> None:
        self.lazy = lazy
        self.rows = np.zeros(0, dtype=np.int64)  # full-model row of each session row, -1 for a cut
        self.position = np.full(lazy.n_rows, -1, dtype=np.int64)  # session row of each full-model row
        self.cuts = sp.coo_matrix((0, lazy.n_vars))  # cut rows over the full model's columns
        self.columns = np.asarray(seed, dtype=np.int64)  # in session order
        sub = lazy.submodel(seed)
        self._touch(sub.matrix.indices)
        lower, upper = lazy.row_bounds
        model = IlpModel(sub.costs, self._remap(sub.matrix, seed), lower[self.rows], upper[self.rows], {})
        self.session = HighsSession(model, options, relax=True)

    def _touch(self, row_indices: np.ndarray) -> np.ndarray:
        touched = np.unique(row_indices)
        fresh = touched[self.position[touched] < 0]
        self.position[fresh] = np.arange(self.rows.size, self.rows.size + fresh.size)
        self.rows = np.concatenate([self.rows, fresh])
        return fresh

    def _remap(self, matrix: sp.csc_matrix, columns: np.ndarray) -> sp.csc_matrix:
        """Model coefficients (n_rows, k) of ``columns`` (k,) on session rows, with the cut rows'."""
        entries = matrix.tocoo()
        cut, column, value = entries_on(self.cuts, columns)
        rows = np.concatenate([self.position[entries.row], np.flatnonzero(self.rows < 0)[cut]])
        cols = np.concatenate([entries.col, column])
        remapped = sp.csc_matrix(
            (np.concatenate([entries.data, value]), (rows, cols)),
            shape=(self.rows.size, matrix.shape[1]),
        )
        remapped.sum_duplicates()
        remapped.indices = remapped.indices.astype(np.int32)
        return remapped

    def add(self, columns: np.ndarray) -> None:
        """Append the columns (edge ids, k) and any row they touch first."""
        sub = self.lazy.submodel(columns)
        fresh = self._touch(sub.matrix.indices)
        if fresh.size:
            lower, upper = self.lazy.row_bounds
            empty = sp.csr_matrix((fresh.size, self.session.n_vars))
            self.session.add_rows(empty, lower[fresh], upper[fresh])
        self.session.add_columns(sub.costs, self._remap(sub.matrix, columns))
        self.columns = np.concatenate([self.columns, columns])

    def add_cuts(self, rows: sp.csr_matrix, lower: np.ndarray, upper: np.ndarray) -> None:
        """Append cut rows (k, n_edges of the full model), ``lower <= rows @ x <= upper``."""
        self.session.add_rows(rows_on_columns(rows, self.columns), lower, upper)
        self.rows = np.concatenate([self.rows, np.full(rows.shape[0], -1, dtype=np.int64)])
        self.cuts = sp.vstack([self.cuts, rows]).tocoo()

    def duals(self) -> tuple[np.ndarray, CutDuals]:
        """Row duals of the last solve: the model's and the cuts' correction of reduced costs.

        The first (n_rows,) covers every row of the full model, 0 on the rows left out; the cuts'
        duals are sign-corrected (``>=`` rows: mu >= 0).
        """
        duals = self.session.row_duals()
        model_rows = self.rows >= 0
        y = np.zeros(self.lazy.n_rows)
        y[self.rows[model_rows]] = duals[model_rows]
        return y, CutDuals.of(self.cuts, np.maximum(duals[~model_rows], 0.0))


def generate_columns(lazy: LazyModel, seed: np.ndarray, options: SolverOptions) -> ColgenLp:
    """Solve the LP relaxation of the full model by column generation from ``seed`` (sorted ids).

    Where solutions are closed paths (:func:`~spidermatch.solve.cuts.imposes_paths`), each time
    no column prices negative the connectivity cuts the LP solution violates are added
    (:mod:`spidermatch.solve.lp_cuts`, at most ``LP_CUT_ROUNDS`` times) and pricing goes on with
    their duals, so the bound is that of the LP with those cuts.
    """
    lp_options = replace(options, presolve="off", extra={**options.extra, **LP_EXTRA})
    restricted = RestrictedLp(lazy, seed, lp_options)
    built = np.zeros(lazy.n_vars, dtype=bool)
    built[seed] = True
    bounds = _bounds_only(lazy)
    cut_rounds = LP_CUT_ROUNDS if options.lp_cuts and imposes_paths(lazy) else 0
    last_cut_lp = -math.inf  # the LP's value when cuts were last added
    start, complete = time.perf_counter(), None  # the last round whose figures are all known
    for round_number in range(1, MAX_LP_ROUNDS + 1):
        result = restricted.session.run()
        if result.status != "optimal":
            if complete is None:
                raise LpNotSolved(result)
            # stopped after cuts were added to a complete LP: its bound and duals stay valid
            logger.info("colgen: LP stopped after cuts (%s); the last complete round stands", result.message)
            return complete
        solved = restricted.columns  # the columns of this solve (x's order); later ones come after
        row_duals, cut_duals = restricted.duals()
        y = sign_corrected_duals(bounds, row_duals)
        # one pass serves both: the negative columns for this round and, after the last round,
        # the columns up to PRICED_SPAN |L| for the MIPs
        pricing = price(lazy, y, PRICED_SPAN * max(abs(result.objective), 1.0), cut_duals)
        negative = (pricing.reduced < -1e-12 * max(abs(result.objective), 1.0)) & ~built[pricing.columns]
        new = pricing.columns[negative]
        logger.info(
            "colgen round %d: %d columns, %d rows, LP %.8g, bound %.8g, %d priced negative",
            round_number, int(built.sum()), restricted.rows.size, result.objective, pricing.bound, new.size,
        )  # fmt: skip
        if new.size == 0 or relative_gap(result.objective, pricing.bound) <= LP_REL_GAP:
            complete = _colgen_lp(solved, y, cut_duals, pricing, result, round_number, restricted)
            tailing_off = relative_gap(result.objective, last_cut_lp) < LP_CUT_MIN_GAIN
            late = time.perf_counter() - start > LP_CUT_TIME_SHARE * options.time_limit
            if cut_rounds == 0 or tailing_off or late or not _cuts_added(lazy, restricted, result.x):
                return complete
            cut_rounds, last_cut_lp = cut_rounds - 1, result.objective
            continue
        if new.size > MAX_ADD:
            new = np.sort(new[np.argpartition(pricing.reduced[negative], MAX_ADD - 1)[:MAX_ADD]])
        restricted.add(new)
        built[new] = True
    last = _colgen_lp(solved, y, cut_duals, pricing, result, round_number, restricted)
    # out of rounds (while pricing after cuts, the complete round's bound may still be the higher)
    return complete if complete is not None and complete.bound > last.bound else last


def _colgen_lp(solved, y, cut_duals, pricing, result, round_number, restricted) -> ColgenLp:
    """The figures of one solved round (``solved``: its columns in x's order)."""
    by_id = np.argsort(solved)
    return ColgenLp(
        y, pricing.bound, result.objective, solved[by_id], result.x[by_id], round_number, pricing,
        restricted.rows.size, cut_duals, restricted.cuts.tocsr(),
    )  # fmt: skip


def _cuts_added(lazy: LazyModel, restricted: RestrictedLp, x: np.ndarray) -> bool:
    """Add the connectivity cuts that the LP solution x (session order) violates; whether any were."""
    sets = violated_cut_sets(lazy.graph, restricted.columns, x)
    if not sets:
        return False
    rows, lower, upper = connectivity_cuts(lazy.graph, sets)
    restricted.add_cuts(rows, lower, upper)
    logger.info(
        "colgen: %d connectivity cuts (%d node sets) the LP solution violates", rows.shape[0], len(sets)
    )
    return True


def _lp_incumbent(lazy: LazyModel, lp: ColgenLp) -> np.ndarray | None:
    """The LP solution as a full 0/1 vector if it is integral and one closed walk, else None."""
    if count_fractional(lp.x) > 0:
        return None
    x = np.zeros(lazy.n_vars)
    x[lp.columns] = np.rint(lp.x)
    return None if detached_components(lazy.graph, x) else x


def _restricted_mip(lazy, columns, options, incumbent, pool, layers, stop_when, proven) -> SolveResult:
    """The step's MIP over ``columns``, from ``incumbent`` (n,); ``proven``: a bound for the full model."""
    if imposes_paths(lazy):  # connectivity cuts hold for closed paths only (an ablation without CON)
        pool.add_two_cycle_cuts(lazy.graph, layers, columns)
    logger.info("colgen: MIP over %d of %d columns, gap %.2g", columns.size, lazy.n_vars, options.mip_rel_gap)
    repair_wider = _nearby_repair_between_rounds(lazy, columns, pool, objective_of(lazy, incumbent), proven)
    return solve_with_cuts(
        None, lazy.graph, options, columns, incumbent, pool, lazy.compact_submodel(columns), stop_when,
        repair_wider,
    )  # fmt: skip


def _nearby_repair_between_rounds(lazy, columns, pool, incumbent: float, proven: float):
    """``repair_wider`` for :func:`~spidermatch.solve.cuts.solve_with_cuts`: the nearby-column repair.

    A restricted MIP whose optimum has detached cycles that no re-routing within its columns
    mends is re-solved with their cuts from the best closed path it knows, often the stay path;
    when its columns hold no cheap closed path at all, the re-solve can end there. The
    nearby-column repair (:func:`_nearby_repair`) gets its turn at once instead of only after
    the MIP: each path it finds is reported (a run stopped from outside keeps it) and becomes
    the MIP's answer unless the re-solve finds a cheaper one. ``incumbent`` is the cost of the
    best closed path known before the MIP, ``proven`` a bound for the full model.
    """
    best = incumbent

    def repair(options: SolverOptions):
        nonlocal best
        found = _nearby_repair(lazy, columns, pool, options, best)
        if found is not None:
            best = found[1]
            report_known(found[1], proven, used_columns(found[0]))
        return found

    return repair


def _no_result(kind: str, message: str, lazy: LazyModel, start: float, bound: float = -math.inf):
    return SolveResult(
        kind,
        None,
        math.inf,
        bound,
        math.nan,
        time.perf_counter() - start,
        lazy.n_vars,
        lazy.n_rows,
        0,
        message,
    )


def _lp_certified(
    lazy: LazyModel, lp: ColgenLp, x: np.ndarray, objective: float, start: float
) -> SolveResult:
    """An integral, connected LP solution x (n_vars,) of cost ``objective`` within the target gap of L(y)."""
    bound = lp.bound
    logger.info("colgen: the LP solution is integral and one closed path, certified by L(y) alone")
    return SolveResult(
        "optimal",
        x,
        objective,
        bound,
        relative_gap(objective, bound),
        time.perf_counter() - start,
        lazy.n_vars,
        lp.n_rows,  # the restricted LP's, the last model HiGHS solved
        0,
        "Optimal (LP solution integral)",
    )


def certify_by_steps(lazy, lp, options, start, pool, layers, built) -> SolveResult:
    """Steps 3-4 of the module docstring: MIPs over ``{r_j <= t}`` for a growing threshold t.

    Every MIP runs at the target gap: its columns are few (the first one usually already holds
    the optimum), and stopping it at a looser gap for a quick incumbent leaves a dearer U and so
    a wider next threshold (measurements: bench/README.md, solver constants). Each runs over the
    columns of reduced cost at most t, the LP support, the stay seed and the incumbent's columns,
    started from the incumbent. Every column
    outside has ``r_j > t``, so any solution using one costs more than ``L + t``: once the
    incumbent U satisfies ``U <= L + t`` the MIP's proof covers the full model. Otherwise
    ``t`` grows (:func:`next_threshold`) to at most ``U - L``, and strictly: a MIP that does
    not certify has ``L + min_{j not in C} r_j < B_C <= U`` with every such ``r_j > t``.
    A MIP stops early once it cannot certify and has nothing more to give the next step
    (:func:`futile_mip_stop`).
    The column sets are appended to ``built``. The proof: docs/method.md, section 7.
    """
    incumbent = _lp_incumbent(lazy, lp)
    if incumbent is not None:
        objective = objective_of(lazy, incumbent)
        if relative_gap(objective, lp.bound) <= options.mip_rel_gap:
            return _lp_certified(lazy, lp, incumbent, objective, start)
    stay = stay_seed(lazy)
    if incumbent is None:  # the stay path satisfies every row and cut: a run that times out still has it
        incumbent = np.zeros(lazy.n_vars)
        incumbent[stay] = 1.0
    report_known(objective_of(lazy, incumbent), lp.bound, used_columns(incumbent))
    base = np.union1d(lp.support(), stay)
    threshold, best = first_threshold(lp.bound, lazy.graph.n_layers), None
    priced = with_path_reduced_costs(lazy, lp.pricing)
    for step in range(1, MAX_STEPS + 1):
        if threshold > priced.cutoff:
            priced = with_path_reduced_costs(lazy, price(lazy, lp.y, threshold, lp.cut_duals))
        selection = up_to(priced, threshold)
        columns = np.union1d(selection.columns, base)
        if incumbent is not None:
            columns = np.union1d(columns, used_columns(incumbent))
        too_large = mip_memory_problem(columns.size, _room(options))
        if too_large:
            return _stopped_before_mip(lazy, lp, incumbent, best, too_large)
        built.append(columns)
        outside = lp.bound + max(selection.min_outside, 0.0)
        stop_when = futile_mip_stop(outside, lp.bound + JUMP * threshold, options.mip_rel_gap)
        proven = lp.bound if best is None else best.bound  # an earlier step's bound (>= L) still holds
        try:
            result = _restricted_mip(
                lazy, columns, remaining(options, start), incumbent, pool, layers, stop_when, proven
            )
        except RunInterrupted as stop:  # its figures hold for the restricted MIP only
            stop.known.update(interrupted_full_model_figures(stop.known, proven, outside))
            raise
        if result.x is None:
            if result.out_of_memory and best is not None:  # keep the last step's, and say why
                return replace(best, status="feasible", message=_out_of_memory(columns))
            break  # time limit before a solution of this step: keep the last one
        # valid lower bounds for the full model: this step's and ``proven`` (L(y), or an earlier step's:
        # a wider MIP stopped early can prove less than a narrower one did)
        bound = max(proven, min(result.bound, outside))
        proven_here = result.status == "optimal" and outside >= result.bound  # the MIP's proof covers all
        certified = proven_here or relative_gap(result.objective, bound) <= options.mip_rel_gap
        if not certified:  # a cheaper solution cut off for detached cycles: re-route it
            result = _with_nearby_repair(lazy, columns, pool, result, remaining(options, start), options)
            certified = relative_gap(result.objective, bound) <= options.mip_rel_gap
        incumbent = result.x
        best = replace(result, bound=bound, gap=relative_gap(result.objective, bound))
        report_known(result.objective, bound, used_columns(incumbent))
        logger.info(
            "colgen step %d: threshold %.3g, objective %.8g, bound for the full model %.8g",
            step, threshold, result.objective, bound,
        )  # fmt: skip
        if certified:
            return replace(best, status="optimal")
        if result.status not in ("optimal", "feasible"):
            return replace(best, status="feasible")
        if result.out_of_memory:  # a wider MIP would need more
            return replace(best, status="feasible", message=_out_of_memory(columns))
        seconds_left = remaining(options, start).time_limit
        if too_little_time_for_a_step(options, seconds_left):
            message = f"not certified: {seconds_left:.1f} s left, too little for a wider MIP ({best.message})"
            return replace(best, status="feasible", message=message)
        if result.status == "feasible":  # time was left: stopped by stop_when
            logger.info(
                "colgen step %d: MIP bound %.8g above what it could certify: widening", step, result.bound
            )
        threshold = next_threshold(threshold, result.objective - lp.bound)
    if best is None:
        return replace(result, bound=lp.bound, gap=math.nan)
    return replace(best, status="feasible", message=f"not certified within {MAX_STEPS} steps")


def _out_of_memory(columns: np.ndarray) -> str:
    return f"not certified: the restricted MIP over {len(columns)} columns ran out of memory"


def _with_nearby_repair(
    lazy, columns, pool, result: SolveResult, options: SolverOptions, whole: SolverOptions
) -> SolveResult:
    """``result`` with a cheaper closed path near the solution its MIP cut off, when one is found.

    The restricted MIP may end with only an expensive closed path (the stay path) after its
    cheapest solution had detached cycles that no re-routing within its columns mends
    (:func:`_nearby_repair`). The closed path found is an incumbent: the step's bound is
    untouched, so the certificate (docs/method.md, section 7) holds as before. ``options``
    holds the time left, ``whole`` the run's: the repair gets a share of what is left, or all
    of it once the run is in its last :func:`~spidermatch.solve.repair.stop_reserve` (a MIP
    stopped for it).
    """
    seconds = options.time_limit
    if seconds > stop_reserve(whole.time_limit):
        seconds = min(REPAIR_TIME_S, REPAIR_TIME_SHARE * seconds)
    found = _nearby_repair(lazy, columns, pool, replace(options, time_limit=seconds), result.objective)
    if found is None:
        return result
    status = "feasible" if result.status == "optimal" else result.status
    return replace(result, x=found[0], objective=found[1], status=status)


def _nearby_repair(lazy, columns, pool, options: SolverOptions, below: float):
    """A closed path near ``pool.detached`` costing less than ``below``: (x (n,), objective) or None.

    :func:`~spidermatch.solve.repair.repair_with_nearby_columns` re-routes the solution with
    detached cycles over the restricted columns ``columns`` and the full model's columns near it,
    within ``options.time_limit``. The pool's solution is taken (a later one is noted anew).
    """
    detached, pool.detached = pool.detached, None
    if detached is None or detached.objective >= below or options.time_limit <= 0:
        return None
    repaired = repair_with_nearby_columns(lazy, columns, detached.used, detached.layers, pool, options)
    if repaired is None:
        return None
    objective = objective_of(lazy, repaired)
    if objective >= below:
        return None
    logger.info(
        "colgen: a closed path of cost %.8g near the cut-off solution of cost %.8g (best known was %.8g)",
        objective, detached.objective, below,
    )  # fmt: skip
    return repaired, objective


def mip_memory_problem(n_columns: int, room: int | None = None) -> str | None:
    """Why a restricted MIP over ``n_columns`` columns should not start (too little memory), or None.

    ``room``: bytes this process may still allocate (default: :func:`available_memory`; None: unknown).
    """
    room = available_memory() if room is None else room
    needed = n_columns * MIP_BYTES_PER_COLUMN
    if room is None or needed <= room:
        return None
    return (
        f"the next MIP over {n_columns} columns would need about {needed / GIB:.1f} GiB, "
        f"but only {room / GIB:.1f} GiB of memory is available"
    )


def _room(options: SolverOptions) -> int | None:
    """Bytes this solve may still allocate, with its ``memory_share`` of the free memory (None: unknown)."""
    return available_memory(options.memory_share)


def _stopped_before_mip(
    lazy, lp, incumbent: np.ndarray, best: SolveResult | None, reason: str
) -> SolveResult:
    """The result when the next MIP is not started (``reason``): the last step's, or the incumbent's."""
    logger.warning("colgen: %s: stopping with the best closed path known", reason)
    message = f"not certified: {reason}"
    if best is not None:
        return replace(best, status="feasible", message=message)
    objective = objective_of(lazy, incumbent)
    return SolveResult(
        "feasible", incumbent, objective, lp.bound, relative_gap(objective, lp.bound), 0.0,
        lazy.n_vars, lp.n_rows, 0, message,
    )  # fmt: skip


def interrupted_full_model_figures(known: dict, lp_bound: float, outside: float) -> dict:
    """Bound and gap for the full model when a signal stopped a restricted MIP.

    The MIP's bound B_C (``known["bound"]``) holds for solutions over its columns only; as in
    :func:`certify_by_steps`, ``max(L(y), min(B_C, O))`` holds for the full model, with ``O`` =
    ``outside``, the bound on every solution using a column left out.
    """
    restricted = known.get("bound")
    bound = lp_bound if restricted is None else max(lp_bound, min(restricted, outside))
    incumbent = known.get("incumbent_objective")
    gap = relative_gap(incumbent, bound) if incumbent is not None else math.nan
    return {"bound": float(bound), "gap": gap if math.isfinite(gap) else None}


def too_little_time_for_a_step(options: SolverOptions, seconds_left: float) -> bool:
    """Whether a further MIP step should not start: too little of the time limit is left.

    A wider MIP cannot certify in a few seconds, and building and loading it does not stop
    at the time limit.
    """
    if not math.isfinite(options.time_limit):
        return False
    return seconds_left < max(LAST_STEP_MIN_S, LAST_STEP_MIN_SHARE * options.time_limit)


def first_threshold(bound: float, n_layers: int) -> float:
    """The first MIP's reduced-cost threshold: ``FIRST_STEP |L|``, scaled up with the curve's length.

    The LP relaxation's gap grows with the resolution, so a first threshold fixed relative to
    |L| starts too low on longer curves and costs a MIP step; raised for every resolution, it
    makes the first MIP of the shorter curves larger than they need and slower. The scale is
    capped at ``FIRST_STEP_MAX_SCALE``: on a long curve a wider first threshold can put so many
    columns into the first MIP, even where the LP's gap is small, that HiGHS stays in its root
    node for minutes (measurements: bench/README.md, solver constants).
    """
    return FIRST_STEP * abs(bound) * min(FIRST_STEP_MAX_SCALE, max(1.0, n_layers / FIRST_STEP_LAYERS))


def futile_mip_stop(outside: float, near: float, rel_gap: float):
    """When a restricted MIP can no longer help: ``stop_when(incumbent, dual_bound)``.

    Once its dual bound exceeds ``outside`` (the bound O on solutions using a column left out,
    plus twice the gap) the MIP cannot certify. It is stopped then if its dual bound also
    exceeds ``near`` = L + ``JUMP`` t (every solution over its columns is too far from L for
    the next threshold to be U - L: the next step grows fourfold whatever it finds), or once
    its incumbent is within ``near`` (the next step jumps to U - L with it). A MIP whose columns
    hold no path cheaper than the stay path would otherwise search on for nothing; stopped
    before a good incumbent, it would leave the next step a dear one to start from, which costs
    more time than the stop saves (measurements: bench/README.md, solver constants).
    """
    limit = outside + 2.0 * rel_gap * abs(outside)

    def stop_when(incumbent: float, dual_bound: float) -> bool:
        return dual_bound > limit and (dual_bound > near or incumbent <= near)

    return stop_when


def next_threshold(threshold: float, incumbent_gap: float) -> float:
    """The next MIP's reduced-cost threshold after one that did not certify.

    ``incumbent_gap`` is U - L(y); any column of larger reduced cost is fixed by the incumbent,
    so the threshold never needs to exceed it, and a MIP at ``U - L`` certifies. When that is
    within ``JUMP`` times the current threshold it is taken at once (growing ``GROWTH``-fold
    first and then to U - L would cost one more MIP); otherwise the threshold grows
    ``GROWTH``-fold. It exceeds ``threshold`` (see :func:`certify_by_steps`).
    """
    if threshold <= 0 or incumbent_gap <= JUMP * threshold:
        return max(threshold, incumbent_gap)
    return max(threshold, min(GROWTH * threshold, incumbent_gap))


def _count_distinct(column_sets: list[np.ndarray]) -> int:
    return int(np.unique(np.concatenate(column_sets)).size)


def objective_of(lazy: LazyModel, x: np.ndarray) -> float:
    """Objective of a full 0/1 vector x (n_vars,)."""
    used = used_columns(x)
    return float(lazy.costs(used) @ x[used])


def solve_column_generation(
    lazy: LazyModel, graph: ProductGraph, curve: SpiderCurve, options: SolverOptions
) -> SolveResult:
    """Column generation, reduced-cost fixing and a final MIP, certified for the full model."""
    if not isinstance(lazy, LazyModel):
        raise TypeError("the colgen strategy needs a LazyModel (the full model is never built)")
    start = time.perf_counter()
    seed = np.union1d(path_band_seed(lazy), stay_seed(lazy))
    try:
        lp = generate_columns(lazy, seed, options)
    except LpNotSolved as stopped:
        kind = "no_solution" if stopped.result.status in ("no_solution", "feasible") else "error"
        return _no_result(kind, f"restricted LP not solved: {stopped.result.message}", lazy, start)
    logger.info(
        "colgen LP: %d of %d columns in %d rounds, bound %.8g (%.1f s)",
        lp.columns.size, lazy.n_vars, lp.rounds, lp.bound, time.perf_counter() - start,
    )  # fmt: skip
    layers = np.flatnonzero(curve.is_intersection_layer)
    pool = cut_pool(curve.first_layer, layers, options)
    if lp.cuts.shape[0]:  # valid for every closed path: the MIPs start from the LP's bound
        pool.add(lp.cuts, np.zeros(lp.cuts.shape[0]), np.full(lp.cuts.shape[0], np.inf))
    built = [lp.columns]
    result = certify_by_steps(lazy, lp, options, start, pool, layers, built)
    return replace(
        result,
        wall_time=time.perf_counter() - start,
        n_vars=lazy.n_vars,
        columns_built=_count_distinct(built),
    )
