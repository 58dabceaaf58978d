"""match(source, target, features, settings): the SpiderMatch pipeline without Hydra.

mesh -> decimation -> SpiderCurve (source) -> product graph -> costs -> ILP -> HiGHS
-> path -> point maps, with an independent check of every solution.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from spidermatch import defaults, shutdown
from spidermatch.dense.densify import densify
from spidermatch.dense.maps import DenseMap, on_given_meshes
from spidermatch.dense.settings import DenseSettings
from spidermatch.eval.quality import assess, covered_share, dense_figures, remarks, with_dense_figures
from spidermatch.geometry.holes import (
    ClosedCopy,
    closed_copy,
    nearest_given_vertices,
    sides_to_close,
)
from spidermatch.geometry.mesh import Mesh, boundary_vertices
from spidermatch.geometry.partial import PairKind, covered_target, mean_edge_length
from spidermatch.geometry.remesh import Decimated, decimate
from spidermatch.model.correspondence import (
    CheckReport,
    MatchingPath,
    SolutionError,
    active_edges,
    canonical_point_map,
    check_solution,
    entries_without_flow,
    extract_path,
)
from spidermatch.model.costs import RobustLoss, feature_cost_matrix, unit_rows
from spidermatch.model.curve import AUTO_TOUR, TOURS, SpiderCurve, spider_curve
from spidermatch.model.ilp import FAMILIES, IlpModel
from spidermatch.model.lazy_model import LazyModel
from spidermatch.model.product_graph import ProductGraph, build_product_graph
from spidermatch.model.void import void_cost, with_void
from spidermatch.model_size import check_model_fits
from spidermatch.solve.isolate import (
    POLL_S,
    StartedProcess,
    can_isolate,
    solve_isolated,
    start_solver_process,
)
from spidermatch.solve.strategies import LAZY_STRATEGIES, solve_with_strategy, strategy_for
from spidermatch.solve.types import SolveResult, SolverOptions, finite_or_none
from spidermatch.validate import check_settings

logger = logging.getLogger(__name__)

# A partial source is decimated to its share of the faces by area, but never below this.
MIN_PARTIAL_FACES = 100


class MatchError(RuntimeError):
    """A match did not produce a certified result; ``exit_code`` is the CLI's exit status."""

    exit_code = 1


class InfeasibleError(MatchError):
    """No geometrically consistent matching exists for this discretisation."""

    exit_code = 3


class NoSolutionError(MatchError):
    """The solver stopped (time limit) before finding any consistent matching."""

    exit_code = 4


class SolverFailure(MatchError):
    """The solver failed or returned a solution that does not pass the checker."""

    exit_code = 5


def default_solver_options() -> SolverOptions:
    """The solver options of ``conf/solver/default.yaml`` (HiGHS's own defaults are for no time limit)."""
    solver = defaults.group("solver/default")
    return SolverOptions(
        time_limit=float(solver["time_limit"]),
        mip_rel_gap=float(solver["mip_rel_gap"]),
        threads=int(solver["threads"]),
        presolve=str(solver["presolve"]),
        log=bool(solver["log"]),
        flow_rows=str(solver["flow_rows"]),
        lp_cuts=bool(solver["lp_cuts"]),
    )


@dataclass(frozen=True)
class MatchSettings:
    """Everything that decides a match, as plain values.

    Attributes
    ----------
    resolution : int
        Target face count of both decimated meshes.
    decimation : str
        "shortest_edge" or "qslim" (see :func:`spidermatch.geometry.remesh.decimate`).
    curve_augmented, target_augmented : bool
        Use augmented edges for the SpiderCurve's graph / the target's product edges.
    curve_seed : int
    curve_matching : str
        Odd-vertex matching of the SpiderCurve's Christofides tour: "greedy" or "blossom".
    curve_tour : str
        "christofides" (the paper's tour), "two_opt" (shortened; fewer self-intersections) or
        "auto" (the first, then the second unless certified or within the requested gap:
        :data:`AUTO_TOUR_SHARE`; without a time limit the first runs to its end).
    loss : RobustLoss
    constraints : tuple of str
        Constraint families to impose (all four by default).
    solver : SolverOptions
    strategy : str
        Solving strategy name (see :mod:`spidermatch.solve.strategies`), or "auto": the
        strategy for learned features (:func:`~spidermatch.solve.strategies.strategy_for`;
        :func:`spidermatch.match` and the command line pass the features' name).
    isolate_solver : bool
        Solve in a child process (:mod:`spidermatch.solve.isolate`): if HiGHS crashes, the
        result has status "error" with the incumbent objective and bound known before.
    dense : DenseSettings or None
        How to extend the certified map to every full-resolution source vertex
        (:mod:`spidermatch.dense.densify`); None: no dense map.
    partial : bool
        The source is a part of the target (:func:`spidermatch.geometry.partial.pair_kind`): its
        lengths are measured in the target's unit (sqrt of the target's area), not its own.
    close_small_holes : bool
        Match whole shapes on copies with their small holes (a scanner's) closed by fans
        (:mod:`spidermatch.geometry.holes`); every map is told on the meshes as given. A part
        (``partial``) is matched as it is, its whole target closed.

    """

    resolution: int = defaults.resolution("files", "learned")
    decimation: str = defaults.option("curve/default", "decimation")
    curve_augmented: bool = bool(defaults.option("curve/default", "augmented"))
    target_augmented: bool = bool(defaults.option("costs/default", "target_augmented"))
    curve_seed: int = int(defaults.option("curve/default", "seed"))
    curve_matching: str = defaults.option("curve/default", "matching")
    curve_tour: str = defaults.option("curve/default", "tour")
    loss: RobustLoss = field(default_factory=RobustLoss)
    constraints: tuple = tuple(defaults.option("costs/default", "constraints"))
    solver: SolverOptions = field(default_factory=default_solver_options)
    strategy: str = defaults.option("solver/default", "strategy")
    isolate_solver: bool = bool(defaults.option("solver/default", "isolate"))
    dense: DenseSettings | None = field(default_factory=DenseSettings)
    partial: bool = False
    close_small_holes: bool = bool(defaults.option("curve/default", "close_small_holes"))


