"""Where two incomplete scans of one surface overlap: the source region that has a partner.

When both meshes are parts (partial-to-partial matching), some of the source has no partner
on the target, and a SpiderCurve through all of the source would have to map that region
somewhere. The region with a partner is estimated before the solve from the descriptors
alone, by **cycle consistency**: a source vertex x whose most similar target vertex y has,
as its own most similar source vertex, a vertex near x again is taken to be in the overlap.
Outside the overlap a vertex's best match is merely the least bad one, and the way back
lands elsewhere. Single vertices are noisy both ways, so each vertex takes the
area-weighted share of consistent vertices in a ball around it, and the overlap is where
that share reaches :data:`MIN_CONSISTENT_SHARE`; gaps narrower than about twice
:data:`CLOSING_RADIUS` are then closed on the mesh's edge graph (a part of a scan's
noisy estimate breaks into islands otherwise). The certified matching then maps the
largest clean piece of this region (:func:`overlap_part`) as a part of the target.
Measurements: ``docs/partial.md``, "Partial-to-partial".
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from spidermatch.geometry.mesh import Mesh, MeshError
from spidermatch.geometry.partial import (
    PartialShape,
    closed_region,
    edge_adjacency,
    kept_part,
    mean_edge_length,
)

logger = logging.getLogger(__name__)

RETURN_RADIUS = 0.05
"""A vertex is consistent when the way back lands this close (in the shared unit of length)."""

SMOOTHING_RADIUS = 0.1
"""Radius (in the shared unit of length) of the ball whose consistent share each vertex takes."""

MIN_CONSISTENT_SHARE = 0.4
"""Least area-weighted share of consistent vertices in the ball for a vertex to be in the overlap."""

CLOSING_RADIUS = 0.06
"""Gaps in the estimate narrower than about twice this (in the shared unit of length) are filled."""

SAMPLE_CAP = 6000
"""Vertices per mesh the cycle test is run on (evenly drawn); the rest take their nearest sample's answer."""

BLOCK_ROWS = 1024
"""Source rows of the similarity matrix computed at once."""

LEAST_OVERLAP = 0.05
"""Smallest share of the source's area an overlap may have (below it, the pair is refused)."""

REFERENCE_CLOSING_RINGS = 2
"""Rings of the closing of the target's images on the reference shape (fills the vertices a
many-to-one map leaves unhit inside the region it reaches, as the covered target region does)."""

REFERENCE_SHARE = 0.5
"""Least area-weighted share of source vertices in the ball whose partner on the reference the
target reaches too, for a vertex to be in the overlap (:func:`reference_overlap`)."""


@dataclass(frozen=True)
class ReferenceImages:
    """Both parts of a pair read on one whole reference shape: each vertex's most similar reference vertex.

    Attributes
    ----------
    reference : Mesh
        The whole shape (e.g. a network's training shape), V_R vertices.
    source : np.ndarray, shape (V_X,)
        Reference vertex of each source vertex.
    target : np.ndarray, shape (V_Y,)
        Reference vertex of each target vertex.
    """

    reference: Mesh
    source: np.ndarray
    target: np.ndarray

    def swapped(self) -> ReferenceImages:
        """The same reading with the two parts' roles exchanged (to read the target's overlap)."""
        return ReferenceImages(self.reference, self.target, self.source)


def estimated_overlap(
    source: Mesh,
    target: Mesh,
    source_unit: np.ndarray,
    target_unit: np.ndarray,
    unit_length: float,
) -> np.ndarray:
    """Source vertices estimated to have a partner on the target, by cycle consistency of the descriptors.

    Parameters
    ----------
    source, target : Mesh
        V_X and V_Y vertices, in one unit of length.
    source_unit : np.ndarray, shape (V_X, D)
    target_unit : np.ndarray, shape (V_Y, D)
        L2-normalised descriptors (cosine similarity is their dot product).
    unit_length : float
        The pair's unit of length (e.g. sqrt of the larger area); the radii are in it.

    Returns
    -------
    np.ndarray, shape (V_X,), bool

    """
    rows_x, rows_y = _spread_sample(source.n_verts), _spread_sample(target.n_verts)
    points = source.verts[rows_x]
    forward, backward = _mutual_best(source_unit[rows_x], target_unit[rows_y])
    returned = points[backward[forward]]
    consistent = np.linalg.norm(returned - points, axis=1) <= RETURN_RADIUS * unit_length
    region = _smoothed_region(source, rows_x, consistent, MIN_CONSISTENT_SHARE, unit_length)
    logger.info(
        "overlap estimate: %.0f %% of %s's samples return to themselves, %.0f %% of its area kept",
        100 * consistent.mean(),
        source.name,
        100 * source.vertex_areas[region].sum() / source.area,
    )
    return region


