"""The repair of a solver process's last reported solution, in the reserve at the end of a run.

A solver process stopped from outside (:mod:`spidermatch.solve.isolate`) leaves only what it
reported: its closed paths, its bound, and its cheapest solution with detached cycles
(:func:`spidermatch.solve.progress.report_detached`). :func:`repair_reported` turns that
solution into a closed path nearby, in a fresh solver process, from the model alone.
"""

from __future__ import annotations

import math
import time

import numpy as np

from spidermatch.model.lazy_model import LazyModel
from spidermatch.model.product_graph import ProductGraph
from spidermatch.model.solution import USED
from spidermatch.solve.connectivity import detached_components_of_edges
from spidermatch.solve.cuts import CutPool
from spidermatch.solve.repair import repair_with_nearby_columns
from spidermatch.solve.types import SolveResult, SolverOptions


def repair_reported(
    edges: np.ndarray, lazy: LazyModel, graph: ProductGraph, curve, options: SolverOptions
) -> SolveResult:
    """A closed path near a reported solution with detached cycles, from the model alone.

    What a solver process stopped from outside leaves is the last such solution it reported
    (:func:`spidermatch.solve.progress.report_detached`), not its restricted columns or cuts.
    This repair needs neither: it frees the full model's columns near the solution in windows
    around its detached cycles, with flow rows there
    (:func:`~spidermatch.solve.repair.repair_with_nearby_columns`, the solution's own edges
    standing in for the restricted columns). It proves nothing.

    Parameters
    ----------
    edges : np.ndarray, shape (m,)
        Edge ids of the solution with detached cycles, sorted.
    lazy : LazyModel
    graph : ProductGraph
        ``lazy.graph``.
    curve : spidermatch.model.curve.SpiderCurve
        Its ``first_layer`` (L,) ties the layers of one source vertex.
    options : SolverOptions
        Its time limit is the repair's.

    Returns
    -------
    SolveResult
        "feasible" with the closed path (n_vars,) and its cost, bound ``-inf``; "no_solution"
        when none was found in time, or when the solution has no detached cycle to repair.

    """
    start = time.perf_counter()
    pool = CutPool(first_layer=curve.first_layer)
    components = detached_components_of_edges(graph, edges)
    repaired = None
    if components:
        layers = pool.note_detached(graph, components)
        repaired = repair_with_nearby_columns(lazy, edges, edges, layers, pool, options)
    wall = time.perf_counter() - start
    if repaired is None:
        return SolveResult(
            "no_solution", None, math.inf, -math.inf, math.nan, wall, lazy.n_vars, lazy.n_rows, 0,
            "no closed path found near the reported solution",
        )  # fmt: skip
    used = np.flatnonzero(repaired > USED)
    objective = float(lazy.costs(used) @ repaired[used])
    return SolveResult(
        "feasible", repaired, objective, -math.inf, math.nan, wall, lazy.n_vars, lazy.n_rows, 0,
        "a closed path near the last reported solution with detached cycles",
    )  # fmt: skip