@dataclass(eq=False)
class MatchResult:
    """Everything a match produced.

    Attributes
    ----------
    source, target : Decimated
        Low-resolution meshes (centred) and their maps to the full-resolution vertices.
    curve : SpiderCurve
    graph : ProductGraph
    solve : SolveResult
    path : MatchingPath or None
    low_map : np.ndarray, shape (V_X_low,), or None
        Low-resolution target vertex matched to each low-resolution source vertex.
    check : CheckReport or None
    timings : dict
        Seconds per stage.
    model_size : dict
        ``variables``, ``rows``, ``nonzeros`` of the full ILP as built (before any column is
        dropped or connectivity cut added; ``solve.n_rows`` and ``solve.nnz`` describe the
        last model HiGHS solved instead).
    dense : DenseMap or None
        Image of every full-resolution source vertex (None if turned off or unsolved).
    quality : dict or None
        The verdict on a checked matching without ground truth (:func:`spidermatch.eval.quality.assess`).
    pair : PairKind or None
        How the pair was recognised, when the caller recognised it (the CLI and the API do).
    closed : (ClosedCopy or None, ClosedCopy or None)
        The copies of source and target with their small holes closed that were matched
        (``MatchSettings.close_small_holes``), None for a mesh matched as given. ``source``,
        ``target`` and the curve belong to them; ``to_full``, the pairs and the dense map name
        only the given meshes' vertices.
    tours : list of dict
        With ``curve_tour="auto"``: each SpiderCurve tour tried, its status, objective, bound,
        gap and solve time, and which was kept (``curve`` and ``solve`` are that tour's).
        Empty otherwise.
    second_opinion : dict or None
        When the map was judged suspect and matched again with a second opinion's features
        (:func:`kept_opinion`): which map was kept and each one's status, gap and verdict.
    overlap_found : dict or None
        With ``partial="both"``: how the matched source piece was found
        (:func:`spidermatch.api.source_overlap_piece`'s record).

    """

    source: Decimated
    target: Decimated
    curve: SpiderCurve
    graph: ProductGraph
    solve: SolveResult
    path: MatchingPath | None = None
    low_map: np.ndarray | None = None
    check: CheckReport | None = None
    timings: dict = field(default_factory=dict)
    model_size: dict = field(default_factory=dict)
    dense: DenseMap | None = None
    quality: dict | None = None
    pair: PairKind | None = None
    closed: tuple = (None, None)
    tours: list = field(default_factory=list)
    second_opinion: dict | None = None
    overlap_found: dict | None = None

    @property
    def dense_map(self) -> np.ndarray | None:
        """Target vertex (full resolution) of every original source vertex, (V_X,), or None."""
        return None if self.dense is None else self.dense.vertex

    @property
    def full_pairs(self) -> np.ndarray:
        """(source, target) full-resolution vertex indices, one row per low-res source vertex."""
        if self.low_map is None:
            raise MatchError("no matching: " + self.solve.status)
        return np.stack([self.source.to_full, self.target.to_full[self.low_map]], axis=1)

    def raise_for_status(self, hint: str = "") -> None:
        """Raise the :class:`MatchError` subclass matching a failed solve or check.

        ``hint``: a clause the caller knows more about (e.g. features unfit for the pair), added to
        the message of a run without a matching ("" for none).
        """
        status = self.solve.status
        if status == "infeasible":
            raise InfeasibleError(
                "no geometrically consistent matching exists for this discretisation "
                f"({self.graph.n_layers} curve positions x {self.graph.n_target} target vertices; the ILP "
                "is infeasible): try a higher resolution or another curve seed"
            )
        if status == "no_solution":
            remedy = (
                "give the run more memory"  # more time would not help
                if self.solve.out_of_memory
                else "raise solver.time_limit"
            )
            raise NoSolutionError(
                f"the solver stopped without any solution after {self.solve.wall_time:.0f} s"
                f"{why_no_solution(self.solve.message)}: {remedy}, or match at a lower resolution "
                f"(this run: {self.graph.n_layers} curve positions x {self.graph.n_target} target vertices; "
                f"the solver said: {self.solve.message})" + (f"; {hint}" if hint else "")
            )
        if status == "error" or self.low_map is None:
            raise SolverFailure(f"the solver failed: {self.solve.message}")
        if self.check is not None and not self.check.ok:
            raise SolverFailure("the solution fails the independent check: " + "; ".join(self.check.problems))


def why_no_solution(solver_message: str) -> str:
    """What a solver's message of a run without a solution means for the user ("" if nothing to add)."""
    if "detached cycles" in solver_message:
        return (
            ": the cheapest matchings it found laid the source's curve onto the target as several "
            "separate loops, not one closed path, and no single closed path was found in the time left"
        )
    if "LP relaxation not solved" in solver_message:
        return (
            ": it did not finish even the relaxation that bounds the cost from below; this happens at a "
            "resolution too high for the time, and on shapes with many symmetries (a sphere, a cylinder), "
            "where many matchings cost the same and the features cannot tell the vertices apart"
        )
    return ""


@contextmanager
def _stage(timings: dict, name: str):
    logger.info("%s ...", name)
    start = time.perf_counter()
    yield
    seconds = time.perf_counter() - start
    timings[name] = timings.get(name, 0.0) + seconds  # a stage run again (two tours) adds up
    logger.info("%s done in %.2f s", name, seconds)


def source_resolution(source: Mesh, target: Mesh, settings: MatchSettings) -> int:
    """Faces of the source's low-resolution mesh (its share by area for a partial source).

    ``settings.resolution`` for a whole source. A partial source gets its share of it by
    area, so that part and whole get edges of one length: at equal face counts a part of
    half the whole's area would get edges 0.7 times the whole's, and several of its vertices
    would have to share each target vertex.
    """
    if not settings.partial:
        return settings.resolution
    share = min(1.0, source.area / target.area)
    return max(MIN_PARTIAL_FACES, round(settings.resolution * share))


