"""The certified map interpolated to every full-resolution source vertex.

Each vertex is located on the decimated source by its coarse patch and carried to the
same barycentric place of the image triangle; the search for the closest point is pruned
to nearby patches where that cannot change the answer.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from spidermatch.dense.feature_search import CANDIDATE_CELLS, NEAR_VERTICES
from spidermatch.geometry.coarse import coarse_labels, faces_by_label, project_onto_coarse
from spidermatch.geometry.mesh import Mesh, mean_incident_edge_length
from spidermatch.geometry.remesh import Decimated
from spidermatch.geometry.surface import (
    closest_triangle_points,
    face_table,
    padded_rows,
    surface_positions,
)

PRUNE_WIDTH = 600
"""Candidate faces per point above which image points are located among the faces near them only."""


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
