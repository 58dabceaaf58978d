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
    then each fitted vertex projected onto the target near its match. The features decide
    where the surface goes, the rigidity of the source's local shape keeps neighbouring
    vertices together and the right way up: far fewer torn edges and flipped triangles
    than matching each vertex on its own, and a lower error (the noise of single matches
    averages out). The certified matches are where the search starts, not fixed points:
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
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields, replace

import numpy as np
from scipy.spatial import cKDTree

from spidermatch import defaults
from spidermatch.dense.registration import arap_system, fit
from spidermatch.dense.unfold import unfolded_vertices
from spidermatch.geometry.coarse import coarse_labels, faces_by_label, project_onto_coarse, ring_faces
from spidermatch.geometry.mesh import Mesh, mean_incident_edge_length, principal_axes
from spidermatch.geometry.remesh import Decimated
from spidermatch.geometry.surface import (
    closest_triangle_points,
    face_table,
    nearest_corner,
    padded_rows,
    surface_positions,
    vertex_points,
)
from spidermatch.model.costs import unit_rows
from spidermatch.values import is_finite, is_whole

logger = logging.getLogger(__name__)

CANDIDATE_CELLS = 2_000_000
"""Point-face pairs searched at once when image points are located among their patches' faces
(bounds the memory whatever the ratio of full to low resolution; about 300 MB)."""

GATHER_FACTOR = 40
"""Target vertices per candidate above which similarities are gathered rather than multiplied out."""

GATHERED_VALUES = 1 << 25
"""Feature values gathered at once (128 MB in single precision)."""

PRUNE_WIDTH = 600
"""Candidate faces per point above which image points are located among the faces near them only."""

NEAR_VERTICES = 32
"""Nearest target vertices whose faces are searched when the patches are wider than PRUNE_WIDTH."""

RADIUS_SHRINK = 0.7
"""``deformation``: factor of the feature search radius from one round to the next."""

LEAST_RADIUS = 0.5
"""``deformation``: the smallest feature search radius, in local low-resolution edge lengths."""

LEAST_NEIGHBOURS = 16
"""``deformation``: the fewest target vertices searched per point once the radius has shrunk."""

ROTATION_ROUNDS = 5
"""``deformation``: alternations of rotations and positions in each as-rigid-as-possible fit."""

METHODS = ("deformation", "interp", "interp_features", "zoomout", "zoomout_local", "zoomout_accept")


_DEFAULTS = defaults.group("dense/default")


@dataclass(frozen=True)
class DenseSettings:
    """Parameters of the densification.

    Attributes
    ----------
    method : str
        One of :data:`METHODS`.
    radius : float
        Search radius around the interpolated image, in local low-resolution edge lengths
        (``deformation``: in the first round).
    distance_weight : float
        ``interp_features``: weight of (distance / radius)^2 against the feature
        distance ``1 - cos`` of the L2-normalised descriptors.
    n_neighbours : int
        Target vertices considered inside the radius (the nearest ones).
    spectral_start, spectral_stop, spectral_step : int
        ZoomOut's eigenfunction counts: start, stop (inclusive), step.
    spectral_feature_weight : float
        Weight of the descriptors appended to the spectral embedding (0: pure ZoomOut).
    smoothing : int
        Rounds of neighbour averaging of the image points (certified ones held fixed,
        except for ``deformation``), then one projection onto the target surface.
    fit_weight : float
        ``deformation``: weight of a vertex's feature match against the rigidity of its
        edges, per unit of (mean) vertex area.
    deformation_rounds : int
        ``deformation``: rounds of feature matching and fitting.
    inverse : bool
        Also map every target vertex back onto the source (:func:`inverse_map`).
    unfold : bool
        Round the image points to target vertices without folds where a neighbouring vertex
        avoids one (:mod:`spidermatch.dense.unfold`); else each takes its nearest corner.

    """

    method: str = _DEFAULTS["method"]
    radius: float = float(_DEFAULTS["radius"])
    distance_weight: float = float(_DEFAULTS["distance_weight"])
    n_neighbours: int = int(_DEFAULTS["n_neighbours"])
    spectral_start: int = int(_DEFAULTS["spectral_start"])
    spectral_stop: int = int(_DEFAULTS["spectral_stop"])
    spectral_step: int = int(_DEFAULTS["spectral_step"])
    spectral_feature_weight: float = float(_DEFAULTS["spectral_feature_weight"])
    smoothing: int = int(_DEFAULTS["smoothing"])
    fit_weight: float = float(_DEFAULTS["fit_weight"])
    deformation_rounds: int = int(_DEFAULTS["deformation_rounds"])
    inverse: bool = bool(_DEFAULTS["inverse"])
    unfold: bool = bool(_DEFAULTS["unfold"])

    def __post_init__(self) -> None:
        problems = settings_problems(asdict(self))
        if problems:
            raise ValueError("dense settings: " + "; ".join(problems))


