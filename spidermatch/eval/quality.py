"""A verdict on a matching without ground truth: is it plausible, or suspect and why.

The certificate says that no matching is cheaper for the chosen costs; it cannot say that
the costs picked the right correspondence. Four symptoms of a wrong one are visible
without ground truth, on the certified low-resolution map itself:

Mirror image (symmetric flip)
    A map that swaps left and right reverses orientation: the images of the source
    triangles face against the target surface. On a correct map few do (decimation
    noise); on a mirrored one most. ``flipped`` and ``degenerate`` are the shares of
    low-resolution source triangles whose image faces against the target or has no area
    (``spidermatch.eval.metrics`` definitions); ``mirror`` is the flipped share of those whose
    image has an area (degenerate images, two corners on one target vertex, say nothing
    about orientation and are many where the map collapses). At a few hundred faces a
    certified map that is right but a decimated edge off here and there flips a third of
    its triangles too; the dense map it leads to does not. So when there is a dense map,
    ``dense_mirror`` (the same share of its image triangles, at full resolution) must
    agree before a map is called a mirror image (:func:`with_dense_figures`).
Collapse
    A matching that sends many source vertices onto few target vertices (the trivial
    stay path, or costs that do not discriminate): ``distinct`` is the share of distinct
    target vertices among the matches. On a target with boundaries the dense map's covered area
    (``dense_covered``) tells a collapse from a source pressed together, most often a piece of
    which much has no partner (a wrong overlap); both are suspect.
Misplaced region
    A part of the source laid onto the wrong part of the target (a scan's torso onto a
    leg) keeps its triangles facing the right way and its targets distinct, but not its
    distances: ``distortion`` is the share of sampled pairs of source vertices whose
    geodesic distance the map changes by more than half (:func:`distortion`). A right map
    between two poses of one body keeps them. At a few hundred faces the decimated geodesics
    are coarse enough for right maps to exceed the threshold too, so with a dense map its own
    ``dense_distortion`` (full-resolution meshes) must agree. On a target with holes or cuts
    (partial-to-partial, two open scans) geodesics detour around them, and right maps reached
    0.066-0.218 compared plainly: there the certified map's figure is reported only, and the
    dense map's is measured around the boundaries (a pair counts only where no path through
    what was cut away could explain the change) and judged alone, against its own threshold.
Not proven
    A time-limited run whose gap stays large: ``gap``.

The thresholds were calibrated on pairs with ground truth (``bench/bench_quality.py``,
``bench/results/quality_verdict_calibration*``): each separates the correct maps (mean error
below 0.1) from the wrong ones in its figure, mirror images in ``mirror``, collapsed maps in
``distinct`` and ``gap``, misplaced parts of partial scans in ``distortion``
(``bench/results/quality_verdict_partial_to_full_*``; measurements: bench/README.md, solver
constants).
"""

from __future__ import annotations

import math

import numpy as np

from spidermatch.eval.metrics import TEAR_THRESHOLD, flipped_faces, vertex_map_consistency
from spidermatch.geometry.geodesics import GeodesicDistances
from spidermatch.geometry.mesh import Mesh, boundary_vertices, topology
from spidermatch.geometry.remesh import decimate, nearest_vertices
from spidermatch.geometry.surface import surface_positions

MIRROR_SUSPECT = 0.3
"""Flipped share of the non-degenerate image triangles above which the map is called a mirror image."""

DENSE_MIRROR_SUSPECT = 0.2
"""Flipped share of the dense map's non-degenerate image triangles that confirms a mirror image."""

DISTINCT_SUSPECT = 0.45
"""Share of distinct matched target vertices below which the matching is called collapsed."""

GAP_SUSPECT = 0.2
"""Relative gap above which an unproven matching is called suspect."""

DISTORTION_SOURCES = 40
"""Source vertices (drawn with a fixed seed) whose geodesic distances :func:`distortion` compares."""

DISTORTED = 0.5
"""Relative change of a geodesic distance above which :func:`distortion` counts the pair."""

NEAR_QUANTILE = 0.2
"""Pairs closer than this quantile of a source vertex's distances are left out (decimation noise)."""

DISTORTION_SUSPECT = 0.06
"""Share of distorted pairs (:func:`distortion`) above which the map is called misplaced."""

