"""Progress of a HiGHS solve as a log line every few seconds, without HiGHS's own log.

HiGHS calls its interrupt callbacks many times a second during simplex and branch and
bound; :class:`ProgressLog` turns them into at most one INFO line per ``interval`` seconds:
incumbent, bound and gap for a MIP, the iteration count for an LP, and the elapsed time.
"""

from __future__ import annotations

import logging
import math
import time

from spidermatch.solve.types import relative_gap

logger = logging.getLogger(__name__)

PROGRESS_INTERVAL = 5.0  # seconds between two progress lines


def format_value(value: float) -> str:
    """A solver figure for the log: HiGHS reports "no incumbent" as +-inf."""
    return f"{value:.6g}" if math.isfinite(value) and abs(value) < 1e30 else "none"


def format_gap(incumbent: float, bound: float) -> str:
    """The relative gap (incumbent - bound) / |incumbent| in percent, or "n/a"."""
    if max(abs(incumbent), abs(bound)) >= 1e30:  # HiGHS's "none"
        return "n/a"
    gap = relative_gap(incumbent, bound)
    return f"{100.0 * gap:.2f} %" if math.isfinite(gap) else "n/a"


class ProgressLog:
    """Rate-limited progress lines for one HiGHS model.

    Parameters
    ----------
    label : str
        What is being solved ("MIP over 12345 columns", "LP relaxation"), at the start of each line.
    interval : float
        Minimum seconds between two lines; the first comes after ``interval`` seconds, so
        solves shorter than that stay silent.

    """

    def __init__(self, label: str, interval: float = PROGRESS_INTERVAL) -> None:
        self.label = label
        self.interval = interval
        self.started = time.perf_counter()
        self.last = self.started

    def _due(self) -> float | None:
        """Elapsed seconds if a line is due now, else None."""
        now = time.perf_counter()
        if now - self.last < self.interval:
            return None
        self.last = now
        return now - self.started

    def mip(self, data_out) -> None:
        """Called from HiGHS's MIP interrupt callback (``data_out``: its ``HighsCallbackOutput``)."""
        elapsed = self._due()
        if elapsed is None:
            return
        incumbent, bound = float(data_out.mip_primal_bound), float(data_out.mip_dual_bound)
        logger.info(
            "%s: incumbent %s, bound %s, gap %s, %d nodes, %.0f s",
            self.label,
            format_value(incumbent),
            format_value(bound),
            format_gap(incumbent, bound),
            int(data_out.mip_node_count),
            elapsed,
        )

    def simplex(self, data_out) -> None:
        """Called from HiGHS's simplex interrupt callback."""
        elapsed = self._due()
        if elapsed is None:
            return
        logger.info(
            "%s: %d simplex iterations, %.0f s", self.label, int(data_out.simplex_iteration_count), elapsed
        )


_KNOWN_SINK = None  # (incumbent, bound, path) -> None; set in a solver process (spidermatch.solve.isolate)
_DETACHED_SINK = None  # (objective, edges) -> None; likewise


def set_known_sink(sink, detached_sink=None) -> None:
    """Send the figures of :func:`report_known` to ``sink(incumbent, bound, path)`` (None: nowhere).

    ``detached_sink(objective, edges)`` receives those of :func:`report_detached`, and
    ``(None, None)`` from :func:`report_repairing`.
    """
    global _KNOWN_SINK, _DETACHED_SINK
    _KNOWN_SINK, _DETACHED_SINK = sink, detached_sink


def report_known(incumbent: float | None = None, bound: float | None = None, path=None) -> None:
    """Record what a run already knows, in case the solver dies or hangs before it returns.

    Parameters
    ----------
    incumbent : float, optional
        Objective of a solution of the full model that passes as a result (one closed path).
    bound : float, optional
        A lower bound certified for the full model.
    path : np.ndarray, shape (k,), optional
        The incumbent itself: the full-model columns it sets to 1 (sorted ids). With it, a
        solve stopped from outside still returns that matching, not only its cost.

    """
    if _KNOWN_SINK is not None:
        _KNOWN_SINK(incumbent, bound, path)


def report_detached(objective: float, edges) -> None:
    """Record a MIP solution with detached cycles, cheaper than every closed path known then.

    Connectivity cuts will cut it off, but a repair (:mod:`spidermatch.solve.repair`) can turn
    it into a closed path nearby; if the solver is stopped before it gets that far, the run
    can still repair it elsewhere (:func:`spidermatch.solve.isolate.solve_isolated`).

    Parameters
    ----------
    objective : float
        Its cost.
    edges : np.ndarray, shape (k,)
        The full-model columns (product-graph edge ids) it sets to 1, sorted.

    """
    if _DETACHED_SINK is not None:
        _DETACHED_SINK(objective, edges)


def report_repairing() -> None:
    """Record that this process itself now repairs its solutions with detached cycles."""
    if _DETACHED_SINK is not None:
        _DETACHED_SINK(None, None)
