"""The overlap of two parts found by the matching itself (``overlap_method="matched"``).

:func:`spidermatch.geometry.overlap.estimated_overlap` reads the overlap off the descriptors
before any solve. Here the SpiderMatch ILP over all of the source decides it, with a void
vertex on the target (:mod:`spidermatch.model.void`): a curve position with no partner is
matched to the void at a cost per unit of length, and the void is entered and left only at the
target's boundary. The source vertices the certified solution matches to the target are the
overlap; the piece they make is then matched as a part of the target as before.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np

from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.remesh import nearest_vertices
from spidermatch.model import void
from spidermatch.model.curve import AUTO_TOUR, TOURS
from spidermatch.model.void import matched_curve_vertices, void_layers
from spidermatch.pipeline import MatchSettings, _solved, closed_copies, prepare, strategy_resolved
from spidermatch.solve.types import SolveResult, finite_or_none

logger = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class MatchedOverlap:
    """The source overlap a void-vertex solve found.

    Attributes
    ----------
    region : np.ndarray, shape (V_X,), bool, or None
        Source vertices matched to the target (each takes the answer of its nearest decimated
        vertex); None when the solve ended without a solution.
    solved : SolveResult
        The solve (its ``x`` let go).
    void_share : float
        Share of the curve's positions matched to the void (nan without a solution).

    """

    region: np.ndarray | None
    solved: SolveResult
    void_share: float

    def summary(self) -> dict:
        """What ``result.json["overlap"]["found_by"]`` records of the solve (None for an undefined figure)."""
        solved = self.solved
        return {
            "status": solved.status,
            "objective": finite_or_none(solved.objective),
            "bound": finite_or_none(solved.bound),
            "gap": finite_or_none(solved.gap),
            "solve_s": round(float(solved.wall_time), 3),
            "void_share": finite_or_none(round(float(self.void_share), 4)),
        }


def matched_overlap(
    source: Mesh,
    target: Mesh,
    source_features: np.ndarray,
    target_features: np.ndarray,
    settings: MatchSettings,
    void_factor: float | None = None,
    estimate: np.ndarray | None = None,
    outside_weight: float | None = None,
) -> MatchedOverlap:
    """Solve the ILP of all of ``source`` onto ``target`` with a void vertex; the source it matches.

    Parameters
    ----------
    source, target : Mesh
        Two parts of one surface in one unit (V_X and V_Y vertices).
    source_features : np.ndarray, shape (V_X, D)
    target_features : np.ndarray, shape (V_Y, D)
    settings : MatchSettings
        As for the match (resolution, solver, costs); the source is measured as a part of the
        target, no dense map is made, and ``curve_tour="auto"`` takes the paper's tour.
    void_factor : float, optional
        :func:`spidermatch.model.void.void_cost`'s factor (default
        :data:`spidermatch.model.void.VOID_FACTOR`).
    estimate : np.ndarray, shape (V_X,), bool, optional
        An estimate of the overlap (:func:`~spidermatch.geometry.overlap.estimated_overlap`): the
        void costs ``outside_weight`` times as much at the source vertices outside it (default
        :data:`spidermatch.model.void.OUTSIDE_WEIGHT`). None: the same everywhere.

    """
    void_factor = void.VOID_FACTOR if void_factor is None else void_factor
    outside_weight = void.OUTSIDE_WEIGHT if outside_weight is None else outside_weight
    weights = None if estimate is None else np.where(np.asarray(estimate, dtype=bool), 1.0, outside_weight)
    tour = TOURS[0] if settings.curve_tour == AUTO_TOUR else settings.curve_tour
    settings = strategy_resolved(dataclasses.replace(settings, partial=True, dense=None, curve_tour=tour))
    closed = closed_copies(source, target, settings)
    low_x, _, curve, graph, model = prepare(
        source, target, source_features, target_features, settings, {}, closed, void_factor, weights
    )
    void_vertex = graph.n_target - 1  # with_void appends it
    solved = _solved(model, graph, curve, settings)
    if solved.x is None:
        logger.warning("the overlap solve ended %s without a matching: %s", solved.status, solved.message)
        return MatchedOverlap(None, dataclasses.replace(solved, x=None), float("nan"))
    in_void = void_layers(graph, solved.x, void_vertex)
    matched_low = matched_curve_vertices(curve.vertices, in_void, low_x.mesh.n_verts)
    region = matched_low[nearest_vertices(source.verts[low_x.to_full], source.verts)]
    logger.info(
        "overlap matched: %.0f %% of the curve in the void, %.0f %% of %s's area matched (%s)",
        100 * in_void.mean(),
        100 * source.vertex_areas[region].sum() / source.area,
        source.name,
        solved.status,
    )
    return MatchedOverlap(region, dataclasses.replace(solved, x=None), float(in_void.mean()))