DENSE_DISTORTION_SUSPECT = 0.03
"""The dense map's share of distorted pairs that confirms a misplaced region."""

OPEN_DENSE_DISTORTION_SUSPECT = 0.005
"""The dense map's share of distorted pairs, measured around the boundaries of a target that has
them (:func:`distortion`'s ``around_boundaries``), above which the map is called misplaced: right
``partial=both`` maps of FAUST_r parts reached 0.002, wrong ones 0-1 (docs/partial.md)."""

DENSE_COVERED_COLLAPSE = 0.3
"""Target area the dense map covers on a target with boundaries (``partial=both``), as a share of
the matched source's area, below which few distinct targets (``distinct``) are read as a collapse,
above it as a source pressed together. Of 90 ``partial=both`` runs on FAUST_r parts, the 11 with
fewer than 45 % distinct targets that covered 0.03-0.23 were all wrong (stay paths); the 40 that
covered 0.35-1.19 were 31 wrong, 4 in between and 5 right maps (a piece much of which has no
partner is pressed together; docs/partial.md), so both stay suspect, with their own reason."""

DENSE_DISTORTION_MAX_VERTICES = 50_000
"""Meshes up to this size get ``dense_distortion`` on themselves (heat-method geodesics on both:
about 1 s at 20 000 vertices, 8 s at 80 000, one thread); larger ones (a raw scan) on copies
decimated to :data:`DENSE_DISTORTION_COPY_FACES` faces."""

DENSE_DISTORTION_COPY_FACES = 40_000
"""Faces of the copies a mesh over :data:`DENSE_DISTORTION_MAX_VERTICES` vertices is decimated to
for ``dense_distortion`` (about 20 000 vertices)."""


def assess(low_source: Mesh, low_target: Mesh, low_map: np.ndarray, gap: float | None) -> dict:
    """Figures and verdict of a certified low-resolution map, JSON-ready.

    Parameters
    ----------
    low_source, low_target : Mesh
        The decimated meshes the matching was solved on.
    low_map : np.ndarray, shape (V_X_low,)
        Low-resolution target vertex of each low-resolution source vertex.
    gap : float or None
        The solver's relative gap.

    Returns
    -------
    dict
        ``verdict`` ("plausible" or "suspect"), ``reasons`` (list of str), ``unjudged`` (list of
        str: what the figures cannot tell on this pair, e.g. on a target with boundaries) and the figures
        ``mirror``, ``flipped``, ``degenerate``, ``tears``, ``distinct``, ``gap``,
        ``distortion`` and ``distortion_judged`` (False when the target has a boundary).

    """
    low_map = np.asarray(low_map, dtype=np.int64)
    consistency = vertex_map_consistency(
        low_source, low_target, low_map, tear_threshold=coarse_tear(low_target)
    )
    proper = 1.0 - consistency.degenerate
    figures = {
        "mirror": round(consistency.flipped / proper, 4) if proper > 0 else 1.0,
        "flipped": round(consistency.flipped, 4),
        "degenerate": round(consistency.degenerate, 4),
        "tears": round(consistency.tears, 4),
        "distinct": round(np.unique(low_map).size / max(low_map.size, 1), 4),
        "gap": gap if gap is None or math.isfinite(gap) else None,
        "distortion": round(distortion(low_source, low_target, low_map), 4),
        "distortion_judged": topology(low_target).open_boundaries == 0,  # see the module docstring
    }
    return {**judge(figures), **figures}


COARSE_TEAR_EDGES = 2.0
"""A certified map's edge is torn when its images lie more than this many target edges apart."""


def coarse_tear(target: Mesh) -> float:
    """Tear distance for a map between decimated meshes: :data:`COARSE_TEAR_EDGES` median edges.

    At a few hundred faces an edge is longer than the dense maps' tear distance (0.05
    sqrt(area)), so with that distance every edge tears, the identity's too (0.98 on a mesh
    matched to itself at 300 faces). Never below the dense maps' distance.
    """
    return max(TEAR_THRESHOLD * float(np.sqrt(target.area)), COARSE_TEAR_EDGES * target.median_edge_length)


