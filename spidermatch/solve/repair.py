"""Repair a MIP solution with detached cycles into one closed path nearby.

When a restricted MIP's optimum has detached cycles, the re-solve with their cuts starts from
the best *connected* solution HiGHS reported, often only the stay path: on FAUST_r 076->077 at
4000 faces a MIP over 433 k columns found 2.0115 (bound 2.0067) with detached cycles and then
had to restart from 415.2. The repair keeps the solution's own edges and frees every column of
the restricted model in a few layers around each layer with a detached cycle (and around the
other layers of its source vertex, which PES ties to it); a small MIP over those columns, with
the flow rows of :mod:`spidermatch.solve.layer_flow` in the affected layers, re-routes the path
there. Its answer is only a start for the re-solve: it proves nothing and is checked to be one
closed walk before it is used.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from spidermatch.ilp import IlpModel, restrict_columns
from spidermatch.product_graph import ProductGraph
from spidermatch.solve.connectivity import detached_components_of_edges
from spidermatch.solve.highs import HighsSession, SolverOptions
from spidermatch.solve.layer_flow import SessionFlows

logger = logging.getLogger(__name__)

REPAIR_WINDOW = 3  # layers on each side of an affected layer whose columns the repair frees
REPAIR_TIME_S = 30.0  # the repair MIP's time limit at most ...
REPAIR_TIME_SHARE = 0.2  # ... and, between cut rounds, at most this share of the time left
REPAIR_GAP = 1e-3  # a start, not a proof: stop within this relative gap


def window_layers(layers, n_layers: int, window: int = REPAIR_WINDOW) -> np.ndarray:
    """Mask (L,) of the layers within ``window`` positions of any of ``layers`` (cyclically)."""
    near = np.zeros(n_layers, dtype=bool)
    for layer in layers:
        near[(int(layer) + np.arange(-window, window + 1)) % n_layers] = True
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
        Layers whose columns are freed, with ``REPAIR_WINDOW`` layers on each side.
    pool : spidermatch.solve.strategies.CutPool
        Its connectivity cuts go into the repair MIP.
    options : SolverOptions
        Its time limit is the repair's (callers give it at most ``REPAIR_TIME_S``).

    """
    k = column_ids.size
    used = np.asarray(x_sub[:k]) > 0.5
    near = window_layers(affected_layers, graph.n_layers)
    positions = np.flatnonzero(used | near[column_ids // graph.block_size])
    local_ids = column_ids[positions]
    local_options = replace(options, mip_rel_gap=max(options.mip_rel_gap, REPAIR_GAP))
    session = HighsSession(restrict_columns(model, positions), local_options, label="repair MIP")
    if pool.rows is not None:
        session.add_rows(pool.rows[:, local_ids], pool.lower, pool.upper)
    SessionFlows(graph, local_ids, session).cover(pool.flow_layers)
    result = session.run()
    if result.x is None:
        logger.info("repair: no closed path near the solution (%s)", result.message)
        return None
    local_x = result.x[: positions.size]
    if detached_components_of_edges(graph, local_ids[local_x > 0.5]):
        return None
    repaired = np.zeros(k)
    repaired[positions] = local_x
    logger.info(
        "repair: a closed path of cost %.6g over %d columns (%.1f s)",
        result.objective,
        positions.size,
        result.wall_time,
    )
    return repaired
