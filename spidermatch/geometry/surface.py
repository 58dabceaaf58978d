"""Points on a triangle surface: closest points, barycentric coordinates, nearest vertices.

A point on a mesh is stored as a face index (N,) and barycentric coordinates (N, 3)
with respect to that face's three vertices (rows sum to one, entries >= 0).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from spidermatch.geometry.mesh import Mesh

# Candidate faces per query point: the faces whose centroids are nearest.
DEFAULT_CANDIDATES = 16


def barycentric_coordinates(triangles: np.ndarray, points: np.ndarray, clip: bool = True) -> np.ndarray:
    """Barycentric coordinates of ``points`` in the planes of ``triangles``.

    Parameters
    ----------
    triangles : np.ndarray, shape (N, 3, 3)
    points : np.ndarray, shape (N, 3)

    clip : bool
        Clip to [0, 1] and renormalise (points are expected on or next to their
        triangle); without clipping, the coordinates of the orthogonal projection onto
        the triangle's plane (they sum to one and may be negative).

    Returns
    -------
    np.ndarray, shape (N, 3)
        A degenerate triangle gives its first vertex.

    """
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    v0, v1, v2 = b - a, c - a, points - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    denom = d00 * d11 - d01 * d01
    ok = denom > 1e-300
    safe = np.where(ok, denom, 1.0)
    v = np.where(ok, (d11 * d20 - d01 * d21) / safe, 0.0)
    w = np.where(ok, (d00 * d21 - d01 * d20) / safe, 0.0)
    bary = np.stack([1.0 - v - w, v, w], axis=1)
    if not clip:
        return bary
    bary = np.clip(bary, 0.0, None)
    return bary / np.maximum(bary.sum(axis=1, keepdims=True), 1e-300)


def closest_surface_points(
    mesh: Mesh, points: np.ndarray, n_candidates: int = DEFAULT_CANDIDATES, clip: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Closest point of ``mesh`` to each query point, as face + barycentric coordinates.

    The search is over the ``n_candidates`` faces with the nearest centroids plus
    every face around the nearest vertex (exact for points near a reasonably
    shaped surface, which is the use here: points on or next to the mesh).

    Parameters
    ----------
    mesh : Mesh
    points : np.ndarray, shape (N, 3)
    n_candidates : int
    clip : bool
        False: the barycentric coordinates of the projection onto the closest face's
        plane instead of the closest point itself (no collapse of the points beyond a
        convex edge onto that edge; see :func:`barycentric_coordinates`).

    Returns
    -------
    face : np.ndarray, shape (N,), int64
    bary : np.ndarray, shape (N, 3), float64

    """
    return closest_triangle_points(mesh.verts, mesh.faces, points, n_candidates, clip)