WHOLE_SETTINGS = {
    "n_neighbours": 1,
    "spectral_start": 1,
    "spectral_stop": 1,
    "spectral_step": 1,
    "smoothing": 0,
    "deformation_rounds": 1,
}
"""Whole-number settings of :class:`DenseSettings` and their least values."""

REAL_SETTINGS = {
    "radius": "> 0",
    "distance_weight": ">= 0",
    "spectral_feature_weight": ">= 0",
    "fit_weight": "> 0",
}
"""Real-number settings of :class:`DenseSettings` and their allowed range."""


def settings_problems(values: Mapping) -> list[str]:
    """Why ``values`` (keys of :class:`DenseSettings`) are unusable, one ``key=value: rule`` each.

    Checked before any work, so that a bad dense option never ends a run after the solve.
    """
    known = {item.name for item in fields(DenseSettings)}
    problems = [
        f"{key}: unknown (choose from {', '.join(sorted(known))})" for key in values if key not in known
    ]
    if "method" in values and values["method"] not in METHODS:
        choices = ", ".join(METHODS)
        problems.append(f"method={values['method']!r}: unknown dense method; choose from {choices}")
    for key in ("inverse", "unfold"):
        if key in values and not isinstance(values[key], bool):
            problems.append(f"{key}={values[key]!r}: must be true or false")
    for key, least in WHOLE_SETTINGS.items():
        if key in values and (not is_whole(values[key]) or values[key] < least):
            problems.append(f"{key}={values[key]!r}: must be a whole number >= {least}")
    for key, allowed in REAL_SETTINGS.items():
        value = values.get(key, 1.0)
        if not is_finite(value) or (value <= 0 if allowed == "> 0" else value < 0):
            problems.append(f"{key}={value!r}: must be a finite number {allowed}")
    start, stop = values.get("spectral_start", 1), values.get("spectral_stop", 1)
    if is_whole(start) and is_whole(stop) and start > stop:
        problems.append(f"spectral_start={start} > spectral_stop={stop}: the schedule must grow")
    return problems


@dataclass(frozen=True, eq=False)
class InverseMap:
    """A map of every target vertex onto the source, the inverse of a :class:`DenseMap`.

    Attributes
    ----------
    vertex : np.ndarray, shape (V_Y,), int64
        Source vertex of each target vertex.
    face : np.ndarray, shape (V_Y,), int64
        Source face containing each target vertex's source point.
    bary : np.ndarray, shape (V_Y, 3)
        Barycentric coordinates of the source point in ``face``.
    gap : np.ndarray, shape (V_Y,)
        Distance from each target vertex to the forward map's image surface, over
        sqrt(target area): where it is large, no part of the source maps near the vertex.

    """

    vertex: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    gap: np.ndarray


