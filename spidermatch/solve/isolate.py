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

Time limit: HiGHS does not check its time limit or interrupt flag in some phases (a MIP's
root analytic-centre computation, presolve). A child still solving ``OVERRUN_KILL_S``
past the time limit is killed, and the last closed path it reported (with its solution,
:func:`~spidermatch.solve.progress.report_known`) is the result, with the last bound.
"""

from __future__ import annotations

import logging
import math
import multiprocessing
import os
import signal
import threading
import time

import numpy as np

from spidermatch import shutdown
from spidermatch.solve import interrupt
from spidermatch.solve.progress import set_known_sink
from spidermatch.solve.types import SolveResult, SolverOptions, relative_gap

PR_SET_PDEATHSIG = 1  # prctl(2): the signal a process gets when its parent dies

logger = logging.getLogger(__name__)

POLL_S = 0.05  # how often the parent looks at the pipe, the child and the signals
STOP_GRACE_S = 3.0  # after a forwarded signal, how long the child may take to answer
OVERRUN_KILL_S = 4.5  # how far past its time limit the solver process may run before it is killed
# (the budget is kept within 5 s: HiGHS is interrupted at +OVERRUN_GRACE_S where it checks, the
# process killed at +4.5 s where it does not, and the kill takes well under a second)


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


def solve_isolated(solve, model, graph, curve, options: SolverOptions) -> SolveResult:
    """``solve(model, graph, curve, options)`` in a forked solver process.

    Where processes cannot be forked (:func:`can_isolate`), ``solve`` runs here,
    unisolated, with a log message saying so.

    Parameters
    ----------
    solve : callable
        E.g. ``functools.partial(solve_with_strategy, name)``; runs in the child.
    model, graph, curve, options
        Its arguments (inherited by the child through ``fork``, not pickled).

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
    receiver, sender = multiprocessing.Pipe(duplex=False)
    start = time.perf_counter()
    child = ForkedChild(_child_main, (receiver, sender, solve, model, graph, curve, options))
    sender.close()
    logger.info("solver process %d started", child.pid)
    try:
        return _watch(child, receiver, model, start, options)
    finally:
        receiver.close()
        if child.is_alive():
            child.kill()
        child.join()


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

    set_known_sink(sink)
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


def _watch(child, receiver, model, start: float, options: SolverOptions) -> SolveResult:
    """Wait for the child's outcome, forwarding signals; what it sent, or a failure result.

    A child still solving ``OVERRUN_KILL_S`` past ``options.time_limit`` (seconds from
    ``start``) is killed, and its last reported incumbent and bound are returned
    (:func:`_overran`).
    """
    known, path, finishing, forwarded_at = {}, None, False, None
    kill_at = start + options.time_limit + OVERRUN_KILL_S
    with shutdown.native_call():  # a signal is only recorded meanwhile: the child must hear of it first
        while True:
            if receiver.poll(POLL_S):
                try:
                    message = receiver.recv()
                except EOFError:  # the child is gone without a result
                    break
                kind = message[0]
                if kind == "known":
                    known, path = _with_report(message, path)
                    continue
                if kind == "finishing":
                    finishing = True
                    continue
                if kind == "result":
                    return message[1]
                if kind == "raised":
                    raise message[1]
                _, signum, figures = message
                _raise_interrupted(signum, {**known, **figures})
            elif not child.is_alive() and not receiver.poll():
                break
            if shutdown.stop_requested() and forwarded_at is None:
                forwarded_at = time.perf_counter()
                os.kill(child.pid, shutdown.received_signal())
            if forwarded_at is not None and time.perf_counter() - forwarded_at > STOP_GRACE_S:
                logger.warning("the solver process did not stop within %.0f s: killed", STOP_GRACE_S)
                child.kill()
                _raise_interrupted(shutdown.received_signal(), known)
            if not finishing and forwarded_at is None and time.perf_counter() > kill_at:
                child.kill()
                child.join()
                known, path = _last_reports(receiver, known, path)
                return _overran(known, path, model, time.perf_counter() - start, options)
    child.join()
    return _failure(child.exitcode, known, model, time.perf_counter() - start)


def _last_reports(receiver, known: dict, path):
    """``known`` and ``path`` updated by the reports still in the pipe of a killed child."""
    try:
        while receiver.poll(0):
            message = receiver.recv()
            if message[0] == "known":
                known, path = _with_report(message, path)
    except (EOFError, OSError):
        pass
    return known, path


def _with_report(message: tuple, path):
    """The figures of a ``("known", figures, new path or None, its objective)`` report, and the path then."""
    _, figures, new_path, objective = message
    return figures, path if new_path is None else (objective, new_path)


def _overran(known: dict, path, model, wall: float, options: SolverOptions) -> SolveResult:
    """The result of a solver process killed for running past its time limit.

    HiGHS checks neither its time limit nor its interrupt flag in some phases (a MIP's
    root analytic-centre computation on a large model can run many minutes past the limit;
    measurements: bench/README.md, solver constants). The last incumbent the child reported
    with its solution is the result, with the last certified bound: "optimal" if they are within
    ``options.mip_rel_gap`` (both hold for the full model), else "feasible"; "no_solution"
    without an incumbent.
    """
    bound = known.get("bound")
    bound = -math.inf if bound is None else bound
    overrun, time_limit = wall - options.time_limit, options.time_limit
    logger.error(
        "the solver process was %.0f s past the %.0f s time limit inside HiGHS (a phase without "
        "interrupt checks): stopped",
        overrun,
        time_limit,
    )
    words = f"stopped {overrun:.0f} s past the time limit inside HiGHS"
    if path is None:
        message = f"{words}, before any solution was known"
        return SolveResult(
            "no_solution", None, math.inf, bound, math.nan, wall, model.n_vars, model.n_rows,
            int(getattr(model, "nnz", 0) or 0), message,
        )  # fmt: skip
    objective, columns = path
    x = np.zeros(model.n_vars)
    x[columns] = 1.0
    gap = relative_gap(objective, bound)
    status = "optimal" if gap <= options.mip_rel_gap else "feasible"
    message = f"{words}; the best closed path and bound reported before"
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
