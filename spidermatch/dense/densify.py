"""Densification: a map for every full-resolution source vertex from the certified low-resolution one.

Methods (``DenseSettings.method``):

``interp``
    Each full-resolution source vertex is projected onto the low-resolution source
    surface (triangle + barycentric coordinates), among the low-resolution triangles
    around the low-resolution vertex nearest to it along the surface
    (:mod:`spidermatch.geometry.coarse`; a projection by distance in space alone lands on the
    wrong body part where two parts nearly touch). The triangle's three certified
    images (low-resolution target vertices) are blended with the same barycentric
    weights. The blend is carried to the full-resolution target through the target's
    own projection onto its low-resolution surface (the full-resolution triangle, among
    those of the three images' surface patches, whose projection contains the blend,
    with the same barycentric coordinates).
``deformation`` (the default)
    Starts from the ``interp`` image points and alternates, ``deformation_rounds`` times:
    each vertex's feature match, the most similar target vertex within a local radius of
    its current image point (as ``interp_features``; the radius shrinks from ``radius``
    local edge lengths by :data:`RADIUS_SHRINK` per round to :data:`LEAST_RADIUS`); then an
    as-rigid-as-possible fit of the whole source mesh to those matches
    (:mod:`spidermatch.dense.registration`, goal weight ``fit_weight`` per unit of vertex area);
    then each fitted vertex projected onto the target near where the fit put it (near its
    match instead where the nearest target vertex lies far from the match along the
    target's edges: another part that the fit passes close to, :func:`projection_anchors`).
    The features decide where the surface goes, the rigidity of the source's local shape
    keeps neighbouring vertices together and the right way up: far fewer torn edges and
    flipped triangles than matching each vertex on its own, and a lower error (the noise of
    single matches averages out). The certified matches are where the search starts, not fixed points:
    the low-resolution images are quantised to vertices a coarse edge apart, and pinning
    the dense map to them would put a kink at every one (``result.json`` reports how far
    the dense images of the certified vertices lie from their certified images).
``interp_features``
    ``interp``, then among the full-resolution target vertices within a local radius
    (a multiple of the low-resolution edge length there; 2 by default) of the
    interpolated point, the one with the smallest feature distance, plus an optional
    distance penalty (0 by default). The certified map decides where a vertex goes to
    within two coarse edges; the descriptors, which are locally sharper than a
    quantised low-resolution map, place it there.
``zoomout``
    ZoomOut spectral upsampling (Melzi et al. 2019) started from the ``interp`` map:
    alternately fit a functional map in the first k eigenfunctions and re-read the
    point map by nearest neighbours in the spectral embedding, k growing.
``zoomout_local``
    As ``zoomout``, but each vertex may only go to a target vertex within a local
    radius of its ``interp`` image (a neighbourhood-preserving spectral refinement).
``zoomout_accept``
    ``zoomout`` proposes, and a proposal is accepted only within the local radius of
    the ``interp`` image; elsewhere the ``interp`` image is kept.

Every method but ``deformation`` pins the low-resolution source vertices to their certified
images: full-resolution vertex ``low_x.to_full[i]`` goes to ``low_y.to_full[low_map[i]]``.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from spidermatch.dense.feature_search import (
    feature_refined_vertices,
    local_candidates,
)
from spidermatch.dense.interpolation import interpolated_points
from spidermatch.dense.maps import DenseMap, InverseMap, inverse_map
from spidermatch.dense.registration import arap_system, fit
from spidermatch.dense.settings import DenseSettings
from spidermatch.dense.unfold import unfolded_vertices
from spidermatch.geometry.coarse import closest_points_near
from spidermatch.geometry.graph_distance import farther_than
from spidermatch.geometry.mesh import Mesh, mean_incident_edge_length
from spidermatch.geometry.remesh import Decimated
from spidermatch.geometry.surface import (
    nearest_corner,
    surface_positions,
    vertex_points,
)
from spidermatch.model.costs import unit_rows

logger = logging.getLogger(__name__)


RADIUS_SHRINK = 0.7
"""``deformation``: factor of the feature search radius from one round to the next."""

LEAST_RADIUS = 0.5
"""``deformation``: the smallest feature search radius, in local low-resolution edge lengths."""

LEAST_NEIGHBOURS = 16
"""``deformation``: the fewest target vertices searched per point once the radius has shrunk."""

PROGRESS_VERTICES = 20_000
"""Sources with at least this many vertices show a progress bar of the dense stage (a 80 000-vertex
scan takes about 50 s there, a FAUST_r mesh of 5 000 vertices about 3 s)."""

LONG_STAGE_VERTICES = 50_000
"""Sources with at least this many vertices are told before the dense stage that it takes minutes
and how to skip it (measured, one core: 40 s for a clean 80 000-vertex subdivision of a FAUST_r
body, about 2 min for a noisy one, 9 min for a raw 240 000-vertex scan; docs/dense_maps.md)."""

ROTATION_ROUNDS = 5
"""``deformation``: alternations of rotations and positions in each as-rigid-as-possible fit."""

PROJECTION_REACH = 3.0
"""``deformation``: how far, in search radii along the target's edges, the vertex nearest to a
fitted position may lie from the vertex's feature match and still anchor its projection."""


