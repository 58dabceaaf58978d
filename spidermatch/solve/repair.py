"""Repair a MIP solution with detached cycles into one closed path nearby.

When a restricted MIP's optimum has detached cycles, the re-solve with their cuts starts from
the best *connected* solution HiGHS reported, often only the stay path, which can cost many
times as much as the solution with detached cycles (measurements: bench/README.md, solver
constants). The repair keeps the solution's own edges and frees every column of the restricted
model in a few layers around each layer with a detached cycle (and around the other layers of
its source vertex, which PES ties to it); a small MIP over those columns, with the flow rows of
:mod:`spidermatch.solve.layer_flow` in the affected layers, re-routes the path there (the
windows also cover the layers PES ties to the freed ones, and widen once if the first try has no
closed path). Its answer is only a start for the re-solve: it proves nothing and is checked to
be one closed walk before it is used. Column generation, whose restricted MIP may lack the
columns of any closed path nearby, can also widen the repair to the full model's columns near
the solution (:func:`repair_with_nearby_columns`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace

import numpy as np
import scipy.sparse as sp

from spidermatch.model.ilp import IlpModel, restrict_columns
from spidermatch.model.lazy_model import LazyModel
from spidermatch.model.product_graph import ProductGraph
from spidermatch.model.solution import USED
from spidermatch.solve.connectivity import is_closed_path
from spidermatch.solve.highs import HighsSession
from spidermatch.solve.layer_flow import SessionFlows
from spidermatch.solve.progress import report_repairing
from spidermatch.solve.types import SolverOptions

logger = logging.getLogger(__name__)

REPAIR_WINDOWS = (3, 12)  # layers on each side of an affected layer whose columns the repair frees:
# the first try, and a wider one if the first has no closed path
REPAIR_TIME_S = 30.0  # the repair MIP's time limit at most ...
REPAIR_TIME_SHARE = 0.2  # ... and, between cut rounds, at most this share of the time left
STOP_RESERVE_S = 2 * REPAIR_TIME_S  # a MIP whose cheapest solution has detached cycles stops this long
# (at most REPAIR_TIME_SHARE of the limit) before the limit, for the repairs in the solver process;
# the last half is the reserve of a repair in a fresh process if that one is still inside HiGHS
# (spidermatch.solve.isolate)
REPAIR_GAP = 1e-3  # a start, not a proof: stop within this relative gap
NEARBY_RINGS = 2  # a widened repair adds the columns within this many target rings of the solution ...
NEARBY_STAGES = (
    (2, 0),
    (REPAIR_WINDOWS[0], 1),
    (REPAIR_WINDOWS[0], NEARBY_RINGS),
    (REPAIR_WINDOWS[1], NEARBY_RINGS),
)  # ... at most: its tries, as (window, rings), smallest first. A smaller repair MIP finds a closed
# path sooner and often a cheaper one (TOSCA horse5-plane vs horse0: 5.72 in 6 s with 0 rings and
# windows of 2 layers, 7.59 in 40 s with 1 ring and 3 layers, 8.78 in 60 s with 2 rings;
# bench/README.md, solver constants)
NEARBY_TRY_SHARE = 0.5  # every try but the last gets at most this share of the repair's time left


def stop_reserve(time_limit: float) -> float:
    """Seconds before ``time_limit`` at which a MIP stops to leave time for the repairs."""
    return min(STOP_RESERVE_S, REPAIR_TIME_SHARE * time_limit)


def window_layers(layers, n_layers: int, window: int = REPAIR_WINDOWS[0]) -> np.ndarray:
    """Mask (L,) of the layers within ``window`` positions of any of ``layers`` (cyclically)."""
    near = np.zeros(n_layers, dtype=bool)
    for layer in layers:
        near[(int(layer) + np.arange(-window, window + 1)) % n_layers] = True
    return near


def freed_layers(layers, first_layer: np.ndarray | None, n_layers: int, window: int) -> np.ndarray:
    """Mask (L,) of the layers a repair frees: windows around ``layers``, closed under PES twice.

    A freed layer whose source vertex recurs elsewhere on the curve is tied by PES to that
    layer; were it kept fixed, the freed one could not move either. So the windows of those
    layers are freed as well (twice over; ``first_layer`` (L,) is the curve's).
    """
    near = window_layers(layers, n_layers, window)
    if first_layer is None:
        return near
    for _ in range(2):
        tied = np.flatnonzero(np.isin(first_layer, np.unique(first_layer[near])) & ~near)
        near |= window_layers(tied, n_layers, window)
    return near


def repair_detached(
    model: IlpModel,
    graph: ProductGraph,
    column_ids: np.ndarray,
    x_sub: np.ndarray,
    affected_layers,
    pool,
    options: SolverOptions,
) -> np.ndarray | None:
    """A closed path (k,) over the restricted columns near ``x_sub``, or None if none was found.

    Parameters
    ----------
    model : IlpModel
        The restricted model (k columns).
    graph : ProductGraph
    column_ids : np.ndarray, shape (k,)
        Full-model edge id of each column of ``model``, sorted.
    x_sub : np.ndarray, shape (k,) or longer
        The solution with detached cycles (entries after the first k are ignored).
    affected_layers : iterable of int
        Layers whose columns are freed, with the layers around them (:func:`freed_layers`;
        first ``REPAIR_WINDOWS[0]`` on each side, then, if that has no closed path, the next).
    pool : spidermatch.solve.cuts.CutPool
        Its connectivity cuts and flow layers go into the repair MIP; its ``first_layer``
        ties layers of one source vertex.
    options : SolverOptions
        Its time limit is the repair's (callers give it at most ``REPAIR_TIME_S``).

    """
    k = column_ids.size
    used = np.asarray(x_sub[:k]) > USED
    layer_of = column_ids // graph.block_size

    def attempt(near: np.ndarray, _, local_options: SolverOptions):
        positions = np.flatnonzero(used | near[layer_of])
        local_x = _local_mip(model, graph, column_ids[positions], positions, pool, local_options)
        return positions, local_x

    return _in_growing_windows(attempt, affected_layers, pool, graph.n_layers, k, options)


def _in_growing_windows(
    attempt, affected_layers, pool, n_layers: int, size: int, options: SolverOptions,
    stages=tuple((window, None) for window in REPAIR_WINDOWS), share: float = 1.0,
):  # fmt: skip
    """The first closed path ``attempt(freed layers (L,), stage, options)`` finds over ``stages``.

    ``stages`` are (window, anything the attempt needs) pairs, tried in order; every try but the
    last gets at most ``share`` of the time left. ``attempt`` returns (positions (p,), a solution
    over them or None); the answer is that solution spread into a vector (size,), or None when
    no try gave one in time.
    """
    deadline = time.perf_counter() + options.time_limit
    report_repairing()  # a solver process that repairs is not stuck (spidermatch.solve.isolate)
    for number, (window, stage) in enumerate(stages):
        left = deadline - time.perf_counter()
        if left <= 0:
            return None
        if number < len(stages) - 1:
            left *= share
        near = freed_layers(affected_layers, pool.first_layer, n_layers, window)
        positions, local_x = attempt(near, stage, replace(options, time_limit=left))
        if local_x is not None:
            repaired = np.zeros(size)
            repaired[positions] = local_x
            return repaired
    return None


def _local_mip(model, graph, local_ids, positions, pool, options, flow_layers=None) -> np.ndarray | None:
    """The repair MIP over the columns at ``positions``: a closed path (len(positions),) or None.

    Flow rows keep the path in one piece in ``flow_layers`` (default: the pool's).
    """
    local_options = replace(options, mip_rel_gap=max(options.mip_rel_gap, REPAIR_GAP))
    session = HighsSession(restrict_columns(model, positions), local_options, label="repair MIP")
    if pool.rows is not None:
        session.add_rows(pool.rows[:, local_ids], pool.lower, pool.upper)
    SessionFlows(graph, local_ids, session).cover(pool.flow_layers if flow_layers is None else flow_layers)
    result = session.run()
    if result.x is None:
        logger.info("repair over %d columns: no closed path (%s)", positions.size, result.message)
        return None
    local_x = result.x[: positions.size]
    if not is_closed_path(graph, local_x, local_ids):
        logger.info("repair over %d columns: its solution has detached cycles", positions.size)
        return None
    logger.info(
        "repair: a closed path of cost %.6g over %d columns (%.1f s)",
        result.objective,
        positions.size,
        result.wall_time,
    )
    return local_x


def nearby_columns(graph: ProductGraph, used: np.ndarray, layers: np.ndarray, rings: int = NEARBY_RINGS):
    """Edge ids of ``layers`` between target vertices near where the solution ``used`` runs.

    Parameters
    ----------
    graph : ProductGraph
    used : np.ndarray, shape (m,)
        Edge ids of a solution (e.g. one with detached cycles).
    layers : np.ndarray, shape (L,), bool
        The layers whose columns may be added.
    rings : int
        A layer's columns are those whose two target vertices lie within ``rings`` rings of a
        vertex the solution visits in that layer or the layers before and after it.

    Returns
    -------
    np.ndarray, shape (k,), int64
        Sorted edge ids.

    """
    n_layers, n = graph.n_layers, graph.n_target
    tuples = graph.edge_tuples(used)
    visited = np.zeros((n_layers, n), dtype=bool)
    visited[tuples[:, 0], tuples[:, 1]] = True
    visited[tuples[:, 2], tuples[:, 3]] = True
    visited |= np.roll(visited, 1, axis=0) | np.roll(visited, -1, axis=0)
    edges = graph.target_edges
    step = sp.csr_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n)) + sp.identity(n)
    chosen = np.flatnonzero(layers)
    reach = visited[chosen].T.astype(np.float64)  # (V_Y, k): one column per chosen layer
    for _ in range(rings):
        reach = step @ reach
    near = reach.T > 0
    rows, entries = np.nonzero(near[:, graph.block_src] & near[:, graph.block_dst])
    return chosen[rows].astype(np.int64) * graph.block_size + entries  # ascending: rows, then entries


def repair_with_nearby_columns(
    lazy: LazyModel,
    columns: np.ndarray,
    used: np.ndarray,
    affected_layers,
    pool,
    options: SolverOptions,
) -> np.ndarray | None:
    """A closed path (n,) near a solution with detached cycles, over columns a restricted MIP lacked.

    :func:`repair_detached` re-routes within the restricted MIP's columns; where those hold no
    closed path near the solution (the path's detours around a self-intersection need columns
    that the path reduced costs left out), this repair also frees, in windows of layers around
    the affected ones, every column of the full model between target vertices near the solution
    (:func:`nearby_columns`), with flow rows in every freed layer so that the re-routed path has
    no detached cycle there. It tries :data:`NEARBY_STAGES` in turn, from windows of 2 layers and
    the target vertices the solution visits (0 rings) to windows of 12 layers and
    :data:`NEARBY_RINGS` rings, each try but the last with at most :data:`NEARBY_TRY_SHARE` of
    the time left: a smaller repair MIP finds its closed path sooner, often a cheaper one too.
    Its answer is a start and an incumbent: it proves nothing, and it is checked to be one
    closed walk; its model holds every row of the full model that its columns touch, so it is
    feasible for the full model.

    Parameters
    ----------
    lazy : LazyModel
    columns : np.ndarray, shape (k,)
        The restricted MIP's columns (sorted edge ids).
    used : np.ndarray, shape (m,)
        Edge ids of the solution with detached cycles.
    affected_layers : iterable of int
        Layers of its detached cycles (and those PES ties to them).
    pool : spidermatch.solve.cuts.CutPool
    options : SolverOptions
        Its time limit is the repair's.

    Returns
    -------
    np.ndarray, shape (n,) or None
        The closed path as a full-model 0/1 vector, or None if none was found in time.

    """
    graph = lazy.graph

    def attempt(near: np.ndarray, rings: int, local_options: SolverOptions):
        inside = columns[near[columns // graph.block_size]]
        positions = np.union1d(np.union1d(used, inside), nearby_columns(graph, used, near, rings))
        model = lazy.compact_submodel(positions)
        flow_layers = pool.flow_layers | set(np.flatnonzero(near).tolist())  # no new cycle where it re-routes
        local = np.arange(positions.size)
        return positions, _local_mip(model, graph, positions, local, pool, local_options, flow_layers)

    return _in_growing_windows(
        attempt, affected_layers, pool, graph.n_layers, lazy.n_vars, options, NEARBY_STAGES, NEARBY_TRY_SHARE
    )
