"""Quality of dense maps: geodesic error at the reference points, tears and flips.

Maps are given in point form: an image point on the target for every source vertex
(``DenseMap.points``), or, for vertex maps such as the features' nearest neighbours, the
image vertices' positions. All distances are divided by sqrt(area of the target).

Tears
    A source edge (i, j) is torn when its image points are more than ``0.05 sqrt(area)``
    apart on the target, measured geodesically. Euclidean distance alone under-counts
    (two legs or fingers can be close in space and far on the surface), so an edge whose
    images are within the threshold in space is checked along the target's edge graph:
    with v_i, v_j the target vertices nearest to the two image points and o_i, o_j the
    distances to them, the edge is torn when ``d_graph(v_i, v_j) - o_i - o_j`` exceeds the
    threshold. ``d_graph`` is Dijkstra on the edge graph, stopped at the threshold plus
    the offsets (:mod:`spidermatch.geometry.graph_distance`: exact, on the part of the
    target within that distance of the image vertices, a block of them at a time). It
    over-estimates the geodesic distance by a few per cent on a well-shaped mesh.
Flips
    A source triangle is flipped when its image triangle (the three image points) has a
    normal pointing against the target surface there (negative dot product with the sum
    of the target's vertex normals interpolated at the three image points), and
    degenerate when the image triangle's area is below 1e-6 of the target's mean
    triangle area (e.g. two corners on one target vertex). ``flips`` counts both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from spidermatch.eval.errors import pointwise_geodesic_errors
from spidermatch.geometry.geodesics import GeodesicDistances
from spidermatch.geometry.graph_distance import farther_than
from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.operators import vertex_normals
from spidermatch.geometry.surface import closest_surface_points

TEAR_THRESHOLD = 0.05
DEGENERATE_AREA = 1e-6
SAMPLED_FACES = 20_000  # meshes with more source faces are scored on a fixed sample of this many
DIJKSTRA_TOTAL_CELLS = 3e9  # distances a tear count may fill (starts x V_Y), a few seconds


def scored_face_count(n_target: int) -> int:
    """Source faces to score against a target of ``n_target`` vertices (each may start a Dijkstra run)."""
    return int(np.clip(DIJKSTRA_TOTAL_CELLS / (3 * n_target), 1000, SAMPLED_FACES))


@dataclass(frozen=True)
class Consistency:
    """Geometric consistency of a dense map.

    Attributes
    ----------
    tears : float
        Fraction of source edges whose images are more than the threshold apart.
    flips : float
        Fraction of source triangles whose image is flipped or degenerate.
    flipped, degenerate : float
        The two parts of ``flips``.

    """

    tears: float
    flips: float
    flipped: float
    degenerate: float

    def as_dict(self) -> dict:
        """JSON-ready figures."""
        return {name: float(getattr(self, name)) for name in ("tears", "flips", "flipped", "degenerate")}


def sampled_faces(source: Mesh, most: int = SAMPLED_FACES) -> np.ndarray | None:
    """A fixed random sample of ``most`` source faces (sorted), or None when the mesh has no more.

    Tears and flips are fractions of edges and faces: a uniform sample estimates them with
    a standard error below 0.4 percentage points at 20 000 faces, at a bounded cost.
    """
    if source.n_faces <= most:
        return None
    return np.sort(np.random.default_rng(0).choice(source.n_faces, size=most, replace=False))


def consistency(
    source: Mesh,
    target: Mesh,
    points: np.ndarray,
    face: np.ndarray | None = None,
    bary=None,
    faces: np.ndarray | None = None,
    tear_threshold: float | None = None,
) -> Consistency:
    """Tears and flips of the map sending source vertex i to ``points[i]`` on ``target``.

    Parameters
    ----------
    source, target : Mesh
    points : np.ndarray, shape (V_X, 3)
        Image point of each source vertex, on the target surface (only those of the
        vertices of ``faces`` are read when a sample is given).
    face, bary : np.ndarray, shapes (V_X,), (V_X, 3), optional
        The image points as target face + barycentric coordinates (found by
        closest-point search when not given).
    faces : np.ndarray, shape (S,), optional
        Source faces to score (e.g. :func:`sampled_faces`); tears then count their edges.
        Default: all.
    tear_threshold : float, optional
        Distance on the target beyond which an edge's images are torn apart; default
        ``TEAR_THRESHOLD`` sqrt(target area).

    """
    points = np.asarray(points, dtype=np.float64)
    if points.shape != (source.n_verts, 3):
        raise ValueError(f"need one image point per source vertex ({source.n_verts}, 3), got {points.shape}")
    if face is None or bary is None:
        face, bary = closest_surface_points(target, points)
    if faces is not None:
        source = Mesh(source.verts, source.faces[faces], source.name)  # unused vertices are never read
    torn = torn_edges(source, target, points, face, bary, tear_threshold)
    flipped, degenerate = flipped_faces(source, target, points, face, bary)
    flips = flipped | degenerate
    return Consistency(
        float(torn.mean()), float(flips.mean()), float(flipped.mean()), float(degenerate.mean())
    )


def vertex_map_consistency(
    source: Mesh,
    target: Mesh,
    src_to_tgt: np.ndarray,
    faces: np.ndarray | None = None,
    tear_threshold: float | None = None,
) -> Consistency:
    """:func:`consistency` of a vertex map (V_X,), e.g. the features' nearest neighbours."""
    from spidermatch.geometry.surface import vertex_points

    vertices = np.asarray(src_to_tgt, dtype=np.int64)
    face, bary = vertex_points(target, vertices)
    return consistency(source, target, target.verts[vertices], face, bary, faces, tear_threshold)