@dataclass(frozen=True, eq=False)
class DenseMap:
    """A map of every full-resolution source vertex onto the full-resolution target.

    Attributes
    ----------
    vertex : np.ndarray, shape (V_X,), int64
        Target vertex of each original source vertex: a corner of its image point's face,
        or with ``DenseSettings.unfold`` a neighbour of one where that avoids a fold.
    face : np.ndarray, shape (V_X,), int64
        Target face containing each image point.
    bary : np.ndarray, shape (V_X, 3), float64
        Barycentric coordinates of each image point in ``face`` (rows sum to one).
    method : str
        The method that made it.
    covered : np.ndarray, shape (V_Y,), bool, or None
        For a partial source: the target vertices the map covers (the overlap); None for
        two whole shapes, where the map covers the whole target.
    inverse : InverseMap or None
        Every target vertex mapped back onto the source (``DenseSettings.inverse``).

    """

    vertex: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    method: str
    covered: np.ndarray | None = None
    inverse: InverseMap | None = None

    def points(self, target: Mesh) -> np.ndarray:
        """3D image points on ``target``, shape (V_X, 3)."""
        return surface_positions(target, self.face, self.bary)


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
    face, bary, local_edge = interpolated_points(source, target, low_x, low_y, low_map)
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
        face, bary = deformed_points(source, target, points, local_edge, features, settings, rest_scale)
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
    if settings.unfold:
        vertex = unfolded_vertices(source, target, dense.vertex, dense.points(target), fixed)
        dense = replace(dense, vertex=vertex)
    if settings.inverse:
        dense = replace(dense, inverse=inverse_map(dense, source, target))
    return dense


def inverse_map(dense: DenseMap, source: Mesh, target: Mesh) -> InverseMap:
    """Every target vertex mapped back through ``dense``: its closest point on the image surface.

    The image surface is the source mesh with each vertex at its image point. A target
    vertex goes to the source point (face, barycentric coordinates) whose image is closest
    to it, so the two maps agree: following the inverse and then the forward map moves a
    target vertex by ``gap`` only (zero where the image surface covers it).
    """
    face, bary, gap = closest_on_image_surface(dense, source, target, target.verts)
    return InverseMap(nearest_corner(source, face, bary), face, bary, gap)