def low_resolution_features(features: np.ndarray, to_full: np.ndarray) -> np.ndarray:
    """Rows of full-resolution features (V, D) at the low-res vertices, L2-normalised."""
    return unit_rows(np.asarray(features)[to_full])


def strategy_resolved(settings: MatchSettings) -> MatchSettings:
    """``settings`` with ``strategy="auto"`` replaced by a strategy: the one for features other than WKS."""
    return dataclasses.replace(settings, strategy=strategy_for(settings.strategy, "precomputed"))


def prepare(
    source: Mesh,
    target: Mesh,
    source_features: np.ndarray,
    target_features: np.ndarray,
    settings: MatchSettings,
    timings: dict,
    closed: tuple | None = None,
    void_factor: float | None = None,
    void_weights: np.ndarray | None = None,
) -> tuple[Decimated, Decimated, SpiderCurve, ProductGraph, IlpModel | LazyModel]:
    """Decimate, trace the curve, build the product graph, the costs and the ILP.

    For a strategy in ``LAZY_STRATEGIES`` the ILP is a :class:`LazyModel` (feature costs only;
    columns are built by the strategy); otherwise the full :class:`IlpModel`. ``closed``: the
    meshes' copies with small holes closed (:func:`closed_copies`, computed when not given);
    a mesh that has one is matched on it, its decimated vertices mapped to given vertices only.
    ``void_factor``: the target graph gets a void vertex (:mod:`spidermatch.model.void`) of
    that cost factor, index ``low_y.mesh.n_verts``; None: the plain target. ``void_weights``
    (V_X,): per source vertex, a multiplier of the void's cost (None: 1 everywhere).
    """
    settings = strategy_resolved(settings)
    _check_features(source, source_features, "source")
    _check_features(target, target_features, "target")
    check_model_fits(
        (source.n_faces, target.n_faces), settings.resolution, settings.strategy, settings.target_augmented
    )
    closed = closed_copies(source, target, settings) if closed is None else closed
    source, target = matched_meshes((source, target), closed)
    source_scale = length_scale(target if settings.partial else source)
    logger.info(
        "lengths in %s: source area %.6g, target area %.6g",
        "the target's sqrt(area) (partial source)" if settings.partial else "each mesh's sqrt(area)",
        source.area,
        target.area,
    )
    with _stage(timings, "decimate"):
        low_x = decimate(source.centred(), source_resolution(source, target, settings), settings.decimation)
        low_y = decimate(target.centred(), settings.resolution, settings.decimation)
        low_x, low_y = (given_vertices_only(low, copy) for low, copy in zip((low_x, low_y), closed))
    with _stage(timings, "curve"):
        curve = spider_curve(
            low_x.mesh,
            settings.curve_augmented,
            settings.curve_seed,
            settings.curve_matching,
            settings.curve_tour,
        )
    with _stage(timings, "costs"):
        edges_y = low_y.mesh.augmented_edges if settings.target_augmented else low_y.mesh.edges
        vertex_costs = feature_cost_matrix(
            low_resolution_features(source_features, low_x.to_full),
            low_resolution_features(target_features, low_y.to_full),
            settings.loss,
        )
        target_verts, crossing, void = low_y.mesh.verts * length_scale(target), None, None
        if void_factor is not None:
            cost = void_cost(vertex_costs, void_factor)
            logger.info(
                "void vertex: cost %.4g (%.3g x the median cheapest)%s",
                cost,
                void_factor,
                "" if void_weights is None else ", weighted per source vertex",
            )
            if void_weights is not None:
                cost = cost * np.asarray(void_weights, dtype=np.float64)[low_x.to_full]
            augmented = with_void(target_verts, boundary_vertices(low_y.mesh.faces), vertex_costs, cost)
            target_verts, vertex_costs = augmented.verts, augmented.vertex_costs
            crossing, void = augmented.crossing_edges, augmented.void
        graph = build_product_graph(curve.length, target_verts.shape[0], edges_y, crossing)
        lazy = LazyModel(
            graph,
            curve,
            low_x.mesh.verts * source_scale,
            target_verts,
            vertex_costs,
            tuple(settings.constraints),
            void,
        )
        if settings.strategy in LAZY_STRATEGIES:  # the full model is never built
            logger.info(
                "problem: curve length %d, %d columns, %d rows", curve.length, lazy.n_vars, lazy.n_rows
            )
            return low_x, low_y, curve, graph, lazy
    with _stage(timings, "build"):  # costs and matrix block by block (equal to build_model's)
        model = lazy.full_model()
    logger.info(
        "problem: %d source / %d target vertices, curve length %d; "
        "full model: %d variables, %d rows, %d non-zeros",
        low_x.mesh.n_verts,
        low_y.mesh.n_verts,
        curve.length,
        model.n_vars,
        model.n_rows,
        model.nnz,
    )
    return low_x, low_y, curve, graph, model


def closed_copies(source: Mesh, target: Mesh, settings: MatchSettings) -> tuple:
    """Copies of source and target with their small holes closed (ClosedCopy or None each).

    A part (``settings.partial``) keeps its holes; so does its target unless that is closed
    but for small holes (a whole shape, not another part). (None, None) with
    ``settings.close_small_holes`` off.
    """
    if not settings.close_small_holes:
        return None, None
    sides = sides_to_close(target, settings.partial)
    closed = tuple(closed_copy(mesh) if close else None for mesh, close in zip((source, target), sides))
    for mesh, copy in zip((source, target), closed):
        if copy is not None:
            logger.info(
                "%s: matched with its %d small hole(s) closed", mesh.name, copy.mesh.n_verts - copy.n_verts
            )
    return closed


def matched_meshes(meshes: tuple, closed: tuple) -> tuple:
    """The meshes a match runs on: each given mesh, or its copy with small holes closed."""
    return tuple(mesh if copy is None else copy.mesh for mesh, copy in zip(meshes, closed))