def densify(
    source: Mesh,
    target: Mesh,
    low_x: Decimated,
    low_y: Decimated,
    low_map: np.ndarray,
    source_features: np.ndarray,
    target_features: np.ndarray,
    settings: DenseSettings | None = None,
    spectra: tuple | None = None,
    rest_scale: float | None = None,
) -> DenseMap:
    """Dense map of every vertex of ``source`` from the certified low-resolution map.

    Parameters
    ----------
    source, target : Mesh
        Full-resolution meshes (V_X, V_Y vertices) in the frame of ``low_x``/``low_y``
        (i.e. centred as :func:`spidermatch.pipeline.match` does).
    low_x, low_y : Decimated
        The decimated meshes and their (V_low,) maps to full-resolution vertices.
    low_map : np.ndarray, shape (V_X_low,)
        Certified low-resolution target vertex of each low-resolution source vertex.
    source_features : np.ndarray, shape (V_X, D)
    target_features : np.ndarray, shape (V_Y, D)
    settings : DenseSettings
    spectra : tuple, optional
        ``(evecs_x (V_X, K), mass_x (V_X,), evecs_y (V_Y, K))`` for the ZoomOut methods;
        computed (and cached) with :func:`spectral_basis` if not given.
    rest_scale : float, optional
        ``deformation``: the factor that brings the source's lengths to the target's unit.
        Default sqrt(target area / source area), right for two whole shapes; a part of the
        target in the target's unit needs 1.

    Returns
    -------
    DenseMap

    """
    settings = settings or DenseSettings()
    low_map = np.asarray(low_map, dtype=np.int64)
    _announce_long_stage(source, target)
    with _progress_bar(source, settings) as progress:
        return _densified(source, target, (low_x, low_y, low_map), (source_features, target_features),
                          settings, spectra, rest_scale, progress)  # fmt: skip


def _announce_long_stage(source: Mesh, target: Mesh) -> None:
    """Say before a long dense stage (:data:`LONG_STAGE_VERTICES`) what it costs and how to skip it."""
    if source.n_verts < LONG_STAGE_VERTICES:
        return
    logger.info(
        "dense map of %d source vertices onto %d target vertices: at this size the stage can take "
        "minutes (measured on one core: 40 s to 2 min at 80 000 vertices, 9 min at 240 000); the certified "
        "matching does not need it, and dense.enabled=false (command line) or "
        "MatchSettings(dense=None) (Python) skips it",
        source.n_verts,
        target.n_verts,
    )


def _progress_bar(source: Mesh, settings: DenseSettings) -> _StepBar:
    """A bar over the dense stage's steps, shown for sources of :data:`PROGRESS_VERTICES` or more."""
    from tqdm.auto import tqdm

    rounds = settings.deformation_rounds if settings.method == "deformation" else 1
    steps = 1 + rounds + (settings.smoothing > 0) + bool(settings.unfold) + bool(settings.inverse)
    quiet = source.n_verts < PROGRESS_VERTICES
    bar = tqdm(
        total=steps * _StepBar.UNITS,
        desc=f"dense map of {source.n_verts} vertices ({steps} steps)",
        bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}",
        disable=quiet,
        leave=False,
    )
    return _StepBar(bar)


