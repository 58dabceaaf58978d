"""Per-vertex features of a pair, computed on at most ``max_vertices`` vertices per mesh.

Spectral descriptors and DiffusionNet need Laplacian eigenpairs; on a raw scan of 300 000
vertices those alone take minutes and gigabytes, yet the product graph sees a few hundred
vertices and the dense stage reads features only to rank nearby candidates. A mesh with
more vertices than the cap is therefore decimated to about the cap, its features are
computed there, and each full-resolution vertex gets the inverse-distance-weighted mean of
its nearest decimated vertices' features (rows re-normalised). ``bench/bench_user_copies.py``
measures what this costs in accuracy. A mesh matched as a whole shape that has small holes (a
scanner's, see :data:`spidermatch.geometry.mesh.SMALL_HOLE_SHARE`), or a part's target closed but
for such holes, gets its features on a copy with those holes closed by fans
(:func:`closed_for_features`). A mesh rough with scan noise against its own edges (as shown to
the extractor, after the cap) gets them on a smoothed copy of the same vertices
(:mod:`spidermatch.geometry.smoothing`).
"""

from __future__ import annotations

import logging
import time

import numpy as np
from scipy.spatial import cKDTree

from spidermatch import defaults
from spidermatch.dense.feature_search import feature_nearest_neighbours
from spidermatch.geometry.holes import sides_to_close
from spidermatch.geometry.mesh import Mesh, small_holes_closed
from spidermatch.geometry.overlap import ReferenceImages
from spidermatch.geometry.remesh import decimate
from spidermatch.geometry.smoothing import ROUGH, smoothed_if_rough
from spidermatch.model.costs import unit_rows

logger = logging.getLogger(__name__)

MAX_FEATURE_VERTICES = int(defaults.match_option("features_max_vertices"))
"""Default cap: larger meshes get their features on a decimated copy (``None``/0: no cap)."""

CARRY_NEIGHBOURS = 4
"""Decimated vertices whose features are averaged into each full-resolution vertex."""

CARRY_BLOCK = 50_000
"""Full-resolution vertices carried per block (bounds the (block, k, D) temporary)."""


def pair_features(
    extractor,
    source: Mesh,
    target: Mesh,
    max_vertices: int | None = MAX_FEATURE_VERTICES,
    record: dict | None = None,
    *,
    partial: bool = False,
    overlap: bool = False,
):
    """Features of both meshes, centred, each computed on at most ``max_vertices`` vertices.

    Parameters
    ----------
    extractor : callable
        ``mesh -> (V, D)``; one with ``pair_features(source, target)`` (test-time
        adaptation) is given both meshes at once.
    source, target : Mesh
    max_vertices : int, optional
        The cap (None or 0: every mesh at its own resolution).
    record : dict, optional
        Receives under ``computed_on_vertices`` each capped mesh's name and the copy's vertex
        count, under ``smoothed_for_features`` each smoothed mesh's name, median roughness and
        Taubin steps (:func:`shown_to_extractor`).
    partial : bool
        The source is a part of the target: an extractor with ``part_features(part, whole)``
        is given both meshes at once (the part measured in the whole's unit).
    overlap : bool
        Both meshes are parts of one surface: an extractor with ``parts_features(x, y)`` is
        given both at once (in one unit of length); it takes precedence over ``partial``.

    Returns
    -------
    source_features : np.ndarray, shape (V_src, D)
    target_features : np.ndarray, shape (V_tgt, D)

    """
    method = "parts_features" if overlap else "part_features" if partial else "pair_features"
    wholes = sides_to_close(target, partial, overlap)
    if not hasattr(extractor, method):
        return tuple(
            mesh_features(extractor, mesh, max_vertices, record, is_whole)
            for mesh, is_whole in zip((source, target), wholes)
        )
    shown, back = _shown_pair(source, target, wholes, max_vertices, record)
    return tuple(back(side, features) for side, features in enumerate(getattr(extractor, method)(*shown)))