def distortion(
    source: Mesh, target: Mesh, vertex_map: np.ndarray, seed: int = 0, around_boundaries: bool = False
) -> float:
    """Share of sampled source vertex pairs whose geodesic distance the map changes by more than half.

    From each of :data:`DISTORTION_SOURCES` source vertices (a seeded draw) the geodesic
    distances to every source vertex are compared with those between their images on the
    target. The ratios are divided by their median, so that a pair of meshes in two units, or
    a part measured in its whole's unit, is judged alike; a pair counts when its scaled ratio
    is off 1 by more than :data:`DISTORTED`. Pairs closer than the :data:`NEAR_QUANTILE` of
    each source vertex's distances are left out.

    With ``around_boundaries`` (meshes that are parts of larger surfaces), a distance measured
    on a part may be longer than on its whole, where the path could cross what was cut away:
    the whole's distance lies between the part's and a floor, the least of the part's distance
    and the two ends' distances to the boundary added (any shorter path leaves the part, so
    reaches its boundary from both ends). A pair then counts only when the two ranges, source
    and target, cannot agree within :data:`DISTORTED`, and the median ratio is taken over the
    pairs whose distances are exact on both sides (all pairs if none is). On closed meshes the
    floor is the distance itself and the figure that of the plain comparison.

    Parameters
    ----------
    source, target : Mesh
        The meshes the map joins (V_X and V_Y vertices).
    vertex_map : np.ndarray, shape (V_X,)
        Target vertex of each source vertex.
    seed : int
    around_boundaries : bool
        Bound the distances of parts as above (two boundary distance fields more).

    Returns
    -------
    float
        In [0, 1]; 0 for a map that keeps every sampled distance up to a common scale.

    """
    vertex_map = np.asarray(vertex_map, dtype=np.int64)
    chosen = np.random.default_rng(seed).choice(
        source.n_verts, min(DISTORTION_SOURCES, source.n_verts), replace=False
    )
    on_source, on_target = GeodesicDistances(source), GeodesicDistances(target)
    along_source = on_source.from_vertices(chosen)  # (S, V_X)
    along_target = on_target.from_vertices(vertex_map[chosen])[:, vertex_map]
    near = np.maximum(np.quantile(along_source, NEAR_QUANTILE, axis=1, keepdims=True), 0.0)
    far = along_source > near
    source_floor, target_floor = along_source, along_target
    if around_boundaries:
        source_floor = _whole_surface_floor(on_source, along_source, chosen, np.arange(source.n_verts))
        target_floor = _whole_surface_floor(on_target, along_target, vertex_map[chosen], vertex_map)
    exact = far & (source_floor >= along_source) & (target_floor >= along_target)
    compared = exact if exact.any() else far
    ratios = along_target[compared] / along_source[compared]
    scale = np.median(ratios) if ratios.size else 0.0
    if scale <= 0:  # a collapsed map: ``distinct`` says it
        return 1.0
    stretched = target_floor > (1.0 + DISTORTED) * scale * along_source
    shrunk = along_target < (1.0 - DISTORTED) * scale * source_floor
    return float(np.mean((stretched | shrunk)[far]))


def _whole_surface_floor(
    geodesics: GeodesicDistances, distances: np.ndarray, rows: np.ndarray, columns: np.ndarray
) -> np.ndarray:
    """Least distance the surface a mesh was cut from can have where the mesh has ``distances``.

    Parameters
    ----------
    geodesics : GeodesicDistances
        On the mesh, a part (V vertices); without a boundary the floor is ``distances`` itself.
    distances : np.ndarray, shape (R, C)
        Geodesic distances on the mesh from its vertices ``rows`` (R,) to its vertices ``columns`` (C,).
    rows, columns : np.ndarray

    Returns
    -------
    np.ndarray, shape (R, C)

    """
    boundary = boundary_vertices(geodesics.mesh.faces)
    if boundary.size == 0:
        return distances
    to_boundary = geodesics.from_set(boundary)
    return np.minimum(distances, to_boundary[rows][:, None] + to_boundary[columns][None, :])


