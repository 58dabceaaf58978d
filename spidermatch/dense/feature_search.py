"""Feature matches near a first guess: the most similar target vertex within a radius.

Candidates are gathered per source vertex from the target vertices near its guessed
image, in levels that spread until a disc holds enough of them, and scored by the cosine
similarity of unit descriptors (and optionally the distance to the guess).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from spidermatch.dense.settings import DenseSettings
from spidermatch.geometry.mesh import Mesh, principal_axes
from spidermatch.model.costs import unit_rows

CANDIDATE_CELLS = 2_000_000
"""Point-face pairs searched at once when image points are located among their patches' faces
(bounds the memory whatever the ratio of full to low resolution; about 300 MB)."""


GATHER_FACTOR = 40
"""Target vertices per candidate above which similarities are gathered rather than multiplied out."""


GATHERED_VALUES = 1 << 25
"""Feature values gathered at once (128 MB in single precision)."""


NEAR_VERTICES = 32
"""Nearest target vertices whose faces are searched when the patches are wider than PRUNE_WIDTH."""


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


def feature_nearest_neighbours(source_features: np.ndarray, target_features: np.ndarray) -> np.ndarray:
    """The features' own dense map: most similar (cosine) target vertex per source vertex, (V_X,)."""
    from spidermatch.dense.zoomout import nearest_rows

    return nearest_rows(unit_rows(source_features), unit_rows(target_features))