def torn_edges(
    source: Mesh,
    target: Mesh,
    points: np.ndarray,
    face: np.ndarray,
    bary: np.ndarray,
    threshold: float | None = None,
) -> np.ndarray:
    """Whether each source edge (E,) is torn (see the module docstring), bool (E,).

    ``threshold``: the tear distance on the target (default ``TEAR_THRESHOLD`` sqrt(area)).
    """
    if threshold is None:
        threshold = TEAR_THRESHOLD * np.sqrt(target.area)
    edges = source.edges
    euclidean = np.linalg.norm(points[edges[:, 0]] - points[edges[:, 1]], axis=1)
    torn = euclidean > threshold
    corners = target.faces[face]
    offsets_all = np.linalg.norm(target.verts[corners] - points[:, None, :], axis=2)
    snapped = corners[np.arange(len(face)), np.argmin(offsets_all, axis=1)]
    offset = offsets_all.min(axis=1)
    check = np.flatnonzero(~torn & (snapped[edges[:, 0]] != snapped[edges[:, 1]]))
    if check.size:
        a, b = snapped[edges[check, 0]], snapped[edges[check, 1]]
        slack = offset[edges[check, 0]] + offset[edges[check, 1]]
        torn[check] = farther_than(target, a, b, threshold + slack)
    return torn


