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
(a full-model vector, 30 MB at 1000 faces) comes back once through a pipe, ~0.1 s.
Per-solve isolation (each HiGHS run in a process) would ship every restricted model
(see ``bench/repro/solver_process_cost.py``) and lose the LP's warm start between the
rounds of column generation; one process for the whole solve stage keeps both.

Signals: SIGINT/SIGTERM reach the parent (and, from a terminal, ``timeout`` or SLURM,
usually the child too). The parent forwards them; the child stops HiGHS and sends what it
knew, and the parent raises :class:`~spidermatch.guard.RunInterrupted` with it. A child
that has not answered ``STOP_GRACE_S`` after that is killed.
"""

from __future__ import annotations

import logging
import math
import multiprocessing
import os
import signal
import threading
import time

from spidermatch import guard
from spidermatch.solve import highs as highs_module
from spidermatch.solve.highs import SolveResult, SolverOptions, relative_gap
from spidermatch.solve.progress import set_known_sink

PR_SET_PDEATHSIG = 1  # prctl(2): the signal a process gets when its parent dies

logger = logging.getLogger(__name__)

POLL_S = 0.05  # how often the parent looks at the pipe, the child and the signals
STOP_GRACE_S = 3.0  # after a forwarded signal, how long the child may take to answer


class KnownFigures:
    """The cheapest incumbent objective and the largest full-model bound reported so far."""

    def __init__(self) -> None:
        self.incumbent = math.inf
        self.bound = -math.inf

    def update(self, incumbent: float | None, bound: float | None) -> bool:
        """Take in a report; True if it improved either figure."""
        better = False
        if incumbent is not None and incumbent < self.incumbent:
            self.incumbent, better = float(incumbent), True
        if bound is not None and bound > self.bound:
            self.bound, better = float(bound), True
        return better

    def as_dict(self) -> dict:
        """JSON-ready figures for ``result.json``, named as in ``interrupted_figures`` (:mod:`highs`)."""
        gap = relative_gap(self.incumbent, self.bound)
        return {
            "incumbent_objective": self.incumbent if math.isfinite(self.incumbent) else None,
            "bound": self.bound if math.isfinite(self.bound) else None,
            "gap": gap if math.isfinite(gap) else None,
        }


def can_isolate() -> bool:
    """Whether this process may start the solver process.

    A daemonic ``multiprocessing`` worker (e.g. of a ``multiprocessing.Pool`` a user runs
    matches in) may not have children; there the solve runs in the worker itself.
    """
    return not multiprocessing.current_process().daemon


def solve_isolated(solve, model, graph, curve, options: SolverOptions) -> SolveResult:
    """``solve(model, graph, curve, options)`` in a forked solver process.

    In a process that may not have children (:func:`can_isolate`), ``solve`` runs here,
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
        logger.info("solving in this process: a daemonic worker process cannot start the solver process")
        return solve(model, graph, curve, options)
    context = multiprocessing.get_context("fork")
    receiver, sender = context.Pipe(duplex=False)
    child = context.Process(
        target=_child_main, args=(sender, solve, model, graph, curve, options), name="spidermatch-solver"
    )
    start = time.perf_counter()
    child.start()
    sender.close()
    logger.info("solver process %d started", child.pid)
    try:
        return _watch(child, receiver, model, start)
    finally:
        receiver.close()
        if child.is_alive():
            child.kill()
        child.join()


def _child_main(sender, solve, model, graph, curve, options) -> None:
    """The solver process: run ``solve`` and send its outcome (multiprocessing then calls ``os._exit``)."""
    _die_with_parent()
    guard.fresh_in_child()
    highs_module.fresh_in_child()
    lock, known = threading.Lock(), KnownFigures()

    def send(message) -> None:
        with lock:
            sender.send(message)

    def sink(incumbent, bound) -> None:  # also called from HiGHS's callbacks, on the solver thread
        with lock:
            if known.update(incumbent, bound):
                sender.send(("known", known.as_dict()))

    set_known_sink(sink)
    try:
        result = solve(model, graph, curve, options)
        send(("result", result))
    except guard.RunInterrupted as stop:
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


def _watch(child, receiver, model, start: float) -> SolveResult:
    """Wait for the child's outcome, forwarding signals; what it sent, or a failure result."""
    known, forwarded_at = {}, None
    with guard.native_call():  # a signal is only recorded meanwhile: the child must hear of it first
        while True:
            if receiver.poll(POLL_S):
                try:
                    message = receiver.recv()
                except EOFError:  # the child is gone without a result
                    break
                kind = message[0]
                if kind == "known":
                    known = message[1]
                    continue
                if kind == "result":
                    return message[1]
                if kind == "raised":
                    raise message[1]
                _, signum, figures = message
                _raise_interrupted(signum, {**known, **figures})
            elif not child.is_alive() and not receiver.poll():
                break
            if guard.stop_requested() and forwarded_at is None:
                forwarded_at = time.perf_counter()
                os.kill(child.pid, guard.received_signal())
            if forwarded_at is not None and time.perf_counter() - forwarded_at > STOP_GRACE_S:
                logger.warning("the solver process did not stop within %.0f s: killed", STOP_GRACE_S)
                child.kill()
                _raise_interrupted(guard.received_signal(), known)
    child.join()
    return _failure(child.exitcode, known, model, time.perf_counter() - start)


def _raise_interrupted(signum: int, figures: dict) -> None:
    """Raise :class:`RunInterrupted` for ``signum`` with the child's figures."""
    if guard.stop_requested():
        guard.raise_if_stopped(figures)
    raise guard.RunInterrupted(signum, figures)


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