def part_feature_options(
    extractor,
    source: Mesh,
    target: Mesh,
    count: int,
    max_vertices: int | None = MAX_FEATURE_VERTICES,
    record: dict | None = None,
) -> tuple[list[tuple[str, np.ndarray]], np.ndarray]:
    """A partial source's features in each of its ``count`` best presentations, and the target's.

    An extractor with ``part_feature_options(part, whole, count)`` (an orientation search)
    gives several; any other gives one, its :func:`pair_features` with ``partial=True``.

    Returns
    -------
    options : list of (str, np.ndarray (V_src, D))
        Each presentation's description (empty without a search) and the source's features in it.
    target_features : np.ndarray, shape (V_tgt, D)
    """
    if count <= 1 or not hasattr(extractor, "part_feature_options"):
        feat_x, feat_y = pair_features(extractor, source, target, max_vertices, record, partial=True)
        return [("", feat_x)], feat_y
    shown, back = _shown_pair(source, target, sides_to_close(target, True), max_vertices, record)
    options, feat_y = extractor.part_feature_options(*shown, count)
    return [(label, back(0, features)) for label, features in options], back(1, feat_y)


def reference_images(
    extractor,
    source: Mesh,
    target: Mesh,
    max_vertices: int | None = MAX_FEATURE_VERTICES,
    record: dict | None = None,
):
    """Two parts read on the extractor's whole reference shape, each as a part of it, or None.

    Each part gets the partial mode's features against the reference
    (:func:`pair_features` with ``partial=True``: turned and placed on it, measured in its unit, a
    part of another size fitted to it), and each vertex its most similar reference vertex.
    An extractor without ``reference_mesh`` (WKS, joined networks) gives None.

    Returns
    -------
    spidermatch.geometry.overlap.ReferenceImages or None
    """
    reference = getattr(extractor, "reference_mesh", None)
    if reference is None:
        return None
    images = []
    for part in (source, target):
        feat_part, feat_reference = pair_features(
            extractor, part, reference, max_vertices, record, partial=True
        )
        images.append(feature_nearest_neighbours(feat_part, feat_reference))
    return ReferenceImages(reference, *images)


def _shown_pair(source: Mesh, target: Mesh, wholes, max_vertices, record):
    """The meshes an extractor is shown for a pair (centred, closed where whole, capped) and the way back.

    Returns the two meshes shown and ``back(side, features)``: features computed on side 0
    (source) or 1 (target) as shown, carried to that mesh's own vertices.
    """
    centred = [
        closed_for_features(mesh.centred(), is_whole) for mesh, is_whole in zip((source, target), wholes)
    ]
    capped = [capped_mesh(mesh, max_vertices, record) for mesh in centred]
    shown = [shown_to_extractor(mesh if low is None else low, record) for low, mesh in zip(capped, centred)]
    given = (source, target)

    def back(side: int, features: np.ndarray) -> np.ndarray:
        return on_full_mesh(features, capped[side], centred[side])[: given[side].n_verts]

    return shown, back


def closed_for_features(mesh: Mesh, whole: bool = True) -> Mesh:
    """``mesh`` with its small holes closed (:func:`small_holes_closed`) when it is a whole shape.

    A scanner's small hole in a whole shape is not part of the surface the descriptors describe:
    the Laplacian of the holed mesh has a boundary there that the closed training shapes never
    had. Such a mesh's features are computed on the closed copy (its own vertices first) and its
    own rows kept; so are those of a part's whole target. Parts (``whole=False``) are left as
    they are: the partial recipe trains on cuts that have such holes, and closing them did not
    help there (measured in docs/partial.md, "Small holes are not cuts").
    """
    return small_holes_closed(mesh) if whole else mesh


