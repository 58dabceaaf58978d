"""The solve stage in a child process: a native crash of HiGHS ends the child, not the run.

HiGHS runs in C++ inside the Python process; a memory error there (issue 28: ``free():
invalid pointer`` in a sub-MIP's presolve, ``docs/solver_failures.md``) aborts the whole
process, before ``result.json`` leaves the status ``started``. :func:`solve_isolated` forks
a *solver process* that runs the strategy and sends back its :class:`SolveResult`; on the
way it reports the best incumbent objective and full-model bound known
(:func:`spidermatch.solve.progress.report_known`). If it dies, the parent returns a result
with status ``"error"`` and those figures, which the CLI writes as ``solver_failure``
(exit code 5).

Cost: ``fork`` copies nothing up front (pages are shared until written); the result
(a full-model vector) comes back once through a pipe, a small cost beside the solve
(measurements: bench/README.md, solver constants).
Per-solve isolation (each HiGHS run in a process) would ship every restricted model
(see ``bench/repro/solver_process_cost.py``) and lose the LP's warm start between the
rounds of column generation; one process for the whole solve stage keeps both.

Signals: SIGINT/SIGTERM reach the parent (and, from a terminal, ``timeout`` or SLURM,
usually the child too). The parent forwards them; the child stops HiGHS and sends what it
knew, and the parent raises :class:`~spidermatch.shutdown.RunInterrupted` with it. A child
that has not answered ``STOP_GRACE_S`` after that is killed.

Retry: the HiGHS aborts seen were inside a primal heuristic, or an allocation that failed on
one of HiGHS's worker threads under a memory limit (docs/solver_failures.md). A child that dies
is followed by one more in a fresh process with the heuristics off (:data:`RETRY_OPTIONS`) and
HiGHS on one thread (:data:`RETRY_THREADS`), over what is left of the time limit, after the
dead child's last solution with detached cycles is repaired; the cheapest of the retry's
solution and the closed paths known (reported or repaired) is the result.

Time limit: HiGHS does not check its time limit or interrupt flag in some phases (a MIP's
root analytic-centre computation, presolve). A child still solving ``OVERRUN_KILL_S``
past the time limit is killed, and the last closed path it reported (with its solution,
:func:`~spidermatch.solve.progress.report_known`) is the result, with the last bound.

The same phases can keep the child from stopping a MIP in time to repair a solution with
detached cycles that is much cheaper than every closed path it has (the stay path, at 4000
faces). The child reports such solutions too
(:func:`~spidermatch.solve.progress.report_detached`); if the last one reported is newer than
the last closed path when only the reserve (:func:`parent_reserve`) is left, and the child
has not begun a repair itself since, the child is killed and a fresh solver process repairs
that solution in the reserve
(:func:`~spidermatch.solve.reserve.repair_reported`; column generation's lazy model only).
"""

from __future__ import annotations

import functools
import logging
import math
import multiprocessing
import os
import signal
import threading
import time
from dataclasses import replace

import numpy as np

from spidermatch import shutdown
from spidermatch.model.lazy_model import LazyModel
from spidermatch.model.solution import used_columns
from spidermatch.solve import interrupt
from spidermatch.solve.progress import set_known_sink
from spidermatch.solve.repair import stop_reserve
from spidermatch.solve.reserve import repair_reported
from spidermatch.solve.types import SolveResult, SolverOptions, relative_gap

PR_SET_PDEATHSIG = 1  # prctl(2): the signal a process gets when its parent dies

logger = logging.getLogger(__name__)

POLL_S = 0.05  # how often the parent looks at the pipe, the child and the signals
STOP_GRACE_S = 3.0  # after a forwarded signal, how long the child may take to answer
OVERRUN_KILL_S = 4.5  # how far past its time limit the solver process may run before it is killed
RETRY_OPTIONS = {"mip_heuristic_effort": 0.0, "mip_heuristic_run_feasibility_jump": False}  # after a death
RETRY_THREADS = 1  # an allocation failing on a HiGHS worker thread aborts; on its main thread it is a status
REPAIR_AFTER_DEATH_SHARE = 0.5  # of the time left, the most a dead process's detached solution gets
CANCELLED = "stopped: no longer wanted (another curve's solve beside it was certified)"
RETRY_MIN_S = 10.0  # the least time left for which a solve is retried after its process died
# (the budget is kept within 5 s: HiGHS is interrupted at +OVERRUN_GRACE_S where it checks, the
# process killed at +4.5 s where it does not, and the kill takes well under a second)