def closest_on_image_surface(
    dense: DenseMap, source: Mesh, target: Mesh, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each point's closest point on the image surface (see :func:`inverse_map`).

    Parameters
    ----------
    points : np.ndarray, shape (N, 3)
        Points on or near the target.

    Returns
    -------
    face : np.ndarray, shape (N,), int64
        Source face.
    bary : np.ndarray, shape (N, 3)
    gap : np.ndarray, shape (N,)
        Distance to the image surface over sqrt(target area).
    """
    images = dense.points(target)
    face, bary = closest_triangle_points(images, source.faces, points)
    closest = np.einsum("nk,nkd->nd", bary, images[source.faces[face]])
    return face, bary, np.linalg.norm(closest - points, axis=1) / np.sqrt(target.area)


def deformed_points(
    source: Mesh,
    target: Mesh,
    points: np.ndarray,
    local_edge: np.ndarray,
    features: tuple[np.ndarray, np.ndarray],
    settings: DenseSettings,
    rest_scale: float,
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
        # Projected near the vertex's own match only: a free projection jumps to another
        # body part where two parts nearly touch.
        face, bary = closest_triangle_points(
            target.verts, target.faces, fitted, candidates=ring_faces(target, matches)
        )
        points = surface_positions(target, face, bary)
        radius = max(radius * RADIUS_SHRINK, LEAST_RADIUS)
    return face, bary


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
    candidates = ring_faces(target, dense.vertex)
    face, bary = closest_triangle_points(target.verts, target.faces, points, candidates=candidates)
    return DenseMap(nearest_corner(target, face, bary), face, bary, dense.method)


def interpolated_points(
    source: Mesh, target: Mesh, low_x: Decimated, low_y: Decimated, low_map: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Method ``interp``: barycentric transfer through the certified low-resolution triangles.

    Returns
    -------
    face : np.ndarray, shape (V_X,)
        Full-resolution target face of each image point.
    bary : np.ndarray, shape (V_X, 3)
    local_edge : np.ndarray, shape (V_X,)
        Mean length of the low-resolution target edges at the three images (the local scale).

    """
    low_face, low_bary = project_onto_coarse(source, low_x, clip=False)
    images = low_map[low_x.mesh.faces[low_face]]
    blended = np.einsum("nk,nkd->nd", low_bary, low_y.mesh.verts[images])
    # Invert the target's own projection onto its low-resolution surface: locate the blend
    # among the projected full-resolution triangles and carry its barycentric coordinates
    # back to the full-resolution triangle (the identity when source = target). Only the
    # triangles of the three images' own surface patches are candidates, so a blend never
    # lands on another body part that happens to be near in space.
    target_labels = coarse_labels(target, low_y)
    target_face, target_bary = project_onto_coarse(target, low_y, clip=False, labels=target_labels)
    projected = surface_positions(low_y.mesh, target_face, target_bary)
    table = faces_by_label(target, target_labels, low_y.mesh.n_verts)
    if images.shape[1] * table.shape[1] <= PRUNE_WIDTH:
        face, bary = _closest_in_patches(projected, target.faces, blended, table, images)
    else:
        face, bary = _closest_near_in_patches(projected, target, target_labels, blended, table, images)
    local_edge = mean_incident_edge_length(low_y.mesh)[images].mean(axis=1)
    return face, bary, local_edge


def _closest_in_patches(projected, faces, points, table, images) -> tuple[np.ndarray, np.ndarray]:
    """Closest face to each point (N, 3) among all faces of its images' patches, a block of rows at a time."""
    face, bary = np.empty(len(points), dtype=np.int64), np.empty((len(points), 3))
    rows = max(1, CANDIDATE_CELLS // (images.shape[1] * table.shape[1]))  # a block's (rows, C) table
    for start in range(0, len(points), rows):
        block = slice(start, start + rows)
        patches = table[images[block]].reshape(len(images[block]), -1)
        face[block], bary[block] = closest_triangle_points(
            projected, faces, points[block], candidates=patches
        )
    return face, bary


def _closest_near_in_patches(
    projected, target, labels, points, table, images
) -> tuple[np.ndarray, np.ndarray]:
    """Closest face among the patches' faces around the point's nearest patch vertices (large patches).

    A target much finer than its low-resolution mesh has patches of thousands of faces;
    the closest one lies around the patch vertices nearest to the point, so only faces
    around those are searched: around the :data:`NEAR_VERTICES` nearest (projected) target
    vertices that belong to one of the three patches, or, for a point with none of those
    (its images span no low-resolution face, so other patches lie between), around the
    :data:`NEAR_VERTICES` nearest vertices of each of its own patches.
    """
    tree, around = cKDTree(projected), face_table(target.faces, target.n_verts)
    face, bary = np.empty(len(points), dtype=np.int64), np.empty((len(points), 3))
    rows = max(1, CANDIDATE_CELLS // (NEAR_VERTICES * around.shape[1]))
    missed = []
    for start in range(0, len(points), rows):
        block = np.arange(start, min(start + rows, len(points)))
        near = tree.query(points[block], k=min(NEAR_VERTICES, len(projected)))[1].reshape(len(block), -1)
        allowed = (labels[near][:, :, None] == images[block][:, None, :]).any(axis=2)
        candidates = np.where(allowed[:, :, None], around[near], -1).reshape(len(block), -1)
        found = (candidates >= 0).any(axis=1)
        face[block[found]], bary[block[found]] = closest_triangle_points(
            projected, target.faces, points[block[found]], candidates=candidates[found]
        )
        missed.append(block[~found])
    miss = np.concatenate(missed)
    near = _nearest_in_own_patches(projected, labels, points[miss], images[miss])
    for start in range(0, len(miss), rows):
        rows_near, block = near[start : start + rows], miss[start : start + rows]
        candidates = np.where(rows_near[:, :, None] >= 0, around[rows_near], -1).reshape(len(block), -1)
        found = (candidates >= 0).any(axis=1)
        face[block[found]], bary[block[found]] = closest_triangle_points(
            projected, target.faces, points[block[found]], candidates=candidates[found]
        )
        if not found.all():  # patches without a full-resolution vertex: their faces, whole
            lost = block[~found]
            face[lost], bary[lost] = _closest_in_patches(
                projected, target.faces, points[lost], table, images[lost]
            )
    return face, bary


def _nearest_in_own_patches(projected, labels, points, images) -> np.ndarray:
    """The :data:`NEAR_VERTICES` vertices nearest to each point in each of its patches.

    Parameters
    ----------
    projected : np.ndarray, shape (V, 3)
    labels : np.ndarray, shape (V,)
        Patch (low-resolution vertex) of every vertex.
    points : np.ndarray, shape (N, 3)
    images : np.ndarray, shape (N, 3)
        The three patches of each point.

    Returns
    -------
    np.ndarray, shape (N, 3 * NEAR_VERTICES), int64
        Vertex indices, -1 where a patch has fewer vertices.

    """
    members = padded_rows(labels, np.arange(len(labels)), int(labels.max()) + 1)
    near = np.full((len(points), images.shape[1], NEAR_VERTICES), -1, dtype=np.int64)
    for patch in np.unique(images):
        vertices = members[patch][members[patch] >= 0]
        row, slot = np.nonzero(images == patch)
        if vertices.size == 0:
            continue
        k = min(NEAR_VERTICES, vertices.size)
        index = cKDTree(projected[vertices]).query(points[row], k=k)[1].reshape(len(row), k)
        near[row, slot, :k] = vertices[index]
    return near.reshape(len(points), images.shape[1] * NEAR_VERTICES)  # also for no points


def local_candidates(
    target: Mesh, points: np.ndarray, radius: np.ndarray, k: int, tree: cKDTree | None = None
):
    """Nearest ``k`` target vertices of each point and which lie within ``radius``.

    ``tree``: a KD-tree of ``target.verts``, if the caller has one.

    Returns
    -------
    index : np.ndarray, shape (N, k)
    distance : np.ndarray, shape (N, k)
    inside : np.ndarray, shape (N, k), bool
        Within the point's radius; the nearest vertex always counts as inside.

    """
    k = min(k, target.n_verts)
    distance, index = (tree or cKDTree(target.verts)).query(points, k=k)
    distance, index = distance.reshape(len(points), k), index.reshape(len(points), k)
    inside = distance <= np.asarray(radius)[:, None]
    inside[:, 0] = True
    return index, distance, inside


def feature_refined_vertices(
    target: Mesh,
    points: np.ndarray,
    radius: np.ndarray,
    source_unit: np.ndarray,
    target_unit: np.ndarray,
    settings: DenseSettings,
) -> np.ndarray:
    """Method ``interp_features``: best feature match near each interpolated point.

    Cost of target vertex y for source vertex x with interpolated point p:
    ``(1 - <f_x, f_y>) + distance_weight * (|p - y| / radius)^2`` over the vertices
    within ``radius`` of p (unit-norm descriptors f).

    The ``n_neighbours`` nearest vertices cover the radius on a mesh of benchmark density,
    but only a small disc of it on a dense scan. When the radius holds more vertices than
    that, the search runs coarse to fine (:func:`spread_levels`): over an evenly spread subset
    of the target vertices within the radius, then over the ``n_neighbours`` vertices of the
    next denser subset around the best so far, and so on to the full resolution (always
    within the radius). The searched area, and so the map, does not shrink as the target's
    resolution grows.

    Returns
    -------
    np.ndarray, shape (V_X,), int64

    """
    costs = (source_unit, target_unit, settings)
    centres = points
    for allowed in spread_levels(target, float(np.median(radius)), settings.n_neighbours):
        best = _cheapest_near(target.verts, allowed, centres, points, radius, costs)
        centres = target.verts[best]
    return best


def spread_levels(target: Mesh, radius: float, n_neighbours: int) -> list[np.ndarray]:
    """Target vertex subsets for the coarse-to-fine search, sparsest first; the last is every vertex.

    The sparsest has about ``n_neighbours / 2`` vertices in a disc of ``radius``; each next one
    is denser by ``n_neighbours / pi`` (so that ``n_neighbours`` of its vertices around a point
    cover the spacing of the one before). A subset keeps one vertex per cell of a cubic grid
    in the mesh's principal frame (:func:`principal_frame`).
    A target with at most ``n_neighbours`` vertices per disc has the one full level.
    """
    per_disc = target.n_verts * np.pi * radius**2 / target.area
    density, growth = 0.5 * n_neighbours, max(n_neighbours / np.pi, 2.0)
    levels = []
    if per_disc > n_neighbours:
        frame = principal_frame(target.verts)
    while per_disc > n_neighbours and density < per_disc:
        cell = radius * np.sqrt(np.pi / density)
        cells = np.floor(frame / cell).astype(np.int64)
        levels.append(np.sort(np.unique(cells, axis=0, return_index=True)[1]))
        density *= growth
    return [*levels, np.arange(target.n_verts)]


def principal_frame(verts: np.ndarray) -> np.ndarray:
    """Coordinates (V, 3) about the centroid along the principal axes.

    A grid in this frame partitions a mesh the same way in any position and rotation (an
    axis's sign does not matter: the cells' borders lie at whole multiples of the cell size
    on both sides of the centroid), so the subsets it picks (the lowest vertex index per
    cell) are those of the mesh as given in any frame.
    """
    return (verts - verts.mean(axis=0)) @ principal_axes(verts)


def _cheapest_near(
    verts: np.ndarray,
    allowed: np.ndarray,
    centres: np.ndarray,
    points: np.ndarray,
    radius: np.ndarray,
    costs: tuple,
) -> np.ndarray:
    """For each point, the cheapest of the ``n_neighbours`` ``allowed`` vertices nearest to its centre.

    Only candidates within ``radius`` of the point count, and the one nearest to the centre
    always does (when the centre is the point, that is the nearest vertex).

    Returns
    -------
    np.ndarray, shape (N,), int64
        Vertex indices into ``verts``.

    """
    source_unit, target_unit, settings = costs
    tree = cKDTree(verts[allowed])
    k = min(settings.n_neighbours, len(allowed))
    out = np.empty(len(points), dtype=np.int64)
    rows = max(1, CANDIDATE_CELLS // max(k, 1))  # bounds the (rows, k) tables
    for start in range(0, len(points), rows):
        block = slice(start, start + rows)
        index = allowed[tree.query(centres[block], k=k)[1].reshape(-1, k)]
        distance = np.linalg.norm(verts[index] - points[block, None, :], axis=2)
        inside = distance <= radius[block, None]
        inside[:, 0] = True
        similarity = candidate_similarities(source_unit[block], target_unit, index)
        cost = 1.0 - similarity + settings.distance_weight * (distance / radius[block, None]) ** 2
        cost[~inside] = np.inf
        out[block] = index[np.arange(len(index)), np.argmin(cost, axis=1)]
    return out


def candidate_similarities(source_unit: np.ndarray, target_unit: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Cosine similarity of each source row (N, D) with its candidate target rows ``index`` (N, K).

    Computed in single precision a block of source rows at a time: against all targets (a
    (block, V_Y) product, fastest while V_Y is small) or, on a target with more than
    :data:`GATHER_FACTOR` K vertices, against the gathered candidate rows only (a (block, K, D)
    array), whose cost does not grow with V_Y.

    Returns
    -------
    np.ndarray, shape (N, K), float32

    """
    from spidermatch.dense.zoomout import BLOCK

    targets = np.ascontiguousarray(target_unit, dtype=np.float32)
    out = np.empty(index.shape, dtype=np.float32)
    gather = len(targets) > GATHER_FACTOR * index.shape[1]
    rows = max(1, GATHERED_VALUES // (index.shape[1] * targets.shape[1])) if gather else BLOCK
    for start in range(0, len(index), rows):
        sources = np.asarray(source_unit[start : start + rows], dtype=np.float32)
        if gather:
            out[start : start + rows] = np.einsum("nd,nkd->nk", sources, targets[index[start : start + rows]])
        else:
            products = sources @ targets.T
            out[start : start + rows] = np.take_along_axis(products, index[start : start + rows], axis=1)
    return out


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


def feature_nearest_neighbours(source_features: np.ndarray, target_features: np.ndarray) -> np.ndarray:
    """The features' own dense map: most similar (cosine) target vertex per source vertex, (V_X,)."""
    from spidermatch.dense.zoomout import nearest_rows

    return nearest_rows(unit_rows(source_features), unit_rows(target_features))
