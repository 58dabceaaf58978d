"""Running HiGHS so that a signal or an overrun deadline stops it without freeing memory under it.

Every solve of the process runs on one long-lived solver thread while the main thread waits
in Python, where signal handlers run at once; a stop goes to HiGHS through its own interrupt
callbacks (:class:`spidermatch.solve.highs.HighsSession`).
"""

from __future__ import annotations

import logging
import os
import queue
import threading
import time

from spidermatch import shutdown

logger = logging.getLogger(__name__)


class _SolverThread:
    """One long-lived daemon thread that runs every HiGHS solve of the process.

    The main thread waits in Python, so a signal handler runs at once (it cannot while the
    main thread is inside C++); and HiGHS always sees the same calling thread, as it did
    when it ran on the main thread.
    """

    def __init__(self) -> None:
        self.jobs: queue.Queue = queue.Queue()
        self.thread: threading.Thread | None = None

    def submit(self, job) -> threading.Event:
        """Run ``job()`` on the solver thread; the returned event is set when it has finished."""
        if self.thread is None or not self.thread.is_alive():
            self.thread = threading.Thread(target=self._work, args=(self.jobs,), name="highs", daemon=True)
            self.thread.start()
        done = threading.Event()
        self.jobs.put((job, done))
        return done

    @staticmethod
    def _work(jobs: queue.Queue) -> None:
        while True:
            job, done = jobs.get()
            try:
                job()
            finally:
                done.set()


_SOLVER_THREAD = _SolverThread()


def fresh_in_child() -> None:
    """In a forked child: a solver thread of its own (the parent's is not in the child).

    HiGHS's thread pool is per calling thread, so the child's first solve starts a new one.
    Registered to run after every ``fork`` (the solver process, a user's
    ``multiprocessing.Pool`` worker), as a solve there would otherwise wait forever on the
    parent's thread.
    """
    global _SOLVER_THREAD
    _SOLVER_THREAD = _SolverThread()


os.register_at_fork(after_in_child=fresh_in_child)


STOP_GRACE_S = 1.0  # after a signal, how long to wait for HiGHS to reach an interrupt check


OVERRUN_GRACE_S = 2.0  # how far HiGHS may run past its time limit before it is interrupted (callbacks)


def run_interruptibly(highs, figures_so_far, cancel: threading.Event, deadline: float | None = None) -> None:
    """``highs.run()`` on the solver thread, stopped by SIGINT/SIGTERM or at ``deadline``.

    On a signal HiGHS's interrupt callbacks stop the solve at its next check. HiGHS does
    not check during presolve or some heuristics, which can last minutes; if it has not
    stopped within ``STOP_GRACE_S`` the solve is abandoned (it dies with the process) and
    :class:`~spidermatch.shutdown.RunInterrupted` carries ``figures_so_far()``.

    HiGHS's own time limit is not checked in those phases either, so a MIP can run far past it
    (measurements: bench/README.md, solver constants). Past ``deadline``
    (``time.perf_counter()`` seconds) ``cancel`` is set, which the callbacks turn into HiGHS's
    own interrupt (``user_interrupt``), and the run is waited for: a run is never left running
    while the process goes on (a solver thread left behind could use memory that Python or HiGHS
    has meanwhile freed or reused, and ran concurrently with the next solve). Returns when
    ``highs.run()`` has finished.
    """
    failure: list[BaseException] = []

    def job() -> None:
        try:
            highs.run()
        except BaseException as error:  # re-raised on the calling thread
            failure.append(error)

    with shutdown.native_call():
        done = _SOLVER_THREAD.submit(job)
        try:
            while not done.wait(0.05):
                if shutdown.stop_requested() and not done.wait(STOP_GRACE_S):
                    shutdown.abandon_native_work()
                    shutdown.raise_if_stopped(figures_so_far())
                if deadline is not None and time.perf_counter() > deadline and not cancel.is_set():
                    logger.warning(
                        "HiGHS is %.0f s past its time limit: interrupting it at its next check",
                        OVERRUN_GRACE_S,
                    )
                    cancel.set()
        except BaseException:  # e.g. KeyboardInterrupt without spidermatch's handler: stop HiGHS too
            cancel.set()
            raise
    if failure:
        raise failure[0]
