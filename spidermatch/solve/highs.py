"""The one module that talks to HiGHS (highspy).

The model is passed column-wise in a single ``passModel`` call. Every solve
reports status, objective, best bound, relative gap, wall time and problem size.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import replace

import highspy
import numpy as np
import scipy.sparse as sp

from spidermatch import shutdown
from spidermatch.model.ilp import IlpModel
from spidermatch.model.solution import used_columns
from spidermatch.solve.interrupt import OVERRUN_GRACE_S, run_interruptibly
from spidermatch.solve.progress import ProgressLog, report_detached, report_known
from spidermatch.solve.types import (
    OUT_OF_MEMORY,
    SolveResult,
    SolverOptions,
    certified_mip_bound,
    finite_or_none,
    interrupted_figures,
    relative_gap,
)

logger = logging.getLogger(__name__)


# HiGHS 1.16 aborts the process (free(): invalid pointer) when it frees the presolve of a
# heuristic's sub-MIP: seen from the root reduced-cost heuristic and from RENS, and RINS solves
# sub-MIPs the same way, so all three are off (docs/solver_failures.md,
# bench/repro/highs_submip_presolve_abort.py). They only look for incumbents.
HIGHS_WORKAROUNDS = {
    "mip_heuristic_run_root_reduced_cost": False,
    "mip_heuristic_run_rens": False,
    "mip_heuristic_run_rins": False,
}
KEEP_IMPROVING = 16  # improving solutions a session keeps (each a full-model vector, 8 bytes per column)


_PROCESS_THREADS: int | None = None  # HiGHS fixes its thread pool at the first solve of a process


_STATUS = highspy.HighsModelStatus


_STOPPED = {
    _STATUS.kTimeLimit,
    _STATUS.kIterationLimit,
    _STATUS.kSolutionLimit,
    _STATUS.kInterrupt,
    _STATUS.kObjectiveBound,
    _STATUS.kObjectiveTarget,
}


_INTERRUPT_CALLBACKS = (
    highspy.cb.HighsCallbackType.kCallbackSimplexInterrupt,
    highspy.cb.HighsCallbackType.kCallbackIpmInterrupt,
    highspy.cb.HighsCallbackType.kCallbackMipInterrupt,
)


class SolverOptionError(ValueError):
    """HiGHS rejected an option value (it would otherwise run silently with its default)."""


def set_option(highs, name: str, value) -> None:
    """``highs.setOptionValue(name, value)``, raising :class:`SolverOptionError` if HiGHS rejects it."""
    if highs.setOptionValue(name, value) == highspy.HighsStatus.kError:
        raise SolverOptionError(f"HiGHS rejected the option {name}={value!r}")


def _configure(highs, options: SolverOptions) -> None:
    global _PROCESS_THREADS
    set_option(highs, "output_flag", bool(options.log))
    if math.isfinite(options.time_limit):
        set_option(highs, "time_limit", float(options.time_limit))
    set_option(highs, "mip_rel_gap", float(options.mip_rel_gap))
    set_option(highs, "mip_abs_gap", 0.0)  # the gap is relative only (HiGHS's default adds 1e-6 absolute)
    set_option(highs, "presolve", options.presolve)
    if _PROCESS_THREADS is None:
        _PROCESS_THREADS = int(options.threads)
    elif options.threads != _PROCESS_THREADS:
        logger.warning(
            "HiGHS threads are fixed per process: keeping %d, ignoring %d", _PROCESS_THREADS, options.threads
        )
    if _PROCESS_THREADS:
        set_option(highs, "threads", _PROCESS_THREADS)
    for name, value in HIGHS_WORKAROUNDS.items():
        if highs.setOptionValue(name, value) == highspy.HighsStatus.kError:  # not in this HiGHS version
            logger.debug("HiGHS has no option %s: workaround not needed", name)
    for name, value in options.extra.items():  # may undo a workaround
        set_option(highs, name, value)


def _pass_model(highs, model: IlpModel, integer: bool) -> None:
    matrix = model.matrix
    n, m = model.n_vars, model.n_rows
    integrality = np.full(n, 1 if integer else 0, dtype=np.int32)
    status = highs.passModel(
        n,
        m,
        int(matrix.nnz),
        int(highspy.MatrixFormat.kColwise),
        int(highspy.ObjSense.kMinimize),
        0.0,
        model.costs,
        np.zeros(n),
        np.ones(n),
        np.asarray(model.row_lower, dtype=np.float64),
        np.asarray(model.row_upper, dtype=np.float64),
        matrix.indptr.astype(np.int32),
        matrix.indices.astype(np.int32),
        matrix.data.astype(np.float64),
        integrality,
    )
    if status == highspy.HighsStatus.kError:
        raise RuntimeError(f"HiGHS rejected the model ({n} columns, {m} rows)")


def highs_time_limit(highs, seconds: float, relax: bool) -> float:
    """The ``time_limit`` option that gives the next ``highs.run()`` ``seconds`` more.

    HiGHS (1.16, and the HiGHS sources since at least 1.7) compares an LP's ``time_limit`` with
    its run clock, ``getRunTime()``, which keeps counting over every run of a ``Highs`` object:
    an LP re-solved after earlier runs that together took longer than its own limit stops at
    once. A MIP is timed by a clock of its own that starts with each run (HiGHS's MIP solver
    gives its own LP solver ``getRunTime() + left`` the same way). See
    ``bench/repro/highs_run_clock.py``.

    Parameters
    ----------
    highs : highspy.Highs
    seconds : float
        Time the next run may take.
    relax : bool
        True for an LP (the model has no integer columns).

    """
    return seconds + highs.getRunTime() if relax else seconds


class HighsSession:
    """A model loaded into HiGHS that can be solved, extended with rows and solved again.

    Parameters
    ----------
    model : IlpModel
    options : SolverOptions
    relax : bool
        Solve the LP relaxation (x in [0, 1]) instead of the ILP.
    label : str, optional
        Names the model in the progress lines logged every few seconds during a run.

    Attributes
    ----------
    improving : list of (float, np.ndarray)
        The last ``KEEP_IMPROVING`` improving solutions HiGHS reported during the MIP runs of
        this session, as (objective, x of shape (n,)), oldest first. Lazy rows added later
        may cut some off.
    full_columns : np.ndarray, shape (n_columns,), or None
        Set by a caller that solves a restricted model: the full-model id of each of its
        columns, so that closed paths found during a run are reported in full-model ids
        (:func:`~spidermatch.solve.progress.report_known`).

    """

    def __init__(
        self,
        model: IlpModel,
        options: SolverOptions | None = None,
        relax: bool = False,
        label: str | None = None,
    ) -> None:
        self.options = options or SolverOptions()
        self.relax = relax
        self.n_vars = model.n_vars
        self.n_rows = model.n_rows
        self.nnz = model.nnz
        self.started = time.perf_counter()
        self.highs = highspy.Highs()
        _configure(self.highs, self.options)
        _pass_model(self.highs, model, integer=not relax)
        self.improving: list[tuple[float, np.ndarray]] = []
        self.offered: tuple[float, np.ndarray] | None = None  # the start solution given by set_solution
        self.full_columns: np.ndarray | None = None  # full-model id of each model column, where known
        self.costs = np.asarray(model.costs, dtype=np.float64)
        self.last_mip = (math.inf, -math.inf)  # (incumbent, dual bound) at HiGHS's last MIP callback
        # HiGHS reports its results in the model's costs but the callbacks' figures in its scaled ones
        self.callback_unscale = 2.0 ** -int(self.options.extra.get("user_objective_scale", 0))
        self.cancel = threading.Event()  # set when the waiting thread gave up: HiGHS stops at its next check
        self.stop_when = None  # (incumbent, dual bound) -> True to stop a MIP early (see solve_with_cuts)
        self.stopped_early = False  # the last run was stopped by stop_when
        self.usable = None  # x (n,) -> bool: may an improving solution be used (e.g. one closed path)?
        self.best_usable = math.inf  # cheapest usable solution known (start or improving)
        self.best_unusable = math.inf  # cheapest improving solution that was not usable
        default_label = "LP relaxation" if relax else f"MIP over {model.n_vars} columns"
        self.progress = ProgressLog(label or default_label)
        self.highs.setCallback(self._on_callback, None)
        for kind in _INTERRUPT_CALLBACKS:
            self.highs.startCallback(kind)
        if not relax:
            self.highs.startCallback(highspy.cb.HighsCallbackType.kCallbackMipImprovingSolution)

    def _on_callback(self, kind, message, data_out, data_in, user_data) -> None:
        """HiGHS callback: record improving solutions, log progress, stop on a signal."""
        kinds = highspy.cb.HighsCallbackType
        if kind == kinds.kCallbackMipImprovingSolution:
            self._record_improving(data_out)
            return
        stop = shutdown.stop_requested() or self.cancel.is_set()
        if kind == kinds.kCallbackMipInterrupt:
            unscale = self.callback_unscale
            self.last_mip = (
                unscale * float(data_out.mip_primal_bound),
                unscale * float(data_out.mip_dual_bound),
            )
            self.progress.mip(data_out)
        elif kind == kinds.kCallbackSimplexInterrupt:
            self.progress.simplex(data_out)
        # Asked at the LP solver's reports inside a MIP too: HiGHS's root node can go minutes
        # between MIP reports (4000 faces), and a stop that leaves time for the repair of a
        # solution with detached cycles (spidermatch.solve.cuts) must come before the limit.
        if not stop and not self.relax and self.stop_when is not None:
            incumbent = self.best_usable if self.usable is not None else self.last_mip[0]
            if self.stop_when(incumbent, self.last_mip[1]):
                stop = self.stopped_early = True
        # always written: HiGHS keeps the flag between runs of a session, so a True left from an
        # earlier run would stop the next run at its first check
        data_in.user_interrupt = bool(stop)

    def _record_improving(self, data_out) -> None:
        """Keep a copy of an improving solution."""
        x = np.array(data_out.mip_solution, dtype=np.float64)
        if x.shape == (self.n_vars,):
            objective = self.callback_unscale * float(data_out.objective_function_value)
            self.improving.append((objective, x))
            del self.improving[:-KEEP_IMPROVING]  # the most recent ones (later runs may report dearer ones)
            if self.usable is not None and objective < min(self.best_usable, self.best_unusable):
                if self.usable(x):
                    self.best_usable = objective
                    report_known(incumbent=objective, path=self._full_model_path(x))  # one closed path
                else:
                    self.best_unusable = objective
                    edges = self._full_model_path(x)
                    if edges is not None:
                        report_detached(objective, edges)  # for a repair if the solver is stopped

    def _full_model_path(self, x: np.ndarray) -> np.ndarray | None:
        """The full-model columns (sorted ids) a 0/1 solution x (n,) of this session sets, if known."""
        if self.full_columns is None:
            return None
        return self.full_columns[used_columns(x[: self.full_columns.size])]

    def set_solution(self, x: np.ndarray) -> None:
        """Offer a feasible 0/1 vector (n,) as a starting incumbent."""
        index = np.arange(self.n_vars, dtype=np.int32)
        x = np.asarray(x, dtype=np.float64)
        self.highs.setSolution(self.n_vars, index, x)
        if not self.relax and x.shape == self.costs.shape:
            self.offered = (float(self.costs @ x), x.copy())
            self.best_usable = min(self.best_usable, self.offered[0])  # starts are closed paths

    def add_rows(self, rows, lower: np.ndarray, upper: np.ndarray) -> None:
        """Append constraints ``lower <= rows @ x <= upper`` (rows: scipy sparse, (k, n))."""
        rows = rows.tocsr()
        self.highs.addRows(
            rows.shape[0],
            np.asarray(lower, dtype=np.float64),
            np.asarray(upper, dtype=np.float64),
            int(rows.nnz),
            rows.indptr.astype(np.int32),
            rows.indices.astype(np.int32),
            rows.data.astype(np.float64),
        )
        self.n_rows += rows.shape[0]
        self.nnz += int(rows.nnz)

    def _figures_so_far(self) -> dict:
        """Incumbent and certified bound of the running MIP, from HiGHS's last callback."""
        if self.relax:
            return {"incumbent_objective": None, "bound": None, "gap": None, "solver_message": "LP running"}
        incumbent, dual = self.last_mip
        bound = certified_mip_bound(dual, incumbent, self.options.mip_rel_gap)
        return {
            "incumbent_objective": finite_or_none(incumbent),
            "bound": finite_or_none(bound),
            "gap": finite_or_none(relative_gap(incumbent, bound)),
            "solver_message": "HiGHS had not stopped yet; figures from its last progress report",
        }

    def add_columns(self, costs: np.ndarray, columns) -> None:
        """Append variables in [0, 1] with ``costs`` (k,) and constraint columns (scipy sparse, (m, k)).

        Only for LP sessions (``relax=True``): the new columns are continuous. HiGHS keeps
        the current basis, so the next run starts from the last solution.
        """
        if not self.relax:
            raise ValueError("columns can be added to LP sessions only")
        columns = sp.csc_matrix(columns)
        k = columns.shape[1]
        self.highs.addCols(
            k,
            np.asarray(costs, dtype=np.float64),
            np.zeros(k),
            np.ones(k),
            int(columns.nnz),
            columns.indptr.astype(np.int32),
            columns.indices.astype(np.int32),
            columns.data.astype(np.float64),
        )
        self.n_vars += k
        self.nnz += int(columns.nnz)

    def add_continuous_columns(self, costs: np.ndarray, upper: np.ndarray) -> None:
        """Append continuous variables in [0, ``upper``] (k,) with ``costs`` (k,), in no row yet.

        Works for MIP sessions too (HiGHS makes added columns continuous); rows that use them
        come with :meth:`add_rows`.
        """
        costs = np.asarray(costs, dtype=np.float64)
        k = costs.size
        self.highs.addCols(
            k,
            costs,
            np.zeros(k),
            np.asarray(upper, dtype=np.float64),
            0,
            np.zeros(k, dtype=np.int32),
            np.zeros(0, dtype=np.int32),
            np.zeros(0),
        )
        self.n_vars += k
        self.costs = np.concatenate([self.costs, costs])

    def row_duals(self) -> np.ndarray:
        """Row duals (m,) of the last LP solve (HiGHS's sign convention: ``r = c - A^T y``)."""
        return np.asarray(self.highs.getSolution().row_dual, dtype=np.float64)

    def run(self) -> SolveResult:
        """Solve (again) and read the result.

        ``options.time_limit`` bounds all runs of the session together (from its creation):
        every run is given what is left, through :func:`highs_time_limit` (HiGHS's clocks
        differ between LPs and MIPs).
        """
        start, deadline = time.perf_counter(), None
        if math.isfinite(self.options.time_limit):
            left = max(self.options.time_limit - (start - self.started), 0.0)
            set_option(self.highs, "time_limit", highs_time_limit(self.highs, left, self.relax))
            deadline = start + left + OVERRUN_GRACE_S
        self.cancel.clear()
        self.stopped_early = False
        run_interruptibly(self.highs, self._figures_so_far, self.cancel, deadline)
        result = _read_result(self, time.perf_counter() - start)
        shutdown.raise_if_stopped(interrupted_figures(result))
        return result