def parent_reserve(time_limit: float) -> float:
    """Seconds before ``time_limit`` at which a child stuck in HiGHS gives way to a repair.

    Half the time a MIP stops before the limit to repair in the child
    (:func:`~spidermatch.solve.repair.stop_reserve`, at most ``REPAIR_TIME_S``), so a child that
    does stop in time has half its reserve before the parent steps in.
    """
    return 0.5 * stop_reserve(time_limit)


class KnownFigures:
    """The cheapest incumbent objective and the largest full-model bound reported so far.

    Attributes
    ----------
    path : np.ndarray, shape (k,), or None
        The full-model columns of the cheapest incumbent reported *with* its solution.
    path_objective : float
        That incumbent's objective (``inf`` while there is none).

    """

    def __init__(self) -> None:
        self.incumbent = math.inf
        self.bound = -math.inf
        self.path: np.ndarray | None = None
        self.path_objective = math.inf
        self.detached_objective = math.inf  # cheapest solution with detached cycles reported

    def update(self, incumbent: float | None, bound: float | None, path: np.ndarray | None = None) -> bool:
        """Take in a report; True if it improved either figure or the path."""
        better = False
        if incumbent is not None and incumbent < self.incumbent:
            self.incumbent, better = float(incumbent), True
        if bound is not None and bound > self.bound:
            self.bound, better = float(bound), True
        if path is not None and incumbent is not None and incumbent < self.path_objective:
            self.path, self.path_objective, better = np.asarray(path, dtype=np.int64), float(incumbent), True
        return better

    def as_dict(self) -> dict:
        """JSON-ready figures for ``result.json``, named as in ``solve.types.interrupted_figures``."""
        gap = relative_gap(self.incumbent, self.bound)
        return {
            "incumbent_objective": self.incumbent if math.isfinite(self.incumbent) else None,
            "bound": self.bound if math.isfinite(self.bound) else None,
            "gap": gap if math.isfinite(gap) else None,
        }


def can_isolate() -> bool:
    """Whether this platform can fork the solver process (not on Windows)."""
    return hasattr(os, "fork")


class ForkedChild:
    """``target(*args)`` in a forked process, with the parts of ``multiprocessing.Process`` used here.

    ``multiprocessing`` refuses children to a daemonic process (e.g. a worker of a
    ``multiprocessing.Pool`` a user runs matches in), because a daemon killed abruptly would
    leave them running; the solver process dies with its parent instead
    (:func:`_die_with_parent`), so it is forked directly and works there too.

    Attributes
    ----------
    pid : int
    exitcode : int or None
        None while running; the exit code, or minus the signal number that ended it.

    """

    def __init__(self, target, args: tuple) -> None:
        self.exitcode: int | None = None
        self.pid = os.fork()
        if self.pid == 0:  # the child: never returns
            code = 1
            try:
                target(*args)
                code = 0
            finally:
                os._exit(code)

    def is_alive(self) -> bool:
        """Whether the child still runs (reaps it, and sets ``exitcode``, once it has ended)."""
        if self.exitcode is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid != 0:
                self.exitcode = os.waitstatus_to_exitcode(status)
        return self.exitcode is None

    def kill(self) -> None:
        """SIGKILL the child if it still runs."""
        if self.is_alive():
            os.kill(self.pid, signal.SIGKILL)

    def join(self) -> None:
        """Wait for the child to end and set ``exitcode``."""
        if self.exitcode is None:
            _, status = os.waitpid(self.pid, 0)
            self.exitcode = os.waitstatus_to_exitcode(status)