def dense_mirror(source: Mesh, target: Mesh, face: np.ndarray, bary: np.ndarray) -> float:
    """Flipped share of a dense map's image triangles that have an area.

    Parameters
    ----------
    source, target : Mesh
        The full-resolution meshes the dense map runs between.
    face : np.ndarray, shape (V_X,)
        Target face of each source vertex's image point.
    bary : np.ndarray, shape (V_X, 3)
        Its barycentric coordinates in that face.

    Returns
    -------
    float
        Flipped over non-degenerate source triangles (1.0 when every image is degenerate).
    """
    flipped, degenerate = flipped_faces(source, target, surface_positions(target, face, bary), face, bary)
    proper = int(np.count_nonzero(~degenerate))
    return float(np.count_nonzero(flipped) / proper) if proper else 1.0


def dense_figures(source: Mesh, target: Mesh, dense_map, covered_area: float | None = None) -> dict:
    """``dense_mirror`` and ``dense_distortion`` of a dense map (``spidermatch.dense.maps.DenseMap``).

    The same figures as ``mirror`` and ``distortion``, on the full-resolution meshes (the
    distortion, of meshes over :data:`DENSE_DISTORTION_MAX_VERTICES` vertices, on decimated
    copies: :func:`distortion_meshes`), on a target with boundaries measured around them
    (:func:`distortion`'s ``around_boundaries``; ``dense_distortion_around_boundaries`` says so).
    On such a target a partial map's ``covered_area`` (:func:`covered_share`) becomes
    ``dense_covered`` (:data:`DENSE_COVERED_COLLAPSE`); None elsewhere.
    """
    open_target = boundary_vertices(target.faces).size > 0
    measured = distortion(*distortion_meshes(source, target, dense_map.vertex), around_boundaries=open_target)
    return {
        "dense_mirror": round(dense_mirror(source, target, dense_map.face, dense_map.bary), 4),
        "dense_distortion": round(measured, 4),
        "dense_distortion_around_boundaries": open_target,
        "dense_covered": round(covered_area, 4) if open_target and covered_area is not None else None,
    }


def distortion_meshes(source: Mesh, target: Mesh, vertex_map: np.ndarray) -> tuple[Mesh, Mesh, np.ndarray]:
    """The meshes and vertex map a dense map's ``dense_distortion`` is measured on.

    As given when neither mesh has more than :data:`DENSE_DISTORTION_MAX_VERTICES` vertices;
    else each larger mesh decimated to :data:`DENSE_DISTORTION_COPY_FACES` faces, a copy's
    vertex standing for the full vertex it came from and an image for the copy's vertex
    nearest to it, so that a raw scan's map is judged as a template's is.

    Parameters
    ----------
    source, target : Mesh
        V_X and V_Y vertices.
    vertex_map : np.ndarray, shape (V_X,)
        Target vertex of each source vertex.

    Returns
    -------
    source, target : Mesh
        The meshes measured (V_x and V_y vertices).
    vertex_map : np.ndarray, shape (V_x,)
    """
    vertex_map = np.asarray(vertex_map, dtype=np.int64)
    if max(source.n_verts, target.n_verts) <= DENSE_DISTORTION_MAX_VERTICES:
        return source, target, vertex_map
    if source.n_verts > DENSE_DISTORTION_MAX_VERTICES:
        low = decimate(source, DENSE_DISTORTION_COPY_FACES)
        source, vertex_map = low.mesh, vertex_map[low.to_full]
    if target.n_verts > DENSE_DISTORTION_MAX_VERTICES:
        low_target = decimate(target, DENSE_DISTORTION_COPY_FACES).mesh
        vertex_map = nearest_vertices(low_target.verts, target.verts[vertex_map])
        target = low_target
    return source, target, vertex_map


def covered_share(source: Mesh, target: Mesh, covered: np.ndarray) -> float:
    """Area of the ``covered`` (V_Y,) bool target vertices over ``source``'s area (one unit)."""
    return float(target.vertex_areas[covered].sum() / source.area)


def with_dense_figures(quality: dict, figures: dict) -> dict:
    """``quality`` (from :func:`assess`) with the :func:`dense_figures` added, and judged again."""
    kept = {key: value for key, value in quality.items() if key not in ("verdict", "reasons", "unjudged")}
    kept.update(figures)
    return {**judge(kept), **kept}


