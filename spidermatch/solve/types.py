"""What every solve takes and returns: options, results, the relative gap and the time left.

A leaf of :mod:`spidermatch.solve`: it imports nothing from the other solve modules.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from spidermatch.model.curve import SpiderCurve
from spidermatch.model.ilp import IlpModel
from spidermatch.model.product_graph import ProductGraph
from spidermatch.model.solution import FRACTIONAL


@dataclass(frozen=True)
class SolverOptions:
    """Options of one HiGHS solve.

    Attributes
    ----------
    time_limit : float
        Seconds; ``inf`` for none.
    mip_rel_gap : float
        Stop when (objective - bound) / objective <= this (HiGHS's default is 1e-4).
    threads : int
        Worker threads (0: HiGHS chooses). Fixed for the whole process by the first solve.
    presolve : str
        "choose", "on" or "off".
    log : bool
        Show HiGHS's own log.
    extra : dict
        Any further HiGHS options by name.
    memory_share : float
        Share of the machine's free memory that this solve may count on before it starts a
        large restricted MIP (0.5 for each of two solves side by side;
        :func:`spidermatch.memory.available_memory`).
    flow_rows : str
        Where the MIPs (the restricted ones of ``colgen`` and ``rcfix``, ``plain``'s full model)
        get the flow rows that keep the path in one piece (:mod:`spidermatch.solve.layer_flow`):
        "found", in the layers where a solution showed a detached cycle (then re-solved);
        "intersections", in every self-intersection layer of the SpiderCurve from the first MIP
        on (measured: stronger bounds, weaker incumbents; docs/solver_failures.md).
    lp_cuts : bool
        ``colgen``: add the connectivity cuts its LP solution violates to the LP and price on
        with their duals (:mod:`spidermatch.solve.lp_cuts`), for a higher bound and smaller
        restricted MIPs.

    """

    time_limit: float = math.inf
    mip_rel_gap: float = 1e-4
    threads: int = 0
    presolve: str = "choose"
    log: bool = False
    extra: dict = field(default_factory=dict)
    memory_share: float = 1.0
    flow_rows: str = "found"
    lp_cuts: bool = True


FLOW_ROWS_VALUES = ("found", "intersections")
"""Values of :attr:`SolverOptions.flow_rows`."""


OUT_OF_MEMORY = "Memory limit reached"
"""How a result begins its message when HiGHS stopped because an allocation failed."""


@dataclass(frozen=True)
class SolveResult:
    """Outcome of a solve.

    Attributes
    ----------
    status : str
        "optimal" (within ``mip_rel_gap``), "feasible" (stopped with an incumbent, not
        proven), "infeasible", "no_solution" (stopped before any incumbent) or "error".
    x : np.ndarray, shape (n,), or None
        The solution, rounded to 0/1 for MIPs.
    objective, bound, gap : float
        Incumbent value, best proven lower bound, relative gap (nan when undefined).
    wall_time : float
    n_vars, n_rows, nnz : int
    message : str
        HiGHS's model status in words.

    """

    status: str
    x: np.ndarray | None
    objective: float
    bound: float
    gap: float
    wall_time: float
    n_vars: int
    n_rows: int
    nnz: int
    message: str = ""
    cut_rounds: int = 0
    columns_built: int | None = None  # columns a strategy that never builds the full model did build

    @property
    def out_of_memory(self) -> bool:
        """True if HiGHS stopped because an allocation failed (:data:`OUT_OF_MEMORY`)."""
        return self.message.startswith(OUT_OF_MEMORY)

    @property
    def proven_optimal(self) -> bool:
        """True if the solution is certified optimal within the relative gap."""
        return self.status == "optimal"

    def summary(self) -> dict:
        """JSON-ready figures (no solution vector)."""
        return {
            "status": self.status,
            "proven_optimal": self.proven_optimal,
            "objective": finite_or_none(self.objective),
            "bound": finite_or_none(self.bound),
            "gap": finite_or_none(self.gap),
            "solve_time_s": round(self.wall_time, 3),
            "variables": self.n_vars,
            "rows": self.n_rows,
            "nonzeros": self.nnz,
            "message": self.message,
            "columns_built": self.columns_built,
        }


def finite_or_none(value: float) -> float | None:
    """``value`` as a float, or None when it is missing or not finite (for JSON)."""
    return float(value) if value is not None and math.isfinite(value) else None


ROUNDING_GAP = 1e-12
"""Difference of objective and bound, relative to max(1, |objective|), that is rounding, not a gap."""


def relative_gap(objective: float, bound: float) -> float:
    """(objective - bound) / |objective|; 0 when they differ only by rounding, nan when undefined.

    A pair whose costs vanish on the optimum (a mesh matched to an exact copy with its own
    features) has an objective and a bound of about 1e-18 each: their relative difference
    is rounding noise (23 % on one such pair), not a gap worth a warning.
    """
    if not (math.isfinite(objective) and math.isfinite(bound)):
        return math.nan
    if abs(objective - bound) <= ROUNDING_GAP * max(1.0, abs(objective)):
        return 0.0
    return max(objective - bound, 0.0) / max(abs(objective), 1e-300)


def certified_mip_bound(dual_bound: float, incumbent: float, rel_gap: float) -> float:
    """A lower bound that HiGHS's branch and bound really proves.

    HiGHS prunes every node whose bound is within the relative gap of the incumbent
    and, once none is left, reports the incumbent itself as its dual bound. Only
    ``incumbent - rel_gap * |incumbent|`` is proven for what was pruned, so the bound
    is the smaller of the two (the reported one alone when there is no incumbent).
    """
    if not math.isfinite(incumbent):
        return dual_bound
    return min(dual_bound, incumbent - rel_gap * abs(incumbent))


class LpNotSolved(Exception):
    """An LP (the relaxation or a restricted LP) stopped (time limit) or failed; carries HiGHS's result.

    One class for every strategy, so that an ``except LpNotSolved`` catches it wherever it was raised.
    """

    def __init__(self, result: SolveResult) -> None:
        super().__init__(result.message)
        self.result = result


def interrupted_figures(result: SolveResult) -> dict:
    """What an interrupted solve knew: HiGHS's incumbent (unchecked) and its bound, JSON-ready."""
    return {
        "incumbent_objective": finite_or_none(result.objective),
        "bound": finite_or_none(result.bound),
        "gap": finite_or_none(result.gap),
        "solver_message": result.message,
    }


def remaining(options: SolverOptions, start: float) -> SolverOptions:
    """The options with the time limit reduced by what has elapsed since ``start``."""
    left = max(options.time_limit - (time.perf_counter() - start), 0.0)
    return replace(options, time_limit=left)


def count_fractional(x: np.ndarray, tolerance: float = FRACTIONAL) -> int:
    """How many entries of an LP solution x (n,) are more than ``tolerance`` away from 0 and 1."""
    return int(np.sum((x > tolerance) & (x < 1 - tolerance)))


Strategy = Callable[[IlpModel, ProductGraph, SpiderCurve, SolverOptions], SolveResult]