class StartedProcess:
    """A solver process forked by :func:`start_solver_process`, not yet watched.

    Attributes
    ----------
    child : ForkedChild
    receiver : multiprocessing.connection.Connection
        The parent's end of the child's pipe.
    start : float
        ``time.perf_counter()`` when it was forked; its time limit counts from here.

    """

    def __init__(self, child: ForkedChild, receiver, start: float) -> None:
        self.child, self.receiver, self.start = child, receiver, start

    def discard(self) -> None:
        """Kill the child, reap it and close the pipe (a process that will not be watched)."""
        self.receiver.close()
        self.child.kill()
        self.child.join()


def start_solver_process(solve, model, graph, curve, options: SolverOptions) -> StartedProcess:
    """Fork a solver process running ``solve(model, graph, curve, options)`` (then :func:`solve_isolated`).

    Forking while another thread of this process runs can leave a lock (a stream's, a
    logger's) held for ever in the child, so a caller that watches several solver processes
    from threads forks them all here, on its own thread, first (``curve_tour="auto"``).
    """
    receiver, sender = multiprocessing.Pipe(duplex=False)
    start = time.perf_counter()
    child = ForkedChild(_child_main, (receiver, sender, solve, model, graph, curve, options))
    sender.close()
    logger.info("solver process %d started", child.pid)
    return StartedProcess(child, receiver, start)


def solve_isolated(
    solve,
    model,
    graph,
    curve,
    options: SolverOptions,
    reserve_repair: bool = True,
    cancel: threading.Event | None = None,
    started: StartedProcess | None = None,
) -> SolveResult:
    """``solve(model, graph, curve, options)`` in a forked solver process.

    Where processes cannot be forked (:func:`can_isolate`), ``solve`` runs here,
    unisolated, with a log message saying so.

    Parameters
    ----------
    solve : callable
        E.g. ``functools.partial(solve_with_strategy, name)``; runs in the child.
    model, graph, curve, options
        Its arguments (inherited by the child through ``fork``, not pickled).
    reserve_repair : bool
        Repair the child's last solution with detached cycles in a reserve at the end of the
        limit when the child is still inside HiGHS then (module docstring; ``model`` must be a
        :class:`~spidermatch.model.lazy_model.LazyModel`, else this is off).
    cancel : threading.Event, optional
        Set by another thread when this solve is no longer wanted (a solve of another curve
        beside it was certified: ``curve_tour="auto"``); the child is then killed and the
        result is the best closed path it reported, with :data:`CANCELLED` in its message. No
        repair or retry starts once it is set, and those under way are stopped the same way.
    started : StartedProcess, optional
        The solver process of this solve, already forked by :func:`start_solver_process`
        (the same arguments); by default it is forked here.

    Returns
    -------
    SolveResult
        The child's result; if the child died, status ``"error"`` with the best incumbent
        objective and bound it had reported (no solution vector).

    Raises
    ------
    RunInterrupted
        A signal stopped the solve; ``known`` holds the child's figures.

    """
    if not can_isolate():
        logger.info("solving in this process: this platform cannot fork the solver process")
        return solve(model, graph, curve, options)
    if is_cancelled(cancel):
        if started is not None:
            started.discard()
        logger.info("not solving: %s", CANCELLED)
        return _overran(ChildReports(), model, 0.0, options, CANCELLED)
    started = started or start_solver_process(solve, model, graph, curve, options)
    child, receiver, start = started.child, started.receiver, started.start
    repair_at = math.inf
    if reserve_repair and isinstance(model, LazyModel) and math.isfinite(options.time_limit):
        repair_at = start + options.time_limit - parent_reserve(options.time_limit)
    try:
        result, reports = _watch(child, receiver, model, start, options, repair_at, cancel)
        if result is None:  # stopped at repair_at for the repair
            result = _repaired_in_reserve(reports, model, graph, curve, start, options, cancel)
    finally:
        receiver.close()
        if child.is_alive():
            child.kill()
        child.join()
    if reports.died and not is_cancelled(cancel):
        return _retried_after_death(solve, model, graph, curve, options, start, result, reports, cancel)
    return result


def is_cancelled(cancel: threading.Event | None) -> bool:
    """Whether a solve's ``cancel`` event (None: none) is set."""
    return cancel is not None and cancel.is_set()