def given_vertices_only(low: Decimated, copy: ClosedCopy | None) -> Decimated:
    """``low`` (a decimated closed copy) with each vertex mapped to a vertex of the given mesh."""
    if copy is None:
        return low
    full = copy.mesh.centred()
    return Decimated(low.mesh, nearest_given_vertices(low.to_full, low.mesh.verts, copy, full))


def length_scale(mesh: Mesh) -> float:
    """The factor that brings ``mesh`` to unit surface area (1 / sqrt(area)).

    Product-edge costs add the step lengths of both meshes (method.md 4): measured in
    each mesh's own sqrt(area), a pair in any units (a target in millimetres against a
    source in metres) gets the costs, and so the matching, of the pair in one unit.
    """
    return 1.0 / float(np.sqrt(mesh.area))


def _check_features(mesh: Mesh, features: np.ndarray, role: str) -> None:
    features = np.asarray(features)
    if features.ndim != 2 or features.shape[0] != mesh.n_verts:
        raise ValueError(
            f"{role} features must have shape ({mesh.n_verts}, D) for {mesh.name}, got {features.shape}"
        )
    if not np.isfinite(features).all():
        raise ValueError(f"{role} features of {mesh.name} contain NaN or infinite values")
    highest, lowest = features.max(axis=0), features.min(axis=0)  # rows: at least one vertex
    spread = float((highest - lowest).max(initial=0.0))  # per-column reductions: no (V, D) temporary
    if spread <= 1e-12 * float(np.maximum(np.abs(highest), np.abs(lowest)).max(initial=0.0)):
        raise ValueError(
            f"{role} features of {mesh.name} are the same at every vertex: they tell no vertex from "
            "another, so every matching would cost the same (check how they were computed)"
        )


def match(
    source: Mesh,
    target: Mesh,
    source_features: np.ndarray,
    target_features: np.ndarray,
    settings: MatchSettings | None = None,
    announce_quality: bool = True,
) -> MatchResult:
    """Globally optimal, geometrically consistent matching of ``source`` to ``target``.

    Parameters
    ----------
    source, target : Mesh
        Full-resolution meshes (V_X and V_Y vertices).
    source_features : np.ndarray, shape (V_X, D)
    target_features : np.ndarray, shape (V_Y, D)
        Per-vertex descriptors on the full-resolution meshes.
    settings : MatchSettings
    announce_quality : bool
        Log the quality verdict. False for a caller that makes the dense map itself
        (:func:`add_dense_map` judges the map again and logs the verdict).

    Returns
    -------
    MatchResult
        Always returned; call :meth:`MatchResult.raise_for_status` to turn an
        infeasible, unsolved or unchecked result into an exception.

    """
    settings = strategy_resolved(settings or MatchSettings())
    check_settings(settings)
    timings: dict = {}
    closed = closed_copies(source, target, settings)
    features = (source_features, target_features)
    if settings.curve_tour == AUTO_TOUR and side_by_side_threads(settings):
        attempt, tours = _solved_with_tours_side_by_side(source, target, features, settings, timings, closed)
    elif settings.curve_tour == AUTO_TOUR:
        attempt, tours = _solved_with_tours_in_turn(source, target, features, settings, timings, closed)
    else:
        attempt, tours = _prepared_and_solved(source, target, features, settings, timings, closed), []
    low_x, low_y, curve, graph, model_size, solved = attempt
    result = MatchResult(low_x, low_y, curve, graph, solved, timings=timings, closed=closed, tours=tours)
    result.model_size = model_size
    if solved.x is not None:
        with _stage(timings, "check"):
            _read_solution(result, tuple(settings.constraints))
    if result.low_map is not None:
        result.quality = assess(low_x.mesh, low_y.mesh, result.low_map, solved.gap)
    if settings.dense is not None:  # it logs the verdict, judged again with the dense map
        add_dense_map(
            result, source, target, (source_features, target_features), settings.dense, settings.partial
        )
    elif announce_quality and result.quality is not None:
        _log_quality(result.quality)
    return result


AUTO_TOUR_SHARE = 0.4
"""With ``curve_tour="auto"``: the share of the solver's time limit that the paper's tour
(the first of :data:`~spidermatch.model.curve.TOURS`) gets; the shortened tour gets the rest."""

MIN_SECOND_TOUR_S = 10.0
"""The least time left for which ``curve_tour="auto"`` still tries the second tour."""

OVERLAP_SOLVE_SHARE = 0.5
"""``partial="both"`` with the overlap matched (:mod:`spidermatch.overlap_solve`): the share of the
solver's time limit the overlap's solve may take; the solve of the piece it finds gets the rest."""


def solver_time_left(settings: MatchSettings, used_s: float) -> MatchSettings:
    """``settings`` whose solver may take what the run's earlier solves left of its time limit.

    ``solver.time_limit`` bounds the solves of one matching together (the overlap's and the
    piece's of ``partial="both"``), as it bounds both tours of ``curve_tour="auto"``. No limit
    stays no limit. (A second opinion is a second matching: it gets the whole limit again.)

    Parameters
    ----------
    settings : MatchSettings
    used_s : float
        Seconds the run's earlier solves took.
    """
    limit = settings.solver.time_limit
    if not math.isfinite(limit):
        return settings
    solver = dataclasses.replace(settings.solver, time_limit=max(limit - used_s, 0.0))
    return dataclasses.replace(settings, solver=solver)


def overlap_solve_settings(settings: MatchSettings) -> MatchSettings:
    """``settings`` for the overlap's solve: :data:`OVERLAP_SOLVE_SHARE` of the solver's time limit."""
    return solver_time_left(settings, (1.0 - OVERLAP_SOLVE_SHARE) * settings.solver.time_limit)