def solve_model(
    model: IlpModel,
    options: SolverOptions | None = None,
    initial_solution: np.ndarray | None = None,
    relax: bool = False,
) -> SolveResult:
    """Solve the ILP (or its LP relaxation) once with HiGHS.

    Parameters
    ----------
    model : IlpModel
    options : SolverOptions
    initial_solution : np.ndarray, shape (n,), optional
        A feasible 0/1 vector handed to HiGHS as a starting incumbent.
    relax : bool
        Solve the LP relaxation (x in [0, 1]) instead.

    """
    start = time.perf_counter()
    session = HighsSession(model, options, relax)
    if initial_solution is not None:
        session.set_solution(initial_solution)
    result = session.run()
    return replace(result, wall_time=time.perf_counter() - start)


def _interrupt_reason(session: HighsSession) -> str:
    """Who stopped an interrupted run, in place of HiGHS's "Interrupted by user" (spidermatch mostly)."""
    if shutdown.stop_requested():
        return "interrupted by a signal (Ctrl-C or SIGTERM)"
    if session.stopped_early:
        return "stopped early by spidermatch (time kept for a repair, or nothing more to gain from this MIP)"
    return "stopped by spidermatch (time limit)"


def _read_result(session: HighsSession, wall: float) -> SolveResult:
    highs, relax = session.highs, session.relax
    status = highs.getModelStatus()
    info = highs.getInfo()
    message = highs.modelStatusToString(status)
    if status == _STATUS.kInterrupt:
        message = _interrupt_reason(session)
    has_solution = info.primal_solution_status == 2  # kSolutionStatusFeasible
    x = np.asarray(highs.getSolution().col_value, dtype=np.float64) if has_solution else None
    if x is not None and not relax:
        x = np.rint(np.clip(x, 0.0, 1.0))
    objective = float(info.objective_function_value) if has_solution else math.inf
    if relax:
        bound = objective if status == _STATUS.kOptimal else -math.inf
    else:
        bound = certified_mip_bound(float(info.mip_dual_bound), objective, session.options.mip_rel_gap)
    if status == _STATUS.kOptimal and has_solution:
        kind = "optimal"
    elif status in (_STATUS.kInfeasible, _STATUS.kUnboundedOrInfeasible):
        kind = "infeasible"
    elif has_solution and status in _STOPPED:
        kind = "feasible"
    elif status in _STOPPED:
        kind = "no_solution"
    elif status == _STATUS.kMemoryLimit:  # a failed allocation caught on HiGHS's main thread
        kind = "feasible" if has_solution else "no_solution"
        bound = -math.inf  # what HiGHS reports after it is not read as a certificate
        message = f"{OUT_OF_MEMORY}: HiGHS could not allocate; its incumbent kept, its bound not"
    else:
        kind = "error"
    return SolveResult(
        kind,
        x,
        objective,
        bound,
        relative_gap(objective, bound),
        wall,
        session.n_vars,
        session.n_rows,
        session.nnz,
        message,
    )


# dual simplex: faster here than IPM (measurements: bench/README.md, solver constants)
LP_EXTRA = {"solver": "simplex", "simplex_strategy": 1}