def _retried_after_death(
    solve, model, graph, curve, options, start: float, failed: SolveResult, reports, cancel=None
):
    """After the solver process died: the solve again in a fresh one, HiGHS on one thread, heuristics off.

    The HiGHS aborts seen (docs/solver_failures.md) were inside a primal heuristic, which only
    looks for incumbents (:data:`RETRY_OPTIONS` turns them all off), or an allocation that failed
    on one of HiGHS's worker threads under a memory limit, where nothing catches it (on its main
    thread HiGHS catches it and stops with its incumbent: :data:`RETRY_THREADS`). A solution with
    detached cycles the dead process reported last is mended first (:func:`_repaired_after_death`).
    The retry gets what is left of the time limit (none, if less than :data:`RETRY_MIN_S`). The
    result is the cheaper of its solution and the last closed path the dead process reported (or
    mended), with the larger of the two certified bounds (both hold for the full model). A retry
    that dies too, or no time to retry, leaves the closed path known, if there is one, else
    ``failed`` (status ``"error"``; :func:`_kept_after_death`).
    """
    left = start + options.time_limit - time.perf_counter()
    if _is_retry(options):  # the retry's own death: the first death's caller decides
        return failed
    if left < RETRY_MIN_S:
        return _kept_after_death(failed, reports, model, options, start, "no time left for a retry")
    logger.warning(
        "retrying the solve in a fresh solver process, HiGHS on one thread with its heuristics off (%s left)",
        f"{left:.0f} s" if math.isfinite(left) else "no time limit",
    )
    retry_options = replace(options, threads=RETRY_THREADS, extra={**options.extra, **RETRY_OPTIONS})
    _repaired_after_death(reports, model, graph, curve, retry_options, left, cancel)
    left = start + options.time_limit - time.perf_counter()
    if left < RETRY_MIN_S or is_cancelled(cancel):  # the repair took the time, or no retry is wanted
        words = CANCELLED if is_cancelled(cancel) else "no time left for a retry"
        return _kept_after_death(failed, reports, model, options, start, words)
    retried = solve_isolated(
        solve, model, graph, curve, replace(retry_options, time_limit=left), cancel=cancel
    )
    if retried.status == "error":
        return _kept_after_death(
            failed, reports, model, options, start, f"the retry died too ({retried.message})"
        )
    return _merged_with_dead(retried, reports, model, options, time.perf_counter() - start)


def _kept_after_death(failed: SolveResult, reports, model, options: SolverOptions, start: float, words: str):
    """``failed``, or, once a closed path is known (reported or mended), that path with the last bound.

    A process that died reported its figures, not always a path; a path known after the death
    (the repair of its last solution) is a matching like any other: "feasible" (or "optimal",
    within the gap) rather than an error.
    """
    if reports.path is None:
        return replace(failed, message=f"{failed.message}; {words}")
    return _overran(reports, model, time.perf_counter() - start, options, f"{failed.message}; {words}")


def _repaired_after_death(
    reports, model, graph, curve, options: SolverOptions, left: float, cancel=None
) -> None:
    """The dead process's last solution with detached cycles, mended into ``reports.path`` if cheaper.

    A restricted MIP's first solutions often have detached cycles; column generation mends
    them after the MIP, which a process that died inside it never reached. The mend
    (:func:`~spidermatch.solve.reserve.repair_reported`, as for a child stopped for its
    reserve) gets at most :data:`REPAIR_AFTER_DEATH_SHARE` of the time ``left``, in a fresh
    process with ``options`` (the retry's); the retry gets the rest.
    """
    if reports.detached is None or not reports.detached_is_newer or not isinstance(model, LazyModel):
        return
    budget = replace(options, time_limit=REPAIR_AFTER_DEATH_SHARE * left)
    logger.warning(
        "repairing the dead solver process's last solution (cost %.6g, detached cycles) in at most %.0f s",
        reports.detached[0],
        budget.time_limit,
    )
    _mend_detached(reports, model, graph, curve, budget, cancel)


def _is_retry(options: SolverOptions) -> bool:
    return all(options.extra.get(name) == value for name, value in RETRY_OPTIONS.items())