def _confirmed(suspect: bool, dense_figure: float | None, dense_threshold: float) -> bool:
    """A symptom of the certified map, unless the dense map's figure (None: no dense map) clears it."""
    return suspect and (dense_figure is None or dense_figure > dense_threshold)


def judge(figures) -> dict:
    """``verdict``, ``reasons`` and ``unjudged`` from :func:`assess`'s (and :func:`dense_figures`') figures.

    ``unjudged`` names what the figures cannot tell on this pair: a misplaced region on a target
    with boundaries (``partial=both``, or two open scans matched as wholes) when the dense map's
    figure was not measured around them.
    """
    reasons = []
    dense = figures.get("dense_mirror")  # None: no dense map
    if _confirmed(figures["mirror"] > MIRROR_SUSPECT, dense, DENSE_MIRROR_SUSPECT):
        also = "" if dense is None else f" (of the dense map's, {dense:.0%})"
        reasons.append(
            f"{figures['mirror']:.0%} of the image triangles face against the target{also}: "
            "likely a mirror image (left and right swapped) of the right map, at least in part"
        )
    collapsed = figures["distinct"] < DISTINCT_SUSPECT  # then every distance shrinks: said once
    if collapsed:
        reasons.append(_few_distinct_reason(figures["distinct"], figures.get("dense_covered")))
    judged = figures.get("distortion_judged", True) and not collapsed
    dense = figures.get("dense_distortion")
    distorted = (figures.get("distortion") or 0.0) > DISTORTION_SUSPECT  # None: not measured
    if judged and _confirmed(distorted, dense, DENSE_DISTORTION_SUSPECT):
        also = "" if dense is None else f" (the dense map {dense:.0%})"
        reasons.append(
            f"the map changes {figures['distortion']:.0%} of the sampled geodesic distances by more "
            f"than half{also}: likely a region laid onto the wrong part of the target"
        )
    measured_around = dense is not None and figures.get("dense_distortion_around_boundaries", False)
    judged_around_boundaries = not judged and not collapsed and measured_around
    if judged_around_boundaries and dense > OPEN_DENSE_DISTORTION_SUSPECT:
        reasons.append(
            f"the dense map changes {dense:.1%} of the sampled geodesic distances by more than half "
            "even where the boundaries could explain it: likely a region laid onto the wrong part of "
            "the target"
        )
    gap = figures.get("gap")
    if gap is not None and math.isfinite(gap) and gap > GAP_SUSPECT:
        reasons.append(f"the solver's gap {gap:.1%} is large: a much better matching may exist")
    unjudged = [] if judged or collapsed or judged_around_boundaries else [OPEN_TARGET_UNJUDGED]
    return {"verdict": "suspect" if reasons else "plausible", "reasons": reasons, "unjudged": unjudged}


def _few_distinct_reason(distinct: float, covered: float | None) -> str:
    """Why few distinct matched targets (``distinct``) make a map suspect.

    ``covered``: the dense map's covered target area over the source's (None: not measured), see
    :data:`DENSE_COVERED_COLLAPSE`.
    """
    told = f"only {distinct:.0%} of the matched target vertices are distinct"
    if covered is None:
        return f"{told}: the matching collapses (e.g. the trivial stay path)"
    if covered < DENSE_COVERED_COLLAPSE:
        return f"{told} and the dense map covers {covered:.0%} of the source's area: the matching collapses"
    return (
        f"{told}, the dense map covering {covered:.0%} of the source's area: much of the source is pressed "
        "together, as where much of it has no partner on the target (a wrong overlap)"
    )


def remarks(quality: dict) -> list[str]:
    """What to say beside a verdict: a suspect map's reasons, else what a plausible one did not judge."""
    return quality["reasons"] or quality.get("unjudged", [])


OPEN_TARGET_UNJUDGED = (
    "a region laid onto the wrong part of the target is not judged: the target has boundaries, around "
    "which geodesics detour, and no dense map was measured around them"
)
"""What a verdict on a target with boundaries (``partial=both``, two open scans) cannot tell without
the dense map's figure (``dense.enabled=false``):
the certified map's plain figure reached 0.156 on right maps and stayed below 0.2 on 13 of 25 wrong
ones (``bench/results/partial_to_partial_*.csv``), so it is reported only, and a ``plausible`` there
says this."""
