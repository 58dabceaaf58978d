"""A dense map in point form (:class:`DenseMap`), its inverse, and points on its image surface."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from spidermatch.geometry.holes import ClosedCopy
from spidermatch.geometry.mesh import Mesh, bary_in_given_corners
from spidermatch.geometry.surface import (
    closest_triangle_points,
    nearest_corner,
    surface_positions,
)


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
        For a partial source: the target vertices the map covers (the overlap; with
        ``overlap_method="reference"`` the target's overlap read on the reference shape,
        :func:`spidermatch.api.with_target_overlap_read`); None for two whole shapes, where
        the map covers the whole target.
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


def inverse_map(dense: DenseMap, source: Mesh, target: Mesh) -> InverseMap:
    """Every target vertex mapped back through ``dense``: its closest point on the image surface.

    The image surface is the source mesh with each vertex at its image point. A target
    vertex goes to the source point (face, barycentric coordinates) whose image is closest
    to it, so the two maps agree: following the inverse and then the forward map moves a
    target vertex by ``gap`` only (zero where the image surface covers it).
    """
    face, bary, gap = closest_on_image_surface(dense, source, target, target.verts)
    return InverseMap(nearest_corner(source, face, bary), face, bary, gap)


def in_given_corners(dense: DenseMap, source: Mesh, target: Mesh) -> DenseMap:
    """``dense`` with its barycentric coordinates in the corner order the meshes' faces were given in.

    The matched meshes may have faces reversed on reading (an inward-facing surface,
    :func:`~spidermatch.geometry.mesh.make_mesh`); the files name the user's faces, so their
    coordinates follow the user's corners: ``bary`` the target's, the inverse map's the source's.
    """
    bary = bary_in_given_corners(target, dense.face, dense.bary)
    inverse = dense.inverse
    if inverse is not None:
        inverse = replace(inverse, bary=bary_in_given_corners(source, inverse.face, inverse.bary))
    return replace(dense, bary=bary, inverse=inverse)


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


def on_given_meshes(dense: DenseMap, source: ClosedCopy | None, target: ClosedCopy | None) -> DenseMap:
    """``dense``, made between closed copies of meshes with small holes, told on the meshes as given.

    Rows of the source's hole centres are dropped, so is the target's; image points on a fan
    face move to the hole's rim (:meth:`ClosedCopy.on_given_surface`), and no vertex named is a
    hole centre. A ``None`` side was matched as given.
    """
    if target is not None:
        face, bary = target.on_given_surface(dense.face, dense.bary)
        vertex = target.given_vertices(dense.vertex, face, bary)
        covered = None if dense.covered is None else dense.covered[: target.n_verts]
        dense = replace(dense, vertex=vertex, face=face, bary=bary, covered=covered)
    if source is not None:
        n = source.n_verts
        dense = replace(dense, vertex=dense.vertex[:n], face=dense.face[:n], bary=dense.bary[:n])
    inverse = dense.inverse
    if inverse is None:
        return dense
    if target is not None:
        n = target.n_verts
        inverse = InverseMap(inverse.vertex[:n], inverse.face[:n], inverse.bary[:n], inverse.gap[:n])
    if source is not None:
        face, bary = source.on_given_surface(inverse.face, inverse.bary)
        inverse = InverseMap(source.given_vertices(inverse.vertex, face, bary), face, bary, inverse.gap)
    return replace(dense, inverse=inverse)