def _merged_with_dead(
    retried: SolveResult, reports, model, options: SolverOptions, wall: float
) -> SolveResult:
    """``retried``, or the dead process's cheaper closed path, with the larger bound of the two."""
    reported = reports.known.get("bound")
    bound = max(retried.bound, -math.inf if reported is None else reported)  # a bound of 0 counts
    x, objective = retried.x, retried.objective
    if reports.path is not None and (x is None or reports.path[0] < objective):
        objective, x = reports.path[0], np.zeros(model.n_vars)
        x[reports.path[1]] = 1.0
    words = f"{retried.message} (retried after the solver process died)"
    if x is None:
        return replace(retried, bound=bound, wall_time=wall, message=words)
    gap = relative_gap(objective, bound)
    status = "optimal" if gap <= options.mip_rel_gap else "feasible"
    return replace(
        retried, status=status, x=x, objective=objective, bound=bound, gap=gap, wall_time=wall, message=words
    )


def _child_main(receiver, sender, solve, model, graph, curve, options) -> None:
    """The solver process: run ``solve`` and send its outcome (:class:`ForkedChild` then exits)."""
    receiver.close()  # the parent's end
    _die_with_parent()
    shutdown.fresh_in_child()
    interrupt.fresh_in_child()
    lock, known = threading.Lock(), KnownFigures()

    def send(message) -> None:
        with lock:
            sender.send(message)

    def sink(incumbent, bound, path) -> None:  # also called from HiGHS's callbacks, on the solver thread
        with lock:
            had = known.path
            if known.update(incumbent, bound, path):
                new_path = known.path if known.path is not had else None  # a path is sent once
                sender.send(("known", known.as_dict(), new_path, known.path_objective))

    def detached_sink(objective, edges) -> None:  # called from HiGHS's callbacks, on the solver thread
        with lock:
            if objective is None:  # the child repairs itself
                sender.send(("detached", None, None))
            elif objective < min(known.detached_objective, known.path_objective):
                known.detached_objective = float(objective)
                sender.send(("detached", float(objective), np.asarray(edges, dtype=np.int64)))

    set_known_sink(sink, detached_sink)
    try:
        result = solve(model, graph, curve, options)
        send(("finishing",))  # sending a large solution may outlast the time limit: no kill now
        send(("result", result))
    except shutdown.RunInterrupted as stop:
        send(("interrupted", stop.signum, stop.known))
    except Exception as error:  # noqa: BLE001 - re-raised in the parent
        send(("raised", error))
    finally:
        set_known_sink(None)
        sender.close()


def _die_with_parent() -> None:
    """Ask the kernel to kill this process when its parent dies (Linux; elsewhere a no-op).

    A parent killed with SIGKILL cannot stop its solver process; without this the orphan
    would go on solving, using a core, for a result nobody reads.
    """
    parent = os.getppid()
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)


class ChildReports:
    """What the parent knows of a running child: figures, last closed path, last detached solution.

    Attributes
    ----------
    known : dict
        :meth:`KnownFigures.as_dict` of the last ``"known"`` report.
    path : tuple of (float, np.ndarray) or None
        The cheapest closed path reported: its objective and full-model columns (k,).
    detached : tuple of (float, np.ndarray) or None
        The cheapest solution with detached cycles reported: its objective and edge ids (m,).
    detached_is_newer : bool
        Whether that solution came after the last closed path and after the child last said
        it was repairing one itself.

    """

    def __init__(self) -> None:
        self.known: dict = {}
        self.path: tuple[float, np.ndarray] | None = None
        self.detached: tuple[float, np.ndarray] | None = None
        self.detached_is_newer = False
        self.died = False  # the child ended without a result (a signal or an exit of its own)

    def take(self, message: tuple) -> bool:
        """Take in a ``"known"`` or ``"detached"`` message; False for any other kind."""
        if message[0] == "known":  # ("known", figures, new path or None, its objective)
            _, self.known, new_path, objective = message
            if new_path is not None:
                self.path, self.detached_is_newer = (objective, new_path), False
            return True
        if message[0] == "detached":  # ("detached", objective, edges), or (None, None): repairing itself
            if message[1] is None:
                self.detached_is_newer = False
            else:
                self.detached, self.detached_is_newer = (message[1], message[2]), True
            return True
        return False

    def drain(self, receiver) -> None:
        """Take in the reports still in the pipe of a child that has ended or was killed."""
        try:
            while receiver.poll(0):
                self.take(receiver.recv())
        except (EOFError, OSError):
            pass

    def repair_would_help(self) -> bool:
        """Whether the last solution with detached cycles is newer and cheaper than every closed path."""
        if self.detached is None or not self.detached_is_newer:
            return False
        return self.path is None or self.detached[0] < self.path[0]