class _StepBar:
    """The dense stage's bar: each step a share of it, and the rounding's progress within its step.

    The steps take very different times (on a noisy 60 000-vertex scan the fold-free rounding
    took 6 minutes after deformation rounds of 10-40 s each), so a bar that moves only between
    steps shows no progress for minutes and a wrong time left.
    """

    UNITS = 1000
    """Bar units per step."""

    def __init__(self, bar) -> None:
        self.bar = bar
        self.within = 0  # units of the current step shown so far

    def __enter__(self) -> _StepBar:
        self.bar.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self.bar.refresh()  # the last steps can fall within tqdm's minimum interval and go unshown
        self.bar.__exit__(*exc)

    def update(self) -> None:
        """The current step is done."""
        self.bar.update(self.UNITS - self.within)
        self.within = 0

    def within_step(self, fraction: float) -> None:
        """``fraction`` (0 to 1) of the current step is done."""
        units = min(int(fraction * self.UNITS), self.UNITS)
        if units > self.within:
            self.bar.update(units - self.within)
            self.within = units


def _densified(source, target, low, features, settings, spectra, rest_scale, progress) -> DenseMap:
    """:func:`densify` with ``low`` = (low_x, low_y, low_map) and ``features`` = (source, target) rows."""
    low_x, low_y, low_map = low
    source_features, target_features = features
    face, bary, local_edge = interpolated_points(source, target, low_x, low_y, low_map)
    progress.update()
    radius = settings.radius * local_edge
    if settings.method == "interp":
        vertex = nearest_corner(target, face, bary)
    elif settings.method == "interp_features":
        points = surface_positions(target, face, bary)
        fx, fy = unit_rows(source_features), unit_rows(target_features)
        vertex = feature_refined_vertices(target, points, radius, fx, fy, settings)
        face, bary = vertex_points(target, vertex)
    elif settings.method == "deformation":
        if rest_scale is None:
            rest_scale = float(np.sqrt(target.area / source.area))
        points = surface_positions(target, face, bary)
        features = (unit_rows(source_features), unit_rows(target_features))
        face, bary = deformed_points(
            source, target, points, local_edge, features, settings, rest_scale, progress
        )
        vertex = nearest_corner(target, face, bary)
    else:
        start = nearest_corner(target, face, bary)
        candidates = None
        if settings.method == "zoomout_local":
            points = surface_positions(target, face, bary)
            index, _, inside = local_candidates(target, points, radius, settings.n_neighbours)
            candidates = np.where(inside, index, index[:, :1])
        features = (source_features, target_features)
        vertex = spectral_vertices(source, target, start, candidates, features, settings, spectra)
        if settings.method == "zoomout_accept":
            points = surface_positions(target, face, bary)
            far = np.linalg.norm(target.verts[vertex] - points, axis=1) > radius
            vertex[far] = start[far]
        face, bary = vertex_points(target, vertex)
    if settings.method != "deformation":
        progress.update()
    dense = DenseMap(vertex, face, bary, settings.method)
    # The deformation starts from the certified matches; every other method keeps them.
    keep = settings.method != "deformation"
    fixed = low_x.to_full if keep else np.zeros(0, dtype=np.int64)
    if keep:
        dense = pin_certified(dense, target, low_x, low_y, low_map)
    if settings.smoothing > 0:
        dense = smoothed(dense, source, target, fixed, settings.smoothing)
        if keep:
            dense = pin_certified(dense, target, low_x, low_y, low_map)
        progress.update()
    if settings.unfold:
        points = dense.points(target)
        vertex = unfolded_vertices(source, target, dense.vertex, points, fixed, progress.within_step)
        dense = replace(dense, vertex=vertex)
        progress.update()
    if settings.inverse:
        dense = replace(dense, inverse=_inverse(dense, source, target, settings.unfold))
        progress.update()
    return dense