def reference_overlap(source: Mesh, images: ReferenceImages, unit_length: float) -> np.ndarray:
    """Source vertices whose partner on a whole reference shape the target reaches too, (V_X,) bool.

    Two parts of one kind of surface (two scans of people) are each read on a whole shape of that
    kind, as a part on its whole: the region of the reference the target's vertices reach (closed
    over :data:`REFERENCE_CLOSING_RINGS` rings) is where the target lies, and a source vertex whose
    own partner lies there has a partner on the target. The partial mode's features place a part
    on a whole far better than two parts on each other (docs/partial.md, "The overlap read on a
    reference shape"), which is why this beats the descriptors' cycle test. Single vertices are
    noisy, so each vertex takes the area-weighted share of such vertices within
    :data:`SMOOTHING_RADIUS`, the overlap is where it reaches :data:`REFERENCE_SHARE`, closed as
    :func:`estimated_overlap`'s.

    Parameters
    ----------
    source : Mesh
        V_X vertices.
    images : ReferenceImages
        Both parts' reference vertices.
    unit_length : float
        The pair's unit of length (sqrt of the larger part's area); the radii are in it.

    Returns
    -------
    np.ndarray, shape (V_X,), bool
    """
    reference = images.reference
    reached = np.zeros(reference.n_verts, dtype=bool)
    reached[images.target] = True
    reached = closed_region(reached, edge_adjacency(reference), REFERENCE_CLOSING_RINGS)
    rows_x = _spread_sample(source.n_verts)
    partnered = reached[images.source[rows_x]]
    region = _smoothed_region(source, rows_x, partnered, REFERENCE_SHARE, unit_length)
    logger.info(
        "overlap read on the reference: the target reaches %.0f %% of its area; %.0f %% of %s's area kept",
        100 * reference.vertex_areas[reached].sum() / reference.area,
        100 * source.vertex_areas[region].sum() / source.area,
        source.name,
    )
    return region


def _smoothed_region(
    source: Mesh, rows: np.ndarray, flags: np.ndarray, least_share: float, unit_length: float
) -> np.ndarray:
    """Where flagged samples are the area-weighted majority around, closed on the edge graph, (V_X,) bool.

    ``rows`` (N,) are the sampled source vertices and ``flags`` (N,) bool their answers; each
    vertex takes its nearest sample's share of flagged samples within :data:`SMOOTHING_RADIUS`
    (each sample weighted by the area it stands for), kept where it reaches ``least_share``; gaps
    up to about twice :data:`CLOSING_RADIUS` are closed.
    """
    points = source.verts[rows]
    nearest = cKDTree(points).query(source.verts)[1]  # the sample each vertex takes its answer from
    weights = np.bincount(nearest, weights=source.vertex_areas, minlength=len(rows))  # area it stands for
    share = _ball_share(points, flags, weights, SMOOTHING_RADIUS * unit_length)
    rings = int(np.ceil(CLOSING_RADIUS * unit_length / mean_edge_length(source)))
    return closed_region((share >= least_share)[nearest], edge_adjacency(source), rings)


def overlap_part(
    source: Mesh, overlap: np.ndarray, found_as: str = "has descriptors that match back to themselves"
) -> PartialShape:
    """The largest clean piece of ``source`` whose faces lie in ``overlap`` (V_X,) bool.

    ``found_as`` says in the message how ``overlap`` was found.

    Raises
    ------
    MeshError
        The overlap is (nearly) empty: nothing of the source seems to have a partner.

    """
    keep_faces = np.asarray(overlap, dtype=bool)[source.faces].all(axis=1)
    share = source.face_areas[keep_faces].sum() / source.area
    if share < LEAST_OVERLAP:
        raise MeshError(
            f"{source.name}: no overlap with the target found ({100 * share:.1f} % of its area {found_as}); "
            "check that both scans show one surface in one unit"
        )
    return kept_part(source, keep_faces, f"{source.name}-overlap", "overlap")


def _spread_sample(n: int) -> np.ndarray:
    """At most :data:`SAMPLE_CAP` indices evenly spread over ``range(n)`` (all of them when fewer)."""
    if n <= SAMPLE_CAP:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, SAMPLE_CAP).round().astype(np.int64))


def _mutual_best(source_unit: np.ndarray, target_unit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Most similar target row of each source row (N_X,) and source row of each target row (N_Y,)."""
    targets = np.ascontiguousarray(target_unit, dtype=np.float32)
    forward = np.empty(len(source_unit), dtype=np.int64)
    best_value = np.full(len(targets), -np.inf, dtype=np.float32)
    backward = np.zeros(len(targets), dtype=np.int64)
    for start in range(0, len(source_unit), BLOCK_ROWS):
        block = np.asarray(source_unit[start : start + BLOCK_ROWS], dtype=np.float32) @ targets.T
        forward[start : start + len(block)] = block.argmax(axis=1)
        column_best = block.argmax(axis=0)
        column_value = block[column_best, np.arange(len(targets))]
        better = column_value > best_value
        best_value[better] = column_value[better]
        backward[better] = start + column_best[better]
    return forward, backward


def _ball_share(points: np.ndarray, flags: np.ndarray, weights: np.ndarray, radius: float) -> np.ndarray:
    """Weighted share of flagged points within ``radius`` of each point, shape (N,)."""
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    heads = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(len(points))])
    tails = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(len(points))])
    total = np.bincount(heads, weights=weights[tails], minlength=len(points))
    flagged = np.bincount(heads, weights=(weights * flags)[tails], minlength=len(points))
    return flagged / np.maximum(total, np.finfo(float).tiny)