def _watch(
    child,
    receiver,
    model,
    start: float,
    options: SolverOptions,
    repair_at: float = math.inf,
    cancel: threading.Event | None = None,
):
    """Wait for the child's outcome, forwarding signals; (what it sent or a failure result, reports).

    A child still solving ``OVERRUN_KILL_S`` past ``options.time_limit`` (seconds from
    ``start``) is killed, and its last reported incumbent and bound are returned
    (:func:`_overran`). One still solving at ``repair_at`` (a ``time.perf_counter()`` value)
    while its last solution with detached cycles is newer and cheaper than its closed paths is
    killed too, and the result is None: the caller repairs that solution.
    """
    reports, finishing, forwarded_at = ChildReports(), False, None
    kill_at = start + options.time_limit + OVERRUN_KILL_S
    with shutdown.native_call():  # a signal is only recorded meanwhile: the child must hear of it first
        while True:
            if receiver.poll(POLL_S):
                try:
                    message = receiver.recv()
                except EOFError:  # the child is gone without a result
                    break
                kind = message[0]
                if reports.take(message):
                    continue
                if kind == "finishing":
                    finishing = True
                    continue
                if kind == "result":
                    return message[1], reports
                if kind == "raised":
                    raise message[1]
                _, signum, figures = message
                _raise_interrupted(signum, {**reports.known, **figures})
            elif not child.is_alive() and not receiver.poll():
                break
            if shutdown.stop_requested() and forwarded_at is None:
                forwarded_at = time.perf_counter()
                os.kill(child.pid, shutdown.received_signal())
            if forwarded_at is not None and time.perf_counter() - forwarded_at > STOP_GRACE_S:
                logger.warning("the solver process did not stop within %.0f s: killed", STOP_GRACE_S)
                child.kill()
                _raise_interrupted(shutdown.received_signal(), reports.known)
            if finishing or forwarded_at is not None:
                continue
            now, cancelled = time.perf_counter(), is_cancelled(cancel)
            if cancelled or now > kill_at or (now > repair_at and reports.repair_would_help()):
                child.kill()
                child.join()
                reports.drain(receiver)
                if cancelled:
                    logger.info("solver process %d stopped: %s", child.pid, CANCELLED)
                    return _overran(reports, model, now - start, options, CANCELLED), reports
                if now > kill_at:
                    return _overran(reports, model, now - start, options), reports
                return None, reports
    child.join()
    reports.died = True
    return _failure(child.exitcode, reports.known, model, time.perf_counter() - start), reports


def _repaired_in_reserve(
    reports: ChildReports, model, graph, curve, start: float, options, cancel=None
) -> SolveResult:
    """The result after the child was stopped for a repair: the repaired path if it is cheaper.

    The repair runs in a fresh solver process over what is left of ``options.time_limit``;
    the result is then as for a child stopped at its limit (:func:`_overran`), with the
    repaired path among the closed paths.
    """
    detached_objective = reports.detached[0]
    best = reports.path[0] if reports.path is not None else math.inf
    left = start + options.time_limit - time.perf_counter()
    logger.warning(
        "the solver process was still inside HiGHS %.0f s before the time limit, its best closed "
        "path costing %s and a solution with detached cycles %.6g: stopped, to repair that solution "
        "in the time left",
        left, f"{best:.6g}" if math.isfinite(best) else "nothing (none known)", detached_objective,
    )  # fmt: skip
    words = (
        f"stopped inside HiGHS {left:.0f} s before the time limit to repair a solution with detached cycles"
    )
    mended = _mend_detached(reports, model, graph, curve, replace(options, time_limit=max(left, 0.0)), cancel)
    words += " (repaired)" if mended else " (no cheaper closed path found)"
    return _overran(reports, model, time.perf_counter() - start, options, words)