def flipped_faces(
    source: Mesh, target: Mesh, points: np.ndarray, face: np.ndarray, bary: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Flipped and degenerate image triangles, bool (F_X,) each (see the module docstring)."""
    target_normals = vertex_normals(target.verts, target.faces)
    at_points = np.einsum("nk,nkd->nd", bary, target_normals[target.faces[face]])
    return oriented_triangles(points[source.faces], at_points[source.faces].sum(axis=1), target)


def oriented_triangles(
    corners: np.ndarray, reference: np.ndarray, target: Mesh
) -> tuple[np.ndarray, np.ndarray]:
    """Which triangles on ``target`` face against it, and which have no area (the flips' definition).

    Parameters
    ----------
    corners : np.ndarray, shape (F, 3, 3)
        The triangles' corner positions.
    reference : np.ndarray, shape (F, 3)
        The target's normal direction at each triangle (e.g. its corners' normals summed).
    target : Mesh

    Returns
    -------
    flipped, degenerate : np.ndarray, shape (F,), bool each
        Degenerate: area at most :data:`DEGENERATE_AREA` of the target's mean triangle;
        flipped: not degenerate, and its normal against ``reference``.
    """
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    degenerate = 0.5 * np.linalg.norm(normal, axis=-1) <= DEGENERATE_AREA * target.area / target.n_faces
    flipped = ~degenerate & (np.einsum("fd,fd->f", normal, reference) < 0)
    return flipped, degenerate


def geodesic_errors(
    maps: dict[str, np.ndarray],
    src_corr: np.ndarray,
    tgt_corr: np.ndarray,
    target: Mesh,
    geodesics: GeodesicDistances | None = None,
) -> dict[str, np.ndarray]:
    """Dense Princeton protocol for several vertex maps at once: errors at the K reference points.

    One heat-method solve per distinct true vertex serves every map.

    Parameters
    ----------
    maps : dict of str -> np.ndarray, shape (V_X,)
        Target vertex of every source vertex, per map name.
    src_corr, tgt_corr : np.ndarray, shape (K,)
    target : Mesh

    Returns
    -------
    dict of str -> np.ndarray, shape (K,)
        Geodesic errors over sqrt(area of the target).

    """
    src_corr, tgt_corr = np.asarray(src_corr, np.int64), np.asarray(tgt_corr, np.int64)
    names = list(maps)
    predicted = np.concatenate([np.asarray(maps[name], np.int64)[src_corr] for name in names])
    truth = np.tile(tgt_corr, len(names))
    errors = pointwise_geodesic_errors(target, predicted, truth, geodesics)
    return dict(zip(names, np.split(errors, len(names))))


TRUTH_NEIGHBOURHOOD = 0.05
"""Source radius (in sqrt(source area), along the edges) within which reference points are neighbours."""

TRUTH_JUMP = 0.3
"""Distance (in sqrt(target area), along the edges) at which two neighbours' true images disagree."""


def inconsistent_truth(source: Mesh, target: Mesh, src_corr: np.ndarray, tgt_corr: np.ndarray) -> np.ndarray:
    """Reference points whose true image lies far from those of most of their neighbours on the source.

    A ground-truth correspondence is continuous: reference points within
    :data:`TRUTH_NEIGHBOURHOOD` of each other on the source have true images close together on
    the target. Where a dataset's truth was transferred by nearest points, it can jump onto
    another part that touches this one (FAUST_r tr_reg_076 -> tr_reg_077: 25 of 5000 points of
    a hand pressed against the other hand have their truth on the other hand, about 1.0 from
    their neighbours' truths). A point is inconsistent when the true images of fewer than half
    of its neighbours lie within :data:`TRUTH_JUMP` of its own. A continuous map is scored
    wrong at such points whatever it does, so benchmarks report its error with and without them.

    Parameters
    ----------
    source, target : Mesh
    src_corr, tgt_corr : np.ndarray, shape (K,), int
        Reference points: vertex ``src_corr[k]`` of the source truly goes to ``tgt_corr[k]``.

    Returns
    -------
    np.ndarray, shape (K,), bool
        True where the point's truth disagrees with most of its neighbours' (False for a point
        without neighbours).
    """
    src_corr, tgt_corr = np.asarray(src_corr, np.int64), np.asarray(tgt_corr, np.int64)
    radius = TRUTH_NEIGHBOURHOOD * np.sqrt(source.area)
    pairs = cKDTree(source.verts[src_corr]).query_pairs(radius, output_type="ndarray")
    pairs = pairs[~farther_than(source, src_corr[pairs[:, 0]], src_corr[pairs[:, 1]], radius)]
    jump = TRUTH_JUMP * np.sqrt(target.area)
    agree = ~farther_than(target, tgt_corr[pairs[:, 0]], tgt_corr[pairs[:, 1]], jump)
    neighbours = np.bincount(pairs.reshape(-1), minlength=len(src_corr))
    agreeing = np.bincount(pairs[agree].reshape(-1), minlength=len(src_corr))
    return (neighbours > 0) & (agreeing < 0.5 * neighbours)