def mesh_features(
    extractor,
    mesh: Mesh,
    max_vertices: int | None = MAX_FEATURE_VERTICES,
    record: dict | None = None,
    whole: bool = True,
) -> np.ndarray:
    """Features (V, D) of one mesh (centred) through ``extractor``, on at most ``max_vertices``.

    ``whole``: the mesh is matched as a whole shape, so its small holes are closed first.
    """
    centred = closed_for_features(mesh.centred(), whole)
    low = capped_mesh(centred, max_vertices, record)
    shown = shown_to_extractor(centred if low is None else low, record)
    return on_full_mesh(extractor(shown), low, centred)[: mesh.n_verts]


def shown_to_extractor(mesh: Mesh, record: dict | None = None) -> Mesh:
    """``mesh`` (the one an extractor is given), smoothed first if scan noise makes it rough.

    The copy has the same vertices in the same order (:func:`smoothed_if_rough`), so the
    features it gets are ``mesh``'s rows; ``record["smoothed_for_features"]`` names it.
    """
    smoothed, steps, roughness = smoothed_if_rough(mesh)
    if steps:
        logger.info(
            "%s: rough with scan noise (median roughness %.2f of its edges, above %.2f): features "
            "computed on a copy smoothed in %d Taubin steps",
            mesh.name,
            roughness,
            ROUGH,
            steps,
        )
        if record is not None:
            entry = {"median_roughness": round(roughness, 3), "taubin_steps": steps}
            record.setdefault("smoothed_for_features", {})[mesh.name] = entry
    return smoothed


def on_full_mesh(features, low: Mesh | None, full: Mesh) -> np.ndarray:
    """``features`` (V_low, D) of the capped copy ``low`` carried to ``full`` (as they are without a copy)."""
    features = np.asarray(features)
    return features if low is None else carry_features(features, low, full)


def capped_mesh(mesh: Mesh, max_vertices: int | None, record: dict | None = None) -> Mesh | None:
    """``mesh`` decimated to about ``max_vertices`` vertices, or None when it has no more.

    The copy keeps the mesh's name, so that messages and the orientation search's log name
    the user's file; ``record["computed_on_vertices"]`` receives that name and the copy's vertex count.
    """
    if not max_vertices or mesh.n_verts <= max_vertices:
        return None
    start = time.perf_counter()
    low = decimate(mesh, 2 * int(max_vertices)).mesh
    logger.info(
        "%s: features computed on %d of its %d vertices (features_max_vertices=%d), then carried to all "
        "(decimation %.1f s)",
        mesh.name,
        low.n_verts,
        mesh.n_verts,
        max_vertices,
        time.perf_counter() - start,
    )
    if record is not None:
        record.setdefault("computed_on_vertices", {})[mesh.name] = low.n_verts
    return Mesh(low.verts, low.faces, mesh.name, mesh.notes)


def carry_features(low_features: np.ndarray, low: Mesh, full: Mesh) -> np.ndarray:
    """Features of the decimated mesh carried to every vertex of the full one.

    Parameters
    ----------
    low_features : np.ndarray, shape (V_low, D)
    low : Mesh
        The decimated copy, in the frame of ``full``.
    full : Mesh

    Returns
    -------
    np.ndarray, shape (V_full, D)
        Inverse-distance-weighted means of the ``CARRY_NEIGHBOURS`` nearest decimated
        vertices' rows, each row of unit length (a vertex kept exactly takes its own row).

    """
    tree = cKDTree(low.verts)
    k = min(CARRY_NEIGHBOURS, low.n_verts)
    carried = np.empty((full.n_verts, low_features.shape[1]), dtype=np.float64)
    for start in range(0, full.n_verts, CARRY_BLOCK):
        stop = min(start + CARRY_BLOCK, full.n_verts)
        distance, index = tree.query(full.verts[start:stop], k=k)
        distance, index = distance.reshape(stop - start, k), index.reshape(stop - start, k)
        weights = 1.0 / np.maximum(distance, 1e-12 * np.sqrt(full.area))
        weights /= weights.sum(axis=1, keepdims=True)
        carried[start:stop] = np.einsum("nk,nkd->nd", weights, low_features[index])
    return unit_rows(carried)