def closest_triangle_points(
    verts: np.ndarray,
    faces: np.ndarray,
    points: np.ndarray,
    n_candidates: int = DEFAULT_CANDIDATES,
    clip: bool = True,
    candidates: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`closest_surface_points` on raw arrays (V, 3), (F, 3); degenerate triangles allowed.

    ``candidates`` (N, C), optional: the faces each point may land on (instead of the
    faces nearest in space); -1 entries are padding, each row needs one face.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    if candidates is None:
        candidates = _candidate_faces(verts, faces, points, n_candidates)
    best_face = np.empty(len(points), dtype=np.int64)
    bary = np.empty((len(points), 3))
    for block in _point_blocks(candidates, POINT_BLOCK_PAIRS):
        best_face[block], bary[block] = _closest_among_candidates(
            verts, faces, points[block], candidates[block], clip
        )
    return best_face, bary


def _point_blocks(candidates: np.ndarray, pairs: int) -> list[slice]:
    """Consecutive row ranges of a candidate table (N, C), each with about ``pairs`` candidates (-1: none)."""
    ends = np.cumsum((candidates >= 0).sum(axis=1))
    cuts = np.searchsorted(ends, np.arange(pairs, int(ends[-1]), pairs), side="right")
    bounds = np.unique(np.concatenate([[0], cuts, [len(candidates)]]))
    return [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]


def _closest_among_candidates(
    verts: np.ndarray, faces: np.ndarray, points: np.ndarray, candidates: np.ndarray, clip: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Face (N,) and barycentric coordinates (N, 3) of each point's closest candidate face (N, C)."""
    row, face = _distinct_pairs(candidates)
    paired = points[row]
    closest = _closest_points_blockwise(verts[faces[face]], paired)
    distance = np.linalg.norm(closest - paired, axis=1)
    # The nearest candidate of each point: sort by (point, distance), take each point's first.
    order = np.lexsort((distance, row))
    first = order[np.concatenate([[0], np.flatnonzero(np.diff(row[order])) + 1])]
    if len(first) != len(points):
        raise ValueError("every point needs at least one candidate face")
    best_face = face[first]
    if clip:
        bary = barycentric_coordinates(verts[faces[best_face]], closest[first])
    else:
        bary = barycentric_coordinates(verts[faces[best_face]], points, clip=False)
    return best_face.astype(np.int64), bary


# Triangle-point pairs per call of trimesh's closest_point (bounds its temporary arrays).
PAIR_BLOCK = 65536
# Candidate faces per block of points in closest_triangle_points: its pair arrays (about 200 bytes
# a pair) stay near 50 MB however many points are asked (a 320k-vertex scan asked 7.9 M pairs at once).
POINT_BLOCK_PAIRS = 262144


def _distinct_pairs(candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(point, face) pairs of a candidate table (N, C), without padding (-1) or repeats, row-sorted."""
    ordered = np.sort(candidates, axis=1)
    keep = ordered >= 0
    keep[:, 1:] &= ordered[:, 1:] != ordered[:, :-1]
    row = np.broadcast_to(np.arange(len(ordered), dtype=np.int64)[:, None], ordered.shape)
    return row[keep], ordered[keep].astype(np.int64)


def _closest_points_blockwise(triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Closest point of each triangle (N, 3, 3) to its point (N, 3), shape (N, 3)."""
    from trimesh.triangles import closest_point

    out = np.empty_like(points)
    for start in range(0, len(points), PAIR_BLOCK):
        stop = start + PAIR_BLOCK
        out[start:stop] = closest_point(triangles[start:stop], points[start:stop])
    return out


def _candidate_faces(
    verts: np.ndarray, faces: np.ndarray, points: np.ndarray, n_candidates: int
) -> np.ndarray:
    """(N, C) face indices: nearest centroids, then the faces of the nearest vertex (padded)."""
    centroids = verts[faces].mean(axis=1)
    k = min(n_candidates, len(faces))
    _, by_centroid = cKDTree(centroids).query(points, k=k)
    by_centroid = np.asarray(by_centroid).reshape(len(points), k)
    _, nearest_vertex = cKDTree(verts).query(points)
    ring = face_table(faces, len(verts))[nearest_vertex]
    ring = np.where(ring >= 0, ring, ring[:, :1])
    return np.concatenate([by_centroid, ring], axis=1)


def vertex_face_table(mesh: Mesh) -> np.ndarray:
    """Faces around each vertex, shape (V, max valence), padded with -1.

    Kept with the mesh (read-only), like its rings: the projections near a vertex's rings ask
    for it a block of points at a time.
    """

    def table() -> np.ndarray:
        faces_around = face_table(mesh.faces, mesh.n_verts)
        faces_around.flags.writeable = False
        return faces_around

    return mesh.cached("vertex_face_table", table)


def face_table(faces: np.ndarray, n_verts: int) -> np.ndarray:
    """Faces (F, 3) around each of ``n_verts`` vertices, shape (V, max valence), padded with -1."""
    return padded_rows(faces.reshape(-1), np.repeat(np.arange(len(faces)), 3), n_verts)


def padded_rows(keys: np.ndarray, values: np.ndarray, n_rows: int, fill: int = -1) -> np.ndarray:
    """Group ``values`` (M,) by ``keys`` (M,) in [0, n_rows): one row per key, in input order.

    Returns
    -------
    np.ndarray, shape (n_rows, max group size (at least 1)), int64
        Padded with ``fill``.

    """
    keys, values = np.asarray(keys, dtype=np.int64), np.asarray(values, dtype=np.int64)
    order = np.argsort(keys, kind="stable")
    counts = np.bincount(keys, minlength=n_rows)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(len(keys)) - np.repeat(starts, counts)
    table = np.full((n_rows, max(int(counts.max(initial=0)), 1)), fill, dtype=np.int64)
    table[keys[order], slot] = values[order]
    return table


def vertex_rings(mesh: Mesh) -> np.ndarray:
    """Each vertex and its neighbours, shape (V, 1 + max degree), padded with the vertex itself.

    Kept with the mesh (read-only), like its edges: the dense map and its figures ask for the
    target's rings in every round.
    """

    def rings() -> np.ndarray:
        edges = mesh.edges
        neighbours = padded_rows(edges.reshape(-1), edges[:, ::-1].reshape(-1), mesh.n_verts)
        own = np.arange(mesh.n_verts)[:, None]
        return np.hstack([own, np.where(neighbours >= 0, neighbours, own)])

    return mesh.cached("vertex_rings", rings)


def surface_positions(mesh: Mesh, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """3D positions of points given as face (N,) + barycentric (N, 3), shape (N, 3)."""
    return np.einsum("nk,nkd->nd", bary, mesh.verts[mesh.faces[face]])


def nearest_corner(mesh: Mesh, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """The vertex of each point's face nearest (Euclidean) to the point, shape (N,), int64."""
    corners = mesh.faces[face]
    positions = surface_positions(mesh, face, bary)
    distance = np.linalg.norm(mesh.verts[corners] - positions[:, None, :], axis=2)
    return corners[np.arange(len(face)), np.argmin(distance, axis=1)].astype(np.int64)


def vertex_points(mesh: Mesh, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Surface-point form of vertices: an incident face each and a one-hot bary, (N,), (N, 3)."""
    vertices = np.asarray(vertices, dtype=np.int64)
    face = vertex_face_table(mesh)[vertices, 0]
    bary = (mesh.faces[face] == vertices[:, None]).astype(np.float64)
    return face, bary


def occluded(points: np.ndarray, camera: np.ndarray, faces: np.ndarray, tolerance: float) -> np.ndarray:
    """Which points lie behind the surface, as seen by the camera.

    Parameters
    ----------
    points : np.ndarray, shape (P, 3)
        Camera coordinates (z towards the camera).
    camera : np.ndarray, shape (V, 3)
        Camera coordinates of the mesh vertices.
    faces : np.ndarray, shape (F, 3)
    tolerance : float
        Depth margin, so that points on the surface are not hidden by their own triangles.

    Returns
    -------
    np.ndarray, shape (P,), bool
        True where some triangle covers the point and is nearer the camera by more than ``tolerance``.
    """
    corner, edge_u, edge_v = camera[faces[:, 0]], camera[faces[:, 1]], camera[faces[:, 2]]
    edge_u, edge_v = edge_u - corner, edge_v - corner
    det = edge_u[:, 0] * edge_v[:, 1] - edge_u[:, 1] * edge_v[:, 0]
    usable = np.abs(det) > 1e-14
    corner, edge_u, edge_v, det = corner[usable], edge_u[usable], edge_v[usable], det[usable]
    hidden = np.zeros(len(points), dtype=bool)
    for start in range(0, len(points), 256):
        chunk = points[start : start + 256]
        dx = chunk[:, None, 0] - corner[None, :, 0]
        dy = chunk[:, None, 1] - corner[None, :, 1]
        u = (dx * edge_v[:, 1] - dy * edge_v[:, 0]) / det
        v = (edge_u[:, 0] * dy - edge_u[:, 1] * dx) / det
        depth = corner[:, 2] + u * edge_u[:, 2] + v * edge_v[:, 2]
        covered = (u >= 0) & (v >= 0) & (u + v <= 1) & (depth > chunk[:, None, 2] + tolerance)
        hidden[start : start + 256] = covered.any(axis=1)
    return hidden