def _inverse(dense: DenseMap, source: Mesh, target: Mesh, unfold: bool) -> InverseMap:
    """The inverse of ``dense``, its source vertices rounded fold-free when ``unfold`` is set.

    The image surface folds where the forward image points do, and the nearest corners of the
    closest points fold with it: on FAUST_r 076->077 at 1000 faces (label-free features) the
    fold-free rounding takes the inverse vertex map's flipped triangles from 2.4 % to 0.5 % and
    its tears from 3.2 % to 2.4 %, at the same error (0.029).
    """
    inverse = inverse_map(dense, source, target)
    if not unfold:
        return inverse
    points = surface_positions(source, inverse.face, inverse.bary)
    return replace(inverse, vertex=unfolded_vertices(target, source, inverse.vertex, points))


def deformed_points(
    source: Mesh,
    target: Mesh,
    points: np.ndarray,
    local_edge: np.ndarray,
    features: tuple[np.ndarray, np.ndarray],
    settings: DenseSettings,
    rest_scale: float,
    progress=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Method ``deformation``: the source fitted as rigidly as it can to its feature matches.

    Parameters
    ----------
    source, target : Mesh
    points : np.ndarray, shape (V_X, 3)
        Starting image points on the target (the ``interp`` map).
    local_edge : np.ndarray, shape (V_X,)
        Local low-resolution target edge length at each starting point (the radius unit).
    features : (np.ndarray (V_X, D), np.ndarray (V_Y, D))
        Unit-norm descriptors.
    settings : DenseSettings
    rest_scale : float
        Factor of the source's rest lengths (to the target's unit).
    progress : _StepBar, optional
        Its ``update()`` is called after each round (one step of the dense stage's bar).

    Returns
    -------
    face : np.ndarray, shape (V_X,), int64
    bary : np.ndarray, shape (V_X, 3)
        The final image points on the target.

    """
    areas = source.vertex_areas
    goal_weights = settings.fit_weight * areas / max(float(areas.mean()), np.finfo(float).tiny)
    goal_weights = np.maximum(goal_weights, settings.fit_weight * 1e-6)  # vertices on no face
    system = arap_system(source.verts * rest_scale, source.faces, goal_weights)
    radius = settings.radius
    for _ in range(settings.deformation_rounds):
        # A smaller disc holds fewer vertices: search as many as cover it (the area's share).
        share = (radius / settings.radius) ** 2
        searched = replace(
            settings, n_neighbours=max(LEAST_NEIGHBOURS, int(np.ceil(settings.n_neighbours * share)))
        )
        matches = feature_refined_vertices(target, points, radius * local_edge, *features, searched)
        fitted = fit(system, target.verts[matches], points, ROTATION_ROUNDS)
        anchors = projection_anchors(target, matches, fitted, PROJECTION_REACH * radius * local_edge)
        face, bary = closest_points_near(target, fitted, anchors)
        points = surface_positions(target, face, bary)
        radius = max(radius * RADIUS_SHRINK, LEAST_RADIUS)
        if progress is not None:
            progress.update()
    return face, bary


def projection_anchors(
    target: Mesh, matches: np.ndarray, fitted: np.ndarray, reach: np.ndarray
) -> np.ndarray:
    """The target vertex around which each fitted position is projected onto the target.

    The vertex nearest to the fitted position, so that the image follows the fit (which
    keeps neighbours together), unless that vertex lies farther from the feature match
    along the target's edges than ``reach``: then the fit passes close to another part of
    the target (two parts nearly touching), and the match anchors the projection instead.

    Parameters
    ----------
    target : Mesh
    matches : np.ndarray, shape (V_X,), int64
        Each source vertex's feature match.
    fitted : np.ndarray, shape (V_X, 3)
        Its position after the as-rigid-as-possible fit.
    reach : np.ndarray, shape (V_X,)

    Returns
    -------
    np.ndarray, shape (V_X,), int64

    """
    nearest = np.asarray(target.vertex_tree.query(fitted)[1], dtype=np.int64)
    return np.where(farther_than(target, matches, nearest, reach), matches, nearest)


def smoothed(dense: DenseMap, source: Mesh, target: Mesh, fixed: np.ndarray, rounds: int) -> DenseMap:
    """Average each image point with its source neighbours' images ``rounds`` times, then project.

    Each round moves a point half way to the mean image of its source 1-ring; the
    points of the ``fixed`` source vertices (V_fixed,) do not move.
    """
    import scipy.sparse as sp

    edges = source.edges
    n = source.n_verts
    adjacency = sp.coo_matrix(
        (np.ones(2 * len(edges)), (edges.reshape(-1), edges[:, ::-1].reshape(-1))), (n, n)
    )
    adjacency = sp.diags(1.0 / np.maximum(np.asarray(adjacency.sum(axis=1)).ravel(), 1.0)) @ adjacency.tocsr()
    points = dense.points(target)
    anchored = points[fixed].copy()
    for _ in range(rounds):
        points = 0.5 * points + 0.5 * (adjacency @ points)
        points[fixed] = anchored
    # Each point may only land near where it started (its vertex's two rings of faces): a
    # free projection jumps to another body part where two parts nearly touch.
    face, bary = closest_points_near(target, points, dense.vertex)
    return DenseMap(nearest_corner(target, face, bary), face, bary, dense.method)


def spectral_vertices(
    source: Mesh,
    target: Mesh,
    start: np.ndarray,
    candidates: np.ndarray | None,
    features: tuple[np.ndarray, np.ndarray],
    settings: DenseSettings,
    spectra: tuple | None = None,
) -> np.ndarray:
    """Methods ``zoomout``/``zoomout_local``: ZoomOut from the vertex map ``start`` (V_X,).

    The eigenfunctions are scaled by sqrt(area) so that the descriptor weight
    ``spectral_feature_weight`` means the same on every shape.
    """
    from spidermatch.dense.zoomout import spectral_basis, zoomout

    stop = settings.spectral_stop
    if spectra is None:
        evecs_x, mass_x = spectral_basis(source, stop)
        evecs_y, _ = spectral_basis(target, stop)
    else:
        evecs_x, mass_x, evecs_y = spectra
    stop = min(stop, evecs_x.shape[1], evecs_y.shape[1])
    scale_x, scale_y = np.sqrt(source.area), np.sqrt(target.area)
    extra = None
    if settings.spectral_feature_weight > 0:
        weight = settings.spectral_feature_weight
        extra = (weight * unit_rows(features[0]), weight * unit_rows(features[1]))
    schedule = range(min(settings.spectral_start, stop), stop + 1, settings.spectral_step)
    return zoomout(
        evecs_x[:, :stop] * scale_x,
        mass_x / scale_x**2,
        evecs_y[:, :stop] * scale_y,
        start,
        schedule,
        candidates,
        extra,
    )


def pin_certified(
    dense: DenseMap, target: Mesh, low_x: Decimated, low_y: Decimated, low_map: np.ndarray
) -> DenseMap:
    """Put the certified matches back: ``low_x.to_full[i]`` -> ``low_y.to_full[low_map[i]]``.

    Where two low-resolution source vertices share one nearest full-resolution vertex,
    the later one wins (the decimation makes this rare).
    """
    vertex, face, bary = dense.vertex.copy(), dense.face.copy(), dense.bary.copy()
    anchors, images = low_x.to_full, low_y.to_full[low_map]
    vertex[anchors] = images
    face[anchors], bary[anchors] = vertex_points(target, images)
    return DenseMap(vertex, face, bary, dense.method)


def certified_agreement(
    dense: DenseMap, target: Mesh, low_x: Decimated, low_y: Decimated, low_map: np.ndarray
) -> dict:
    """How far the dense images of the certified vertices lie from their certified images.

    Distances are in local low-resolution edge lengths (the mean length of the
    low-resolution target edges at the certified image), the scale to which the
    certified map is quantised.

    Returns
    -------
    dict
        ``mean_distance`` and ``within_one_edge`` (the share of certified vertices whose dense
        image lies within one local edge length of the certified one).
    """
    low_map = np.asarray(low_map, dtype=np.int64)
    certified = target.verts[low_y.to_full[low_map]]
    dense_images = dense.points(target)[low_x.to_full]
    local_edge = mean_incident_edge_length(low_y.mesh)[low_map]
    distance = np.linalg.norm(dense_images - certified, axis=1) / np.maximum(local_edge, np.finfo(float).tiny)
    return {"mean_distance": float(distance.mean()), "within_one_edge": float(np.mean(distance <= 1.0))}