def _prepared_and_solved(
    source: Mesh, target: Mesh, features: tuple, settings: MatchSettings, timings: dict, closed: tuple
) -> tuple:
    """:func:`prepare` and solve with ``settings.curve_tour``.

    Returns (low_x, low_y, curve, graph, model_size, solved); ``model_size`` (the ILP's
    ``variables``, ``rows`` and ``nonzeros``) stands for the model, which is let go after the solve.
    """
    low_x, low_y, curve, graph, model = prepare(source, target, *features, settings, timings, closed)
    with _stage(timings, "solve"):
        solved = _solved(model, graph, curve, settings)
    return low_x, low_y, curve, graph, _model_size(model), solved


def _solved(
    model,
    graph,
    curve,
    settings: MatchSettings,
    cancel: threading.Event | None = None,
    started: StartedProcess | None = None,
) -> SolveResult:
    """The solve of a prepared model with ``settings``' strategy (isolated if asked), logged.

    ``cancel``, ``started``: see :func:`~spidermatch.solve.isolate.solve_isolated` (isolated
    solves only).
    """
    solve = _solve_function(settings)
    if settings.isolate_solver:
        solved = solve_isolated(solve, model, graph, curve, settings.solver, cancel=cancel, started=started)
    else:
        solved = solve(model, graph, curve, settings.solver)
    solved = within_optimal_gap(solved)
    logger.info(
        "solver (%s tour): %s, objective %.6g, bound %.6g, gap %.2e",
        settings.curve_tour,
        solved.status,
        solved.objective,
        solved.bound,
        solved.gap,
    )
    return solved


def _solve_function(settings: MatchSettings):
    """``solve(model, graph, curve, options)`` with ``settings``' strategy."""
    return partial(solve_with_strategy, settings.strategy)


def _model_size(model) -> dict:
    """The ILP's ``variables``, ``rows`` and ``nonzeros`` (None for a LazyModel, which never builds them)."""
    nonzeros = getattr(model, "nnz", None)
    return {"variables": model.n_vars, "rows": model.n_rows, "nonzeros": nonzeros}


def _solved_with_tours_in_turn(
    source: Mesh, target: Mesh, features: tuple, settings: MatchSettings, timings: dict, closed: tuple
) -> tuple[tuple, list[dict]]:
    """``curve_tour="auto"``: the paper's SpiderCurve, then, unless certified, the shortened one.

    The paper's tour gets :data:`AUTO_TOUR_SHARE` of the time limit (all of it when the rest
    would be under :data:`MIN_SECOND_TOUR_S`, or without a limit); unless its solve ends
    certified or within the requested gap, the 2-opt tour is solved in the time the first left.
    Each is a matching problem of its own (another curve, so other objective values): the
    result is the certified one, else the one with the smaller gap (a matching before none).
    A second tour that fails (an exception) leaves the first's result.

    Returns
    -------
    attempt : tuple
        (low_x, low_y, curve, graph, model_size, solved) of the chosen tour.
    tours : list of dict
        Per tour tried (:func:`_tour_records`): ``tour``, ``status``, ``objective``, ``bound``,
        ``gap``, ``solve_s``, ``chosen``, ``side_by_side`` (false here) and ``message``.
    """
    limit = settings.solver.time_limit
    first_limit = _first_tour_limit(limit)
    attempts = [_tour_attempt(source, target, features, settings, timings, closed, TOURS[0], first_limit)]
    first = attempts[0][-1]
    ranks, held = [_tour_rank(first)], None
    left = limit - first.wall_time
    if not _tour_settled(first, settings.solver.mip_rel_gap) and left >= MIN_SECOND_TOUR_S:
        message = "the %s tour ended %s: trying the %s tour in the %.0f s left"
        logger.info(message, TOURS[0], first.status, TOURS[1], left)
        # the first solution's entry per column (8 bytes each: 0.5 GB at 4000 faces) is let go meanwhile
        held = _solution_support(first.x)
        first = dataclasses.replace(first, x=None)
        attempts[0] = (*attempts[0][:-1], first)
        try:
            second = _tour_attempt(source, target, features, settings, timings, closed, TOURS[1], left)
            attempts.append(second)
            ranks.append(_tour_rank(second[-1]))
        except Exception as error:  # e.g. out of memory building the second tour: the first stands
            logger.warning("the %s tour failed (%s): the %s tour's result stands", TOURS[1], error, TOURS[0])
            logger.debug("second tour", exc_info=True)
    chosen = min(range(len(attempts)), key=ranks.__getitem__)
    if chosen == 0 and held is not None:
        attempts[0] = (*attempts[0][:-1], dataclasses.replace(first, x=_solution_from_support(held)))
    tours = _tour_records([solved for *_, solved in attempts], chosen, side_by_side=False)
    if len(attempts) > 1:
        logger.info("the %s tour's result is kept (%s)", TOURS[chosen], attempts[chosen][-1].status)
    return attempts[chosen], tours


def _tour_records(solves: list[SolveResult], chosen: int, side_by_side: bool) -> list[dict]:
    """``result.json["curve_tours"]``: per tour tried, its outcome and whether it was kept."""
    return [
        {
            "tour": TOURS[k],
            "status": solved.status,
            "objective": finite_or_none(solved.objective),
            "bound": finite_or_none(solved.bound),
            "gap": finite_or_none(solved.gap),
            "solve_s": round(solved.wall_time, 3),
            "chosen": k == chosen,
            "side_by_side": side_by_side,
            "message": solved.message,
        }
        for k, solved in enumerate(solves)
    ]