def _mend_detached(reports: ChildReports, model, graph, curve, options: SolverOptions, cancel=None) -> bool:
    """Whether ``reports.detached``, repaired in a fresh process, gave a cheaper closed path.

    The repair runs within ``options``'s time limit; a closed path cheaper than ``reports.path``
    becomes ``reports.path``.
    """
    best = reports.path[0] if reports.path is not None else math.inf
    repair = functools.partial(repair_reported, reports.detached[1])
    repaired = solve_isolated(repair, model, graph, curve, options, reserve_repair=False, cancel=cancel)
    if repaired.x is None or repaired.objective >= best:
        logger.warning("the repair found no cheaper closed path (%s)", repaired.message)
        return False
    logger.info("repaired: a closed path of cost %.8g", repaired.objective)
    reports.path = (repaired.objective, used_columns(repaired.x))
    return True


def _overran(reports: ChildReports, model, wall: float, options: SolverOptions, words: str | None = None):
    """The result of a solver process killed for running past its time limit (or for a repair).

    HiGHS checks neither its time limit nor its interrupt flag in some phases (a MIP's
    root analytic-centre computation on a large model can run many minutes past the limit;
    measurements: bench/README.md, solver constants). The cheapest closed path reported with
    its solution is the result, with the last certified bound: "optimal" if they are within
    ``options.mip_rel_gap`` (both hold for the full model), else "feasible"; "no_solution"
    without an incumbent.
    """
    bound = reports.known.get("bound")
    bound = -math.inf if bound is None else bound
    if words is None:
        overrun, time_limit = wall - options.time_limit, options.time_limit
        logger.error(
            "the solver process was %.0f s past the %.0f s time limit inside HiGHS (a phase without "
            "interrupt checks): stopped",
            overrun,
            time_limit,
        )
        words = f"stopped {overrun:.0f} s past the time limit inside HiGHS"
    if reports.path is None:
        message = f"{words}, before any solution was known"
        return SolveResult(
            "no_solution", None, math.inf, bound, math.nan, wall, model.n_vars, model.n_rows,
            int(getattr(model, "nnz", 0) or 0), message,
        )  # fmt: skip
    objective, columns = reports.path
    x = np.zeros(model.n_vars)
    x[columns] = 1.0
    gap = relative_gap(objective, bound)
    status = "optimal" if gap <= options.mip_rel_gap else "feasible"
    message = f"{words}; the best closed path known and the bound reported before"
    return SolveResult(
        status, x, objective, bound, gap, wall, model.n_vars, model.n_rows,
        int(getattr(model, "nnz", 0) or 0), message,
    )  # fmt: skip


def _raise_interrupted(signum: int, figures: dict) -> None:
    """Raise :class:`RunInterrupted` for ``signum`` with the child's figures."""
    if shutdown.stop_requested():
        shutdown.raise_if_stopped(figures)
    raise shutdown.RunInterrupted(signum, figures)


def describe_exit(exitcode: int | None) -> str:
    """How a process ended, in words: ``"SIGABRT (exit 134)"`` or ``"exit code 1"``."""
    if exitcode is None:
        return "unknown exit"
    if exitcode < 0:
        return f"{signal.Signals(-exitcode).name} (exit {128 - exitcode})"
    return f"exit code {exitcode}"


def _failure(exitcode: int | None, known: dict, model, wall: float) -> SolveResult:
    """The result of a solver process that died: status "error" with the figures it had reported."""
    incumbent = known.get("incumbent_objective")
    bound = known.get("bound")
    incumbent = math.inf if incumbent is None else incumbent
    bound = -math.inf if bound is None else bound
    message = (
        f"the solver process died: {describe_exit(exitcode)}; incumbent and bound as last reported "
        "(see docs/solver_failures.md)"
    )
    logger.error("%s", message)
    return SolveResult(
        "error",
        None,
        incumbent,
        bound,
        relative_gap(incumbent, bound),
        wall,
        model.n_vars,
        model.n_rows,
        int(getattr(model, "nnz", 0) or 0),
        message,
    )
