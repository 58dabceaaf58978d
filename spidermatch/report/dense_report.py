"""Files and figures of a dense map: ``dense_matches.csv``, ``dense_map.npz`` and the result.json entry.

``dense_map.npz`` holds, for the V_X vertices of the original source mesh:

=====================  ==============  ==========================================================
key                    shape, dtype    content
=====================  ==============  ==========================================================
``vertex``             (V_X,) int64    target vertex (0-based) of each source vertex
``face``               (V_X,) int64    target face (0-based row of the target's face list)
``bary``               (V_X, 3) float  barycentric coordinates of the image point in ``face``
``method``             () str          the densification method
``target_covered``     (V_Y,) bool     partial source only: the target vertices it covers
``inverse_vertex``     (V_Y,) int64    with ``dense.inverse``: source vertex of each target vertex
``inverse_face``       (V_Y,) int64    ... the source face of its source point
``inverse_bary``       (V_Y, 3) float  ... and the barycentric coordinates there
``inverse_gap``        (V_Y,) float    ... distance to the image surface over sqrt(target area)
=====================  ==============  ==========================================================

With ``dense.inverse`` the inverse map is also written as ``dense_inverse_matches.csv``
(``target_vertex,source_vertex``, a row per target vertex).
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import numpy as np

from spidermatch.dense.feature_search import feature_nearest_neighbours
from spidermatch.dense.maps import DenseMap, InverseMap, closest_on_image_surface
from spidermatch.eval.metrics import (
    consistency,
    geodesic_errors,
    sampled_faces,
    scored_face_count,
    vertex_map_consistency,
)
from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.partial import ids_or_missing
from spidermatch.geometry.weld import Weld
from spidermatch.shutdown import atomic_path

logger = logging.getLogger(__name__)


def write_dense_outputs(
    output_dir: Path,
    dense: DenseMap,
    piece: tuple | None = None,
    target_piece: tuple | None = None,
    welds: tuple = (None, None),
) -> list[Path]:
    """Write ``dense_matches.csv``, ``dense_map.npz`` and, with an inverse map, ``dense_inverse_matches.csv``.

    ``dense_matches.csv`` has a ``source_vertex,target_vertex`` row per vertex of the source as
    given, in order (-1 as the target of a vertex outside a matched piece).

    Parameters
    ----------
    output_dir : Path
    dense : DenseMap
    piece : (np.ndarray (V_piece,), np.ndarray (F_piece,), int), optional
        When ``dense`` maps a piece of the user's source (``partial=both``, ``repair=true``):
        the source's vertex and face index of each of the piece's, and the source's vertex
        count V_X. The files then name the source's own vertices and faces: a CSV row per
        source vertex (target -1 outside the piece), ``source_vertex`` (V_piece,) in the
        archive beside the piece's images, and the inverse map onto the source's faces.
    target_piece : (np.ndarray (V_T,), np.ndarray (F_T,), int), optional
        When ``dense`` maps onto a repaired piece of the user's target: the target's vertex and
        face index of each of the piece's, and the target's vertex count V_Y. The files then
        name the target's own vertices and faces; the arrays per target vertex
        (``target_covered``, ``inverse_*``) get V_Y entries, False or -1 (NaN for
        ``inverse_bary`` and ``inverse_gap``) at the vertices the repair left out.
    welds : (Weld or None, Weld or None)
        Source and target given with repeated vertices and matched welded
        (:mod:`spidermatch.geometry.weld`; after any piece above, which then lies in the welded
        mesh): the files name the files' own vertices, a row per source file vertex and a
        per-target-vertex entry per target file vertex, each repeated vertex with the values of
        the vertex it was welded into.
    """
    csv_path, npz_path = output_dir / "dense_matches.csv", output_dir / "dense_map.npz"
    dense = dense if target_piece is None else on_user_target(dense, *target_piece)
    source_weld, target_weld = welds
    dense = dense if target_weld is None else on_file_target(dense, target_weld)
    vertex_ids, face_ids, n_source = piece if piece is not None else (None, None, None)
    inverse_ids = vertex_ids  # where a piece vertex lies in the source as given (None: itself)
    rows = None
    if source_weld is not None:
        inverse_ids = source_weld.to_file if vertex_ids is None else source_weld.file_ids(vertex_ids)
        rows, vertex_ids = source_weld.file_rows(
            np.arange(dense.vertex.size) if vertex_ids is None else vertex_ids
        )
        if piece is None:  # every file vertex has a row, in order
            vertex_ids = None
    image_vertex, image_face, image_bary = (
        (dense.vertex, dense.face, dense.bary)
        if rows is None
        else (dense.vertex[rows], dense.face[rows], dense.bary[rows])
    )
    every = image_vertex
    if vertex_ids is not None:  # a row per source vertex (the file's, where welded); -1 outside the piece
        every = np.full(source_weld.n_file if source_weld is not None else n_source, -1, dtype=np.int64)
        every[vertex_ids] = image_vertex
    _write_vertex_pairs(csv_path, every, "source_vertex,target_vertex")
    extra = {} if dense.covered is None else {"target_covered": dense.covered}
    if vertex_ids is not None:
        extra["source_vertex"] = vertex_ids
    written = [csv_path, npz_path]
    if dense.inverse is not None:
        inverse = dense.inverse
        inverse_vertex = (
            inverse.vertex if inverse_ids is None else ids_or_missing(inverse_ids, inverse.vertex)
        )
        extra.update(
            inverse_vertex=inverse_vertex,
            inverse_face=inverse.face if face_ids is None else ids_or_missing(face_ids, inverse.face),
            inverse_bary=inverse.bary,
            inverse_gap=inverse.gap,
        )
        written.append(output_dir / "dense_inverse_matches.csv")
        _write_vertex_pairs(written[-1], inverse_vertex, "target_vertex,source_vertex")
    with atomic_path(npz_path) as tmp:
        np.savez(
            tmp, vertex=image_vertex, face=image_face, bary=image_bary, method=np.array(dense.method), **extra
        )
    return written


def on_user_target(dense: DenseMap, vertex_ids: np.ndarray, face_ids: np.ndarray, n_target: int) -> DenseMap:
    """``dense`` (onto a piece of the user's target) told in the target's own vertices and faces.

    Per-target-vertex arrays grow from the piece's V_T to ``n_target`` entries: not covered,
    -1 and NaN at the vertices the piece leaves out.
    """
    covered = None
    if dense.covered is not None:
        covered = np.zeros(n_target, dtype=bool)
        covered[vertex_ids] = dense.covered
    inverse = None
    if dense.inverse is not None:
        inv = dense.inverse
        vertex, face = np.full(n_target, -1, dtype=np.int64), np.full(n_target, -1, dtype=np.int64)
        bary, gap = np.full((n_target, 3), np.nan), np.full(n_target, np.nan)
        vertex[vertex_ids], face[vertex_ids], bary[vertex_ids], gap[vertex_ids] = (
            inv.vertex,
            inv.face,
            inv.bary,
            inv.gap,
        )
        inverse = InverseMap(vertex, face, bary, gap)
    return DenseMap(
        vertex_ids[dense.vertex], face_ids[dense.face], dense.bary, dense.method, covered, inverse
    )


def on_file_target(dense: DenseMap, weld: Weld) -> DenseMap:
    """``dense`` (onto a welded target) told in the target file's vertices; faces keep their numbers.

    Image vertices become their first file vertex; per-target-vertex arrays get one entry per
    file vertex, a repeated vertex that of the vertex it was welded into.
    """
    covered = None if dense.covered is None else weld.file_values(dense.covered)
    inverse = dense.inverse
    if inverse is not None:
        inverse = InverseMap(
            *(
                weld.file_values(values)
                for values in (inverse.vertex, inverse.face, inverse.bary, inverse.gap)
            )
        )
    return DenseMap(weld.file_ids(dense.vertex), dense.face, dense.bary, dense.method, covered, inverse)


def _write_vertex_pairs(path: Path, images: np.ndarray, header: str) -> None:
    """A ``header`` row, then ``i,images[i]`` for every i."""
    rows = np.stack([np.arange(images.size), images], axis=1)
    with atomic_path(path) as tmp:
        np.savetxt(tmp, rows, fmt="%d", delimiter=",", header=header, comments="")


def read_dense_map(path: str | os.PathLike) -> DenseMap:
    """Load a ``dense_map.npz`` written by :func:`write_dense_outputs`."""
    with np.load(path) as data:
        covered = data["target_covered"] if "target_covered" in data else None
        inverse = None
        if "inverse_vertex" in data:
            inverse = InverseMap(
                data["inverse_vertex"], data["inverse_face"], data["inverse_bary"], data["inverse_gap"]
            )
        return DenseMap(data["vertex"], data["face"], data["bary"], str(data["method"]), covered, inverse)


COVERED_GAP = 0.02
"""Distance to the image surface, over sqrt(target area), within which a target vertex counts as covered."""

COVERAGE_SAMPLE = 20_000
"""Target vertices whose distance to the image surface is measured (a fixed sample of a larger target)."""


def target_coverage(dense: DenseMap, source: Mesh, target: Mesh) -> dict:
    """How much of the target the dense map reaches.

    Returns
    -------
    dict
        ``reached_vertices``: the share of target vertices that are some source vertex's image
        (the vertex form; below one when the target is finer or the map folds);
        ``covered_area``: the share of the target's area (vertex areas) whose vertices lie
        within :data:`COVERED_GAP` of the image surface (the source mesh with its vertices at
        their image points); ``mean_gap``: the mean distance of the target vertices to it.
        Without an inverse map, a target of more than :data:`COVERAGE_SAMPLE` vertices is
        measured on a fixed sample of that many (the search costs as much as the inverse map).
    """
    reached = np.zeros(target.n_verts, dtype=bool)
    reached[dense.vertex] = True
    if dense.inverse is not None:
        measured, gap = np.arange(target.n_verts), dense.inverse.gap
    else:
        measured = np.arange(target.n_verts)
        if target.n_verts > COVERAGE_SAMPLE:
            measured = np.sort(
                np.random.default_rng(0).choice(target.n_verts, COVERAGE_SAMPLE, replace=False)
            )
        gap = closest_on_image_surface(dense, source, target, target.verts[measured])[2]
    areas = target.vertex_areas[measured]
    return {
        "reached_vertices": float(reached.mean()),
        "covered_area": float(areas[gap <= COVERED_GAP].sum() / areas.sum()),
        "mean_gap": float(gap.mean()),
    }


NEAREST_NEIGHBOUR_PRODUCTS = 8e10
"""Multiply-adds the features' nearest-neighbour map may cost (queries x V_Y x D; a few seconds)."""


def nearest_neighbour_faces(n_target: int, n_features: int) -> int:
    """Source faces whose features' nearest neighbours fit :data:`NEAREST_NEIGHBOUR_PRODUCTS` (>= 500)."""
    queries = NEAREST_NEIGHBOUR_PRODUCTS / max(n_target * n_features, 1)
    return max(int(queries // 3), 500)  # a sparse sample of faces has about three vertices each


def dense_figures(
    dense: DenseMap,
    source: Mesh,
    target: Mesh,
    source_features: np.ndarray,
    target_features: np.ndarray,
    source_corr: np.ndarray | None = None,
    target_corr: np.ndarray | None = None,
    certified: dict | None = None,
) -> tuple[dict, np.ndarray | None]:
    """Consistency (and, with ground truth, error) of the dense map and of the features' nearest neighbours.

    Parameters
    ----------
    dense : DenseMap
    source, target : Mesh
        The full-resolution meshes (V_X, V_Y vertices).
    source_features, target_features : np.ndarray, shapes (V_X, D), (V_Y, D)
    source_corr, target_corr : np.ndarray, shape (K,), optional
        Reference points for the dense Princeton protocol.
    certified : dict, optional
        :func:`spidermatch.dense.densify.certified_agreement` of the map, reported as it is.

    Returns
    -------
    figures : dict
        ``{"method", "dense": {tears, flips, flipped, degenerate[, geodesic_error]},
        "dense_vertex_map": {...}, "nearest_neighbour": {...}, "coverage": {...},
        "certified": {...}, "scored_faces": {dense, nearest_neighbour}, "metrics_time_s"}``,
        JSON-ready. ``dense`` scores the image points (point form), ``dense_vertex_map`` the
        vertex map of ``dense_matches.csv`` and ``nearest_neighbour`` the features' vertex map,
        all with the same definitions (:mod:`spidermatch.eval.metrics`; ``flips`` is ``flipped`` plus
        ``degenerate``); the geodesic error is that of the vertex map. A large source is scored
        on a fixed sample of its faces (:func:`~spidermatch.eval.metrics.scored_face_count`: fewer
        against larger targets), and the features' map on as many as
        :func:`nearest_neighbour_faces` allows, so that the figures never cost more than the match.
    errors : np.ndarray, shape (K,), or None
        The dense map's error at each reference point (with ground truth).

    """
    start = time.perf_counter()
    faces = sampled_faces(source, scored_face_count(target.n_verts))
    nn_faces = sampled_faces(source, nearest_neighbour_faces(target.n_verts, np.shape(target_features)[1]))
    scored = np.arange(source.n_verts) if nn_faces is None else np.unique(source.faces[nn_faces])
    if source_corr is not None:
        scored = np.union1d(scored, source_corr)
    nearest = np.zeros(source.n_verts, dtype=np.int64)  # the features' map, where it is scored
    nearest[scored] = feature_nearest_neighbours(np.asarray(source_features)[scored], target_features)
    figures = {
        "method": dense.method,
        "dense": consistency(source, target, dense.points(target), dense.face, dense.bary, faces).as_dict(),
        "dense_vertex_map": vertex_map_consistency(source, target, dense.vertex, faces).as_dict(),
        "nearest_neighbour": vertex_map_consistency(source, target, nearest, nn_faces).as_dict(),
        "coverage": target_coverage(dense, source, target),
        "scored_faces": {
            "dense": source.n_faces if faces is None else int(faces.size),
            "nearest_neighbour": source.n_faces if nn_faces is None else int(nn_faces.size),
        },
    }
    if certified is not None:
        figures["certified"] = certified
    errors = None
    if source_corr is not None and target_corr is not None:
        maps = {"dense": dense.vertex, "nearest_neighbour": nearest}
        per_map = geodesic_errors(maps, source_corr, target_corr, target)
        for name, values in per_map.items():
            figures[name]["geodesic_error"] = float(values.mean())
        figures["dense_vertex_map"]["geodesic_error"] = figures["dense"]["geodesic_error"]
        errors = per_map["dense"]
    figures["metrics_time_s"] = round(time.perf_counter() - start, 3)
    logger.info(
        "dense map (%s), vertex form: tears %.4f, flipped %.4f, degenerate %.4f%s; covers %.0f %% of the "
        "target's area; features' nearest neighbours: tears %.4f, flips %.4f%s",
        dense.method,
        figures["dense_vertex_map"]["tears"],
        figures["dense_vertex_map"]["flipped"],
        figures["dense_vertex_map"]["degenerate"],
        _error_text(figures["dense"]),
        100 * figures["coverage"]["covered_area"],
        figures["nearest_neighbour"]["tears"],
        figures["nearest_neighbour"]["flips"],
        _error_text(figures["nearest_neighbour"]),
    )
    return figures, errors


def _error_text(figures: dict) -> str:
    return f", mean geodesic error {figures['geodesic_error']:.4f}" if "geodesic_error" in figures else ""