def usable_cores() -> int:
    """Cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def side_by_side_threads(settings: MatchSettings) -> int:
    """HiGHS threads for each of ``curve_tour="auto"``'s two tours solved side by side; 0: in turn.

    Side by side needs two solver processes (``isolate_solver`` on a platform that forks) and
    at least two cores for the solve: ``solver.threads``, or the cores this process may use when
    it is 0 (HiGHS's choice). Each tour gets half of them; ``solver.threads=1`` solves in turn.
    """
    if not (settings.isolate_solver and can_isolate()):
        return 0
    cores = settings.solver.threads or usable_cores()
    return cores // len(TOURS)


def _solved_with_tours_side_by_side(
    source: Mesh, target: Mesh, features: tuple, settings: MatchSettings, timings: dict, closed: tuple
) -> tuple[tuple, list[dict]]:
    """``curve_tour="auto"`` on two cores or more: both tours solved at once, each with the whole limit.

    Both tours are prepared here, then solved in two solver processes side by side (each with
    :func:`side_by_side_threads` HiGHS threads and half the memory its MIP checks count on).
    When one ends certified or within the requested gap, the other is stopped
    (:data:`~spidermatch.solve.isolate.CANCELLED`) and returns the best closed path it had.
    The result is chosen as in :func:`_solved_with_tours_in_turn`. Which of two tours that
    would both be certified is returned can depend on which finishes first.
    A second tour whose preparation fails leaves the first solved alone.

    Returns
    -------
    As :func:`_solved_with_tours_in_turn`; each ``tours`` record has ``side_by_side`` true.
    """
    threads = side_by_side_threads(settings)
    solver = dataclasses.replace(
        settings.solver, threads=threads, memory_share=settings.solver.memory_share / len(TOURS)
    )
    tried = [dataclasses.replace(settings, curve_tour=tour, solver=solver) for tour in TOURS]
    prepared = [prepare(source, target, *features, tried[0], timings, closed)]
    try:
        prepared.append(prepare(source, target, *features, tried[1], timings, closed))
    except Exception as error:  # e.g. out of memory: the first tour alone, as asked of a single tour
        logger.warning("the %s tour could not be prepared (%s): the %s tour alone", TOURS[1], error, TOURS[0])
        logger.debug("second tour", exc_info=True)
        low_x, low_y, curve, graph, model = prepared[0]
        with _stage(timings, "solve"):
            solved = _solved(model, graph, curve, dataclasses.replace(settings, curve_tour=TOURS[0]))
        return (low_x, low_y, curve, graph, _model_size(model), solved), _tour_records([solved], 0, False)
    logger.info(
        "solving the %s and %s tours side by side (HiGHS on %d thread%s each)",
        *TOURS, threads, "" if threads == 1 else "s",
    )  # fmt: skip
    with _stage(timings, "solve"):
        solves = _solved_at_once(prepared, tried)
    ranks = [_tour_rank(solved) for solved in solves]
    chosen = min(range(len(solves)), key=ranks.__getitem__)
    logger.info("the %s tour's result is kept (%s)", TOURS[chosen], solves[chosen].status)
    low_x, low_y, curve, graph, model = prepared[chosen]
    attempt = (low_x, low_y, curve, graph, _model_size(model), solves[chosen])
    return attempt, _tour_records(solves, chosen, side_by_side=True)


def _solved_at_once(prepared: list[tuple], tried: list[MatchSettings]) -> list[SolveResult]:
    """Each prepared tour solved in a solver process of its own, all at once.

    The processes are forked here, on this thread (:func:`~spidermatch.solve.isolate.start_solver_process`),
    then each is watched by a thread of its own; once one is settled (:func:`_tour_settled`)
    the others are stopped. A solve that raised counts as failed (status ``"error"``) while
    another has a result; an interrupt (:class:`~spidermatch.shutdown.RunInterrupted`), or every
    solve raising, is re-raised. Whatever stops this thread stops every solver process first.
    """
    cancel = threading.Event()
    outcomes: list = [None] * len(prepared)
    started = []

    def run(k: int) -> None:
        low_x, low_y, curve, graph, model = prepared[k]
        try:
            outcomes[k] = _solved(model, graph, curve, tried[k], cancel, started[k])
        except BaseException as error:  # noqa: BLE001 - handed to the main thread
            outcomes[k] = error
        if isinstance(outcomes[k], SolveResult) and _tour_settled(outcomes[k], tried[k].solver.mip_rel_gap):
            cancel.set()

    workers = [threading.Thread(target=run, args=(k,), name=f"solve-{tour}") for k, tour in enumerate(TOURS)]
    with shutdown.native_call():  # a signal is only recorded here: each worker forwards it to its process
        try:
            for (*_, curve, graph, model), settings in zip(prepared, tried):
                solve = _solve_function(settings)
                started.append(start_solver_process(solve, model, graph, curve, settings.solver))
            for worker in workers:
                worker.start()
            for worker in workers:
                while worker.is_alive():
                    worker.join(POLL_S)
        except BaseException:  # e.g. KeyboardInterrupt without spidermatch's handler: no orphan solves
            cancel.set()
            for worker in workers:
                if worker.is_alive():
                    worker.join()
            for process in started[sum(worker.ident is not None for worker in workers) :]:
                process.discard()  # forked, never watched
            raise
    shutdown.raise_if_stopped()  # a signal after the solves ended, before the block did
    return _outcomes_or_raise(outcomes, prepared)


def _first_tour_limit(limit: float) -> float:
    """The paper's tour's share of ``limit``: all of it when the rest would be too short to use."""
    if not math.isfinite(limit) or (1 - AUTO_TOUR_SHARE) * limit < MIN_SECOND_TOUR_S:
        return limit
    return AUTO_TOUR_SHARE * limit


def _gap_known(stop: shutdown.RunInterrupted) -> float:
    """The relative gap an interrupted solve knew (inf: none)."""
    gap = (stop.known or {}).get("gap")
    return math.inf if gap is None else float(gap)


def _tour_settled(solved: SolveResult, mip_rel_gap: float) -> bool:
    """Whether a tour's result leaves the other tour nothing to do.

    When it is certified or within the requested gap (a loose ``mip_rel_gap`` turns a
    result within it into "feasible", :func:`within_optimal_gap`). An infeasible tour is not
    settled: infeasibility is the discretisation's, and another curve is another one.
    """
    if solved.status == "optimal":
        return True
    return solved.x is not None and math.isfinite(solved.gap) and solved.gap <= mip_rel_gap


def _outcomes_or_raise(outcomes: list, prepared: list[tuple]) -> list[SolveResult]:
    """:func:`_solved_at_once`'s outcomes as results; an exception becomes status "error" or is raised."""
    interrupts = [
        (k, outcome) for k, outcome in enumerate(outcomes) if isinstance(outcome, shutdown.RunInterrupted)
    ]
    if interrupts:  # the figures of the tour nearest to certified (two problems: gaps, not costs), named
        k, stop = min(interrupts, key=lambda item: _gap_known(item[1]))
        stop.known = {**stop.known, "curve_tour": TOURS[k]}
        raise stop
    if all(isinstance(outcome, BaseException) for outcome in outcomes):
        raise outcomes[0]
    results = []
    for k, outcome in enumerate(outcomes):
        if isinstance(outcome, BaseException):
            logger.warning("the %s tour's solve failed (%s)", TOURS[k], outcome)
            model = prepared[k][-1]
            outcome = SolveResult(
                "error", None, math.inf, -math.inf, math.nan, 0.0, model.n_vars, model.n_rows, 0,
                f"the solve raised {type(outcome).__name__}: {outcome}",
            )  # fmt: skip
        results.append(outcome)
    return results


def _tour_attempt(
    source: Mesh,
    target: Mesh,
    features: tuple,
    settings: MatchSettings,
    timings: dict,
    closed: tuple,
    tour: str,
    time_limit: float,
) -> tuple:
    """One tour of ``curve_tour="auto"``: :func:`_prepared_and_solved` with that tour and time limit."""
    solver = dataclasses.replace(settings.solver, time_limit=time_limit)
    tried = dataclasses.replace(settings, curve_tour=tour, solver=solver)
    return _prepared_and_solved(source, target, features, tried, timings, closed)


def _solution_support(x: np.ndarray | None) -> tuple | None:
    """A solution vector (n,) as its length and nonzero entries, (n, indices, values); None for none."""
    if x is None:
        return None
    support = np.flatnonzero(x)
    return x.size, support, x[support]


def _solution_from_support(held: tuple | None) -> np.ndarray | None:
    """The solution vector (n,) that :func:`_solution_support` held."""
    if held is None:
        return None
    size, support, values = held
    x = np.zeros(size)
    x[support] = values
    return x


def _tour_rank(solved: SolveResult) -> tuple:
    """Sort key of a tour's result: certified first, then with a matching, then by gap."""
    gap = solved.gap if math.isfinite(solved.gap) else math.inf
    return (solved.status != "optimal", solved.x is None, gap)


def needs_second_opinion(result: MatchResult) -> bool:
    """True when ``result`` has a matching its quality verdict calls suspect.

    Called after :func:`add_dense_map` when there is a dense map: the verdict is then the one
    confirmed by the dense map (:func:`spidermatch.eval.quality.with_dense_figures`).
    """
    verdict = None if result.quality is None else result.quality["verdict"]
    return result.low_map is not None and verdict == "suspect"


def joined_features(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Two descriptors of the same vertices side by side: each row the two unit rows over sqrt(2).

    The similarity of two joined rows is the mean of the two descriptors' similarities (as
    :class:`features.learned.EnsembleExtractor` joins networks), and the rows stay unit-norm.

    Parameters
    ----------
    first : np.ndarray, shape (V, D1)
    second : np.ndarray, shape (V, D2)

    Returns
    -------
    np.ndarray, shape (V, D1 + D2)
    """
    if len(first) != len(second):
        raise ValueError(f"the second opinion's features have {len(second)} rows for {len(first)} vertices")
    return np.hstack([unit_rows(first), unit_rows(second)]) / np.sqrt(2.0)


def matched_with_second_opinion(
    first: MatchResult,
    source: Mesh,
    target: Mesh,
    features: tuple,
    second_features: tuple,
    settings: MatchSettings,
) -> tuple[MatchResult, tuple]:
    """Ask a second opinion about ``first`` (judged suspect): the pair matched again, the map to keep.

    The pair is matched (:func:`match`, with ``settings.dense``) with each mesh's ``features``
    and ``second_features`` joined (:func:`joined_features`); :func:`kept_opinion` chooses.

    Parameters
    ----------
    first : MatchResult
        The map judged suspect, of ``source`` to ``target``.
    source, target : Mesh
        The meshes ``first`` matched.
    features, second_features : tuple of np.ndarray
        (V_X, D1) and (V_Y, D1) the first map's features; (V_X, D2) and (V_Y, D2) the second opinion's.
    settings : MatchSettings

    Returns
    -------
    kept : MatchResult
        ``first`` or the second map, its ``second_opinion`` filled in.
    joined : tuple of np.ndarray
        The joined features, (V_X, D1 + D2) and (V_Y, D1 + D2).
    """
    joined = tuple(joined_features(a, b) for a, b in zip(features, second_features))
    return kept_opinion(first, match(source, target, *joined, settings)), joined


def kept_opinion(first: MatchResult, second: MatchResult) -> MatchResult:
    """The map to keep after a second opinion: ``second`` if it is judged plausible, else ``first``.

    A second map judged suspect too, or without a checked matching, leaves the first map,
    which gets ``second_opinion`` all the same (what was tried, for ``result.json``).

    Parameters
    ----------
    first : MatchResult
        The map judged suspect.
    second : MatchResult
        The same pair matched with the second opinion's features.

    Returns
    -------
    MatchResult
        The kept one, its ``second_opinion`` filled in.
    """
    checked = second.low_map is not None and (second.check is None or second.check.ok)
    plausible = checked and second.quality is not None and second.quality["verdict"] == "plausible"
    kept = second if plausible else first
    kept.second_opinion = {
        "kept": "second" if plausible else "first",
        "first": _opinion(first),
        "second": _opinion(second),
    }
    logger.info(
        "second opinion: %s (its verdict: %s); the %s map is kept",
        second.solve.status,
        "none" if second.quality is None else second.quality["verdict"],
        kept.second_opinion["kept"],
    )
    return kept


def _opinion(result: MatchResult) -> dict:
    """Status, objective, gap and verdict of one map of a second opinion, JSON-ready."""
    quality = result.quality or {}
    return {
        "status": result.solve.status,
        "objective": finite_or_none(result.solve.objective),
        "gap": finite_or_none(result.solve.gap),
        "verdict": quality.get("verdict"),
        "reasons": list(quality.get("reasons", [])),
    }


def _log_quality(quality: dict) -> None:
    log = logger.warning if quality["verdict"] == "suspect" else logger.info
    log("quality: %s%s", quality["verdict"], "".join(f"; {r}" for r in remarks(quality)))


def _judged_with_dense_map(
    result: MatchResult, source: Mesh, target: Mesh, dense: DenseMap, covered_area: float | None = None
) -> None:
    """``result.quality`` judged again with the figures of ``dense`` (``source`` to ``target``), and logged.

    ``covered_area``: a partial map's covered target area over the source's
    (:func:`spidermatch.eval.quality.covered_share`).

    Should those figures fail (they compute geodesics on both meshes), the certified map's
    verdict stands, said in the log.
    """
    if result.quality is None:
        return
    before = result.quality
    try:
        figures = dense_figures(source, target, dense, covered_area)
    except Exception as error:  # an extra figure must not cost the matching
        logger.warning(
            "the dense map's quality figures failed (%s): the certified map's verdict stands", error
        )
        logger.debug("dense figures", exc_info=True)
        _log_quality(before)
        return
    result.quality = with_dense_figures(before, figures)
    quality = result.quality
    if len(quality["reasons"]) < len(before["reasons"]):  # a symptom the dense map does not show
        distortion = quality["dense_distortion"]
        logger.info(
            "the certified map looked %s (%s); its dense map does not: %.0f%% of its triangles face against "
            "the target, %s of its sampled distances change by more than half (decimation noise)",
            before["verdict"],
            "; ".join(before["reasons"]),
            100 * quality["dense_mirror"],
            "n/a" if distortion is None else f"{distortion:.0%}",
        )
    _log_quality(quality)


OPTIMAL_GAP = 1e-3
"""The largest relative gap a result may have and still be called "optimal" (the default
``mip_rel_gap`` is 1e-4): a larger requested gap yields "feasible", within the requested gap."""

OPTIMAL_ABSOLUTE_GAP = 1e-6
"""An objective within this of its bound is optimal whatever the relative gap (costs near 0)."""


def within_optimal_gap(solved: SolveResult) -> SolveResult:
    """``solved``, with "optimal" turned into "feasible" when its gap exceeds :data:`OPTIMAL_GAP`.

    HiGHS calls a solution optimal once it is within the requested ``mip_rel_gap``; a
    reader of "optimal" expects no matching to be noticeably cheaper, so a looser
    requested gap (e.g. 0.9) gives "feasible" with a message that says so.
    """
    if solved.status != "optimal" or not math.isfinite(solved.gap) or solved.gap <= OPTIMAL_GAP:
        return solved
    if solved.objective - solved.bound <= OPTIMAL_ABSOLUTE_GAP:
        return solved
    message = (
        f"{solved.message}; within the requested gap, but its gap {solved.gap:.2e} is above {OPTIMAL_GAP:g}: "
        "not proven optimal"
    )
    logger.warning("%s", message)
    return dataclasses.replace(solved, status="feasible", message=message)


def add_dense_map(
    result: MatchResult,
    source: Mesh,
    target: Mesh,
    features: tuple,
    settings: DenseSettings,
    partial: bool = False,
) -> None:
    """Set ``result.dense``: the image of every full-resolution source vertex (a checked matching only).

    For a partial source the map also says which target vertices it covers (``covered``,
    :func:`spidermatch.geometry.partial.covered_target`). ``result.quality`` is judged again
    with the dense map's figures (:func:`spidermatch.eval.quality.with_dense_figures`).

    Parameters
    ----------
    result : MatchResult
        A finished match of ``source`` to ``target``; left as it is without a checked matching.
    source, target : Mesh
        The full-resolution meshes the match was run on.
    features : (np.ndarray (V_X, D), np.ndarray (V_Y, D))
    settings : DenseSettings
    partial : bool
        The source is a part of the target.

    """
    if result.low_map is None or result.check is None or not result.check.ok:
        if result.quality is not None:
            _log_quality(result.quality)
        return
    with _stage(result.timings, "dense"):
        matched = matched_meshes((source, target), result.closed)
        matched_features = [
            rows if copy is None else np.vstack([rows, unit_rows(copy.rim_means(rows))])
            for rows, copy in zip(features, result.closed)
        ]
        dense = densify(
            matched[0].centred(),
            matched[1].centred(),
            result.source,
            result.target,
            result.low_map,
            *matched_features,
            settings.for_part() if partial else settings,
            rest_scale=1.0 if partial else None,  # a part is measured in the target's unit
        )
        result.dense = on_given_meshes(dense, *result.closed)
        if partial:
            whole = target.centred()
            covered = covered_target(whole, result.dense.face, result.dense.bary, mean_edge_length(source))
            result.dense = dataclasses.replace(result.dense, covered=covered)
    covered = result.dense.covered
    covered_area = None if covered is None else covered_share(source, target, covered)
    # judged on the meshes matched (small holes closed)
    _judged_with_dense_map(result, *matched, dense, covered_area)


def _read_solution(result: MatchResult, families: tuple = FAMILIES) -> None:
    tuples = active_edges(result.graph, result.solve.x)
    target_edges = result.graph.target_edges[: result.graph.target_edges.shape[0] // 2]
    n_target = result.graph.n_target
    result.check = check_solution(result.curve.vertices, target_edges, n_target, tuples, families)
    if not result.check.ok:
        logger.error("solution check failed: %s", "; ".join(result.check.problems))
        return
    try:
        if "CON" in families:
            result.path = extract_path(result.graph, result.solve.x)
        else:  # an ablation without flow conservation: one crossing edge per layer, no walk
            result.path = entries_without_flow(result.graph, result.solve.x)
    except SolutionError as error:
        result.check = CheckReport(False, (str(error),))
        return
    result.low_map = canonical_point_map(result.path, result.curve.vertices, result.source.mesh.n_verts)
