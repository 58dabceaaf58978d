"""Immutable triangle meshes, their validation and their edge graphs.

Array conventions used throughout spidermatch: vertices are float64 ``(V, 3)``,
faces int64 ``(F, 3)``, undirected edges int64 ``(E, 2)`` with ``i < j``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

logger = logging.getLogger(__name__)


class MeshError(ValueError):
    """A mesh is unusable; the message names the mesh (usually its file) and the problem."""


@dataclass(frozen=True, eq=False)
class Mesh:
    """A validated triangle mesh.

    Attributes
    ----------
    verts : np.ndarray, shape (V, 3), float64
        Vertex positions (read-only).
    faces : np.ndarray, shape (F, 3), int64
        Vertex indices of each triangle (read-only).
    name : str
        Where the mesh came from (file path or generator name), used in messages.
    notes : tuple of str
        What was repaired when the mesh was made (e.g. faces re-oriented), for logs and reports.

    """

    verts: np.ndarray
    faces: np.ndarray
    name: str = "<mesh>"
    notes: tuple = field(default=(), compare=False)
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        verts = np.array(self.verts, dtype=np.float64, copy=True)
        faces = np.array(self.faces, dtype=np.int64, copy=True)
        verts.setflags(write=False)
        faces.setflags(write=False)
        object.__setattr__(self, "verts", verts)
        object.__setattr__(self, "faces", faces)

    @property
    def n_verts(self) -> int:
        """Number of vertices V."""
        return int(self.verts.shape[0])

    @property
    def n_faces(self) -> int:
        """Number of faces F."""
        return int(self.faces.shape[0])

    def cached(self, key: str, compute):
        """``compute()`` the first time ``key`` is asked for, then the kept value (arrays read-only).

        For data derived from the mesh alone (its edges, areas, vertex rings), which the mesh
        never changes after it is made.
        """
        if key not in self._cache:
            value = compute()
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            self._cache[key] = value
        return self._cache[key]

    @property
    def face_areas(self) -> np.ndarray:
        """Area of each face, shape (F,)."""
        return self.cached("face_areas", lambda: triangle_areas(self.verts, self.faces))

    @property
    def area(self) -> float:
        """Total surface area."""
        return self.cached("area", lambda: float(self.face_areas.sum()))

    @property
    def vertex_areas(self) -> np.ndarray:
        """A third of the area of every face at each of its vertices, shape (V,)."""

        def lumped() -> np.ndarray:
            areas = np.zeros(self.n_verts)
            np.add.at(areas, self.faces.reshape(-1), np.repeat(self.face_areas / 3.0, 3))
            return areas

        return self.cached("vertex_areas", lumped)

    @property
    def edge_lengths(self) -> np.ndarray:
        """Length of each of :attr:`edges`, shape (E,)."""
        return self.cached(
            "edge_lengths",
            lambda: np.linalg.norm(self.verts[self.edges[:, 0]] - self.verts[self.edges[:, 1]], axis=1),
        )

    @property
    def median_edge_length(self) -> float:
        """The median of :attr:`edge_lengths`."""
        return self.cached("median_edge_length", lambda: float(np.median(self.edge_lengths)))

    @property
    def edges(self) -> np.ndarray:
        """Unique undirected mesh edges, shape (E, 2), with ``edges[:, 0] < edges[:, 1]``."""
        return self.cached("edges", lambda: unique_edges(self.faces))

    @property
    def augmented_edges(self) -> np.ndarray:
        """Mesh edges plus, for each interior edge, the edge joining its two opposite vertices.

        Returns
        -------
        np.ndarray, shape (E_aug, 2)
            Unique undirected edges with ``i < j`` (method.md section 2).

        """
        return self.cached("augmented_edges", lambda: augment_edges(self.faces))

    def with_positions(self, verts: np.ndarray) -> Mesh:
        """The same faces, name and notes at other vertex positions ``verts`` (V, 3).

        What depends on the faces alone (the edges) is carried over, not computed again.
        """
        moved = Mesh(verts, self.faces, self.name, self.notes)
        if "edges" in self._cache:
            moved._cache["edges"] = self._cache["edges"]
        return moved

    def centred(self) -> Mesh:
        """Return a copy translated so that the mean vertex lies at the origin."""
        return Mesh(self.verts - self.verts.mean(axis=0), self.faces, self.name, self.notes)

    def edge_graph(self, augmented: bool = False) -> sp.csr_matrix:
        """Symmetric adjacency weighted by Euclidean edge length, shape (V, V); cached, do not modify."""
        key = "augmented_edge_graph" if augmented else "edge_graph"
        edges = self.augmented_edges if augmented else self.edges
        return self.cached(key, lambda: edge_length_graph(self.verts, edges))

    @property
    def vertex_tree(self) -> cKDTree:
        """KD-tree of the vertex positions (cached)."""
        return self.cached("vertex_tree", lambda: cKDTree(self.verts))


def triangle_areas(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area of each triangle.

    Parameters
    ----------
    verts : np.ndarray, shape (V, 3)
    faces : np.ndarray, shape (F, 3)

    Returns
    -------
    np.ndarray, shape (F,)

    """
    a, b, c = (verts[faces[:, k]] for k in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def principal_axes(points: np.ndarray) -> np.ndarray:
    """Unit principal axes of points (N, 3) as the columns of a rotation (3, 3).

    Largest spread first; the last axis's sign makes the determinant +1.
    """
    centred = np.asarray(points, dtype=np.float64) - np.mean(points, axis=0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    axes = vectors[:, ::-1].copy()
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return axes


def vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals, shape (V, 3)."""
    face_normals = np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]])
    normals = np.zeros_like(verts)
    for k in range(3):
        np.add.at(normals, faces[:, k], face_normals)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return normals / np.maximum(length, 1e-12)


def face_edges(faces: np.ndarray) -> np.ndarray:
    """The three sorted edges of every face, shape (F, 3, 2); edge k is opposite corner k."""
    opposite = np.stack([faces[:, [1, 2]], faces[:, [2, 0]], faces[:, [0, 1]]], axis=1)
    return np.sort(opposite, axis=2)


def unique_edges(faces: np.ndarray) -> np.ndarray:
    """Unique undirected edges of a triangle list, shape (E, 2), rows sorted lexicographically."""
    all_edges = face_edges(faces).reshape(-1, 2)
    return np.unique(all_edges, axis=0)


def augment_edges(faces: np.ndarray) -> np.ndarray:
    """Edges plus the 'flip' edge across every interior edge.

    For an interior edge (i, j) shared by triangles (i, j, k) and (j, i, l) the
    augmented edge is (k, l). Duplicates and self-loops are removed.

    Parameters
    ----------
    faces : np.ndarray, shape (F, 3)

    Returns
    -------
    np.ndarray, shape (E_aug, 2), sorted rows with ``i < j``.

    """
    edges_per_face = face_edges(faces).reshape(-1, 2)
    opposite_vertex = faces.reshape(-1)  # corner k is opposite edge k
    order = np.lexsort((edges_per_face[:, 1], edges_per_face[:, 0]))
    sorted_edges = edges_per_face[order]
    same_as_next = np.all(sorted_edges[1:] == sorted_edges[:-1], axis=1)
    first = order[:-1][same_as_next]
    second = order[1:][same_as_next]
    flips = np.sort(np.stack([opposite_vertex[first], opposite_vertex[second]], axis=1), axis=1)
    flips = flips[flips[:, 0] != flips[:, 1]]
    return np.unique(np.concatenate([edges_per_face, flips]), axis=0)


def directed_edges(edges: np.ndarray) -> np.ndarray:
    """Both orientations of undirected edges, shape (2E, 2): first all (i, j), then all (j, i)."""
    return np.concatenate([edges, edges[:, ::-1]])


def edge_length_graph(verts: np.ndarray, edges: np.ndarray) -> sp.csr_matrix:
    """Symmetric sparse matrix with the Euclidean length of each edge, shape (V, V)."""
    lengths = np.linalg.norm(verts[edges[:, 0]] - verts[edges[:, 1]], axis=1)
    n = verts.shape[0]
    rows = np.concatenate([edges[:, 0], edges[:, 1]])
    cols = np.concatenate([edges[:, 1], edges[:, 0]])
    graph = sp.coo_matrix((np.concatenate([lengths, lengths]), (rows, cols)), shape=(n, n))
    return graph.tocsr()


def validate_mesh(verts: np.ndarray, faces: np.ndarray, name: str = "<mesh>") -> np.ndarray:
    """Check that (verts, faces) is a usable triangle mesh; raise :class:`MeshError` if not.

    Checks, in order: array shapes and number types, empty mesh, non-finite coordinates,
    faces that index missing vertices, degenerate faces (repeated vertex or zero area),
    vertices used by no face, non-manifold edges (more than two faces; duplicate faces named as such),
    non-manifold vertices (two fans of faces meeting at one vertex, a "bowtie"),
    several connected components and a non-orientable surface (a Moebius strip). Faces
    that are only oriented inconsistently pass: :func:`make_mesh` re-orients them.

    Parameters
    ----------
    verts : np.ndarray, shape (V, 3)
    faces : np.ndarray, shape (F, 3)
    name : str
        Named in every error message (typically the file path).

    Returns
    -------
    np.ndarray, shape (F,), bool
        Faces to reverse for one consistent orientation (see :func:`faces_to_flip`).

    """
    verts = np.asarray(verts)
    faces = np.asarray(faces)
    _check_shapes(verts, faces, name)
    _check_number_types(verts, faces, name)
    verts = np.asarray(verts, dtype=np.float64)  # areas of float16 (or int) coordinates would round to 0
    _check_finite(verts, name)
    _check_face_indices(faces, verts.shape[0], name)
    _check_precision(verts, faces, name)
    _check_degenerate_faces(verts, faces, name)
    _check_unreferenced(faces, verts.shape[0], name)
    _check_manifold_edges(faces, name)
    _check_manifold_vertices(faces, name)
    _check_single_component(faces, verts.shape[0], name)
    return faces_to_flip(faces, name)


def _check_shapes(verts: np.ndarray, faces: np.ndarray, name: str) -> None:
    if verts.size == 0 or faces.size == 0:
        raise MeshError(
            f"{name}: empty mesh ({verts.shape[0] if verts.ndim else 0} vertices, "
            f"{faces.shape[0] if faces.ndim else 0} faces)"
        )
    if verts.ndim != 2 or verts.shape[1] != 3:
        raise MeshError(f"{name}: vertices must have shape (V, 3), got {verts.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise MeshError(f"{name}: faces must be triangles with shape (F, 3), got {faces.shape}")


def _check_number_types(verts: np.ndarray, faces: np.ndarray, name: str) -> None:
    if verts.dtype.kind not in "fiu":
        kind = "complex numbers" if verts.dtype.kind == "c" else f"values of dtype {verts.dtype}"
        raise MeshError(f"{name}: vertex coordinates must be real numbers, got {kind}")
    if not np.issubdtype(faces.dtype, np.integer):
        swapped = verts.dtype.kind in "iu" and faces.dtype.kind == "f"
        hint = "; the vertices are integers and the faces not: given as (faces, vertices)?" if swapped else ""
        raise MeshError(f"{name}: face indices must be integers, got dtype {faces.dtype}{hint}")


PRECISION_EDGE_SHARE = 0.1
"""Largest single-precision step, as a share of the mean edge length, of coordinates stored in float32."""


def _check_precision(verts: np.ndarray, faces: np.ndarray, name: str) -> None:
    """Refuse coordinates rounded to single precision at a magnitude that erases the shape.

    A georeferenced scan saved in float32 a million metres from the origin keeps steps of 6 cm:
    a body's vertices fall onto a few planes, and matching it gives a wrong map that looks fine
    (FAUST_r 070 -> 071 moved by 1e6 m in float32: `optimal`, `plausible`, error 0.42 against
    0.038). Coordinates that are all exactly float32 numbers are checked against float32's step
    at their largest magnitude on each axis. A mesh in double precision is not judged: its
    coordinates are what the file says (a grid-like CAD mesh's repeated values are its shape).
    """
    if verts.dtype != np.float64 or not np.array_equal(verts.astype(np.float32), verts):
        return
    reach = np.abs(verts).max(axis=0)  # (3,)
    step = np.spacing(reach.astype(np.float32)).astype(np.float64)
    edges = verts[faces[:, [1, 2, 0]]] - verts[faces]
    mean_edge = float(np.linalg.norm(edges, axis=2).mean())
    if mean_edge > 0 and step.max() > PRECISION_EDGE_SHARE * mean_edge:
        far = float(reach.max())
        raise MeshError(
            f"{name}: coordinates in single precision (float32) reach {far:.3g} from the origin, where "
            f"float32 steps by {step.max():.3g}: {step.max() / mean_edge:.1f} times the mean edge length "
            f"({mean_edge:.3g}), so the shape is lost to rounding; save it in double precision, or moved "
            "near the origin (subtract its centre) before storing it in float32"
        )


def _check_finite(verts: np.ndarray, name: str) -> None:
    bad = ~np.isfinite(verts).all(axis=1)
    if bad.any():
        rows = np.flatnonzero(bad)
        raise MeshError(
            f"{name}: {rows.size} vertices have NaN or infinite coordinates "
            f"(first: vertex {rows[0]} = {verts[rows[0]].tolist()})"
        )


def _check_face_indices(faces: np.ndarray, n_verts: int, name: str) -> None:
    bad = (faces < 0) | (faces >= n_verts)
    if bad.any():
        row = int(np.flatnonzero(bad.any(axis=1))[0])
        raise MeshError(
            f"{name}: face {row} = {faces[row].tolist()} refers to a vertex that does not exist "
            f"(the mesh has {n_verts} vertices, valid indices 0..{n_verts - 1})"
        )


def degenerate_faces(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces (F,) bool with a repeated vertex or zero area (relative to the mesh's extent)."""
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    extent = float(np.ptp(verts, axis=0).max()) or 1.0
    return repeated | (triangle_areas(verts, faces) <= 1e-14 * extent**2)


def _check_degenerate_faces(verts: np.ndarray, faces: np.ndarray, name: str) -> None:
    bad = np.flatnonzero(degenerate_faces(verts, faces))
    if bad.size:
        raise MeshError(
            f"{name}: {bad.size} degenerate faces (repeated vertex or zero area), "
            f"first: face {bad[0]} = {faces[bad[0]].tolist()}"
        )


def _check_unreferenced(faces: np.ndarray, n_verts: int, name: str) -> None:
    used = np.zeros(n_verts, dtype=bool)
    used[faces.reshape(-1)] = True
    if not used.all():
        unused = np.flatnonzero(~used)
        raise MeshError(
            f"{name}: {unused.size} vertices are not used by any face "
            f"(first: vertex {unused[0]}); remove them before matching"
        )


def duplicate_faces(faces: np.ndarray) -> np.ndarray:
    """Faces (F,) bool that repeat the three vertices of an earlier face (in any order or orientation)."""
    _, first = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
    repeated = np.ones(len(faces), dtype=bool)
    repeated[first] = False
    return repeated


def _check_duplicate_faces(faces: np.ndarray, name: str) -> None:
    copies = np.flatnonzero(duplicate_faces(faces))
    if copies.size:
        first = faces[copies[0]]
        original = int(np.flatnonzero((np.sort(faces, axis=1) == np.sort(first)).all(axis=1))[0])
        raise MeshError(
            f"{name}: {copies.size} duplicate faces (the three vertices of another face again; first: face "
            f"{copies[0]} repeats face {original}, {first.tolist()})"  # matching adds what repair=true keeps
        )


def edge_face_counts(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unique edges (E, 2), the unique edge of each face edge (3F,) and how many faces each has (E,)."""
    edges, inverse, counts = np.unique(
        face_edges(faces).reshape(-1, 2), axis=0, return_inverse=True, return_counts=True
    )
    return edges, inverse.reshape(-1), counts


def _check_manifold_edges(faces: np.ndarray, name: str) -> None:
    edges, _, counts = edge_face_counts(faces)
    bad = counts > 2
    if bad.any():
        _check_duplicate_faces(faces, name)  # a copy of a face crowds its edges: named as what it is
        first = edges[bad][0]
        raise MeshError(
            f"{name}: {int(bad.sum())} non-manifold edges shared by more than two faces "
            f"(first: edge {first.tolist()} in {int(counts[bad][0])} faces)"
        )


def shared_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every face edge, and the two entries of each edge that two faces share.

    Returns ``edges`` (3F, 2) sorted pairs (edge k of face f, opposite corner k, is entry
    3f + k), and ``first``, ``second`` (S,) each: the two entries of every shared edge.
    ``faces`` (F, 3) must have at most two faces on every edge.
    """
    edges = face_edges(faces).reshape(-1, 2)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    same = np.all(edges[order[1:]] == edges[order[:-1]], axis=1)
    return edges, order[:-1][same], order[1:][same]


def vertex_fans(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fans of faces around each vertex: corners linked across the edges they share.

    Parameters
    ----------
    faces : np.ndarray, shape (F, 3)
        Faces whose edges have at most two faces each.

    Returns
    -------
    vertex : np.ndarray, shape (3F,)
        Vertex of each face corner (corner c of face f is entry 3f + c).
    fan : np.ndarray, shape (3F,)
        Label of the fan each corner belongs to; a manifold vertex's corners share one label.

    """
    n_corners = faces.size
    edges, first, second = shared_edges(faces)
    face_of = np.repeat(np.arange(len(faces)), 3)
    corner_a = face_of[first] * 3 + np.argmax(faces[face_of[first]] == edges[first, :1], axis=1)
    corner_b = face_of[second] * 3 + np.argmax(faces[face_of[second]] == edges[first, :1], axis=1)
    corner_c = face_of[first] * 3 + np.argmax(faces[face_of[first]] == edges[first, 1:], axis=1)
    corner_d = face_of[second] * 3 + np.argmax(faces[face_of[second]] == edges[first, 1:], axis=1)
    rows = np.concatenate([corner_a, corner_c])
    cols = np.concatenate([corner_b, corner_d])
    graph = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n_corners, n_corners))
    return faces.reshape(-1), connected_components(graph, directed=False)[1]


def _check_manifold_vertices(faces: np.ndarray, name: str) -> None:
    vertex, fan = vertex_fans(faces)
    pairs = np.unique(np.stack([vertex, fan], axis=1), axis=0)
    fans_per_vertex = np.bincount(pairs[:, 0])
    bad = np.flatnonzero(fans_per_vertex > 1)
    if bad.size:
        raise MeshError(
            f"{name}: {bad.size} non-manifold vertices where separate fans of faces meet, like a bowtie "
            f"(first: vertex {bad[0]}, in {fans_per_vertex[bad[0]]} fans); spidermatch needs a manifold "
            "surface: split or remove these vertices"
        )


def _check_single_component(faces: np.ndarray, n_verts: int, name: str) -> None:
    edges = face_edges(faces).reshape(-1, 2)
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n_verts, n_verts))
    n_components, labels = connected_components(graph, directed=False)
    if n_components > 1:
        sizes = np.bincount(labels)
        listing = ", ".join(
            f"component {k}: {sizes[k]} vertices (e.g. vertex {int(np.flatnonzero(labels == k)[0])})"
            for k in np.argsort(-sizes)[:5]
        )
        more = "" if n_components <= 5 else f", and {n_components - 5} more"
        raise MeshError(
            f"{name}: the mesh has {n_components} connected components; spidermatch needs one "
            f"connected surface ({listing}{more})"
        )


def faces_to_flip(faces: np.ndarray, name: str = "<mesh>") -> np.ndarray:
    """Faces whose corner order must be reversed for one consistent orientation.

    Two faces sharing an edge are consistently oriented when they traverse it in opposite
    directions. Each face gets one of two orientation labels such that every shared edge
    either keeps or swaps the label as its two faces agree or disagree: the connected
    components of a graph over (face, label) nodes. The surface is orientable exactly when no
    face is connected to itself with the other label. Of the two consistent orientations
    the one that reverses fewer faces is chosen.

    Parameters
    ----------
    faces : np.ndarray, shape (F, 3)
        Faces of a manifold, connected mesh (every edge in at most two faces).
    name : str
        Named in the error message.

    Returns
    -------
    np.ndarray, shape (F,), bool
        True for the faces to reverse (none for a consistently oriented mesh).

    Raises
    ------
    MeshError
        The surface is not orientable (e.g. a Moebius strip), so no orientation exists.

    """
    n_faces = len(faces)
    directed = np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2)  # (3F, 2)
    forward = directed[:, 0] < directed[:, 1]
    undirected = np.sort(directed, axis=1)
    order = np.lexsort((undirected[:, 1], undirected[:, 0]))
    shared = np.all(undirected[order[1:]] == undirected[order[:-1]], axis=1)
    first, second = order[:-1][shared], order[1:][shared]
    face_a, face_b = first // 3, second // 3
    agree = forward[first] != forward[second]  # opposite directions: consistently oriented
    other_a, other_b = face_a + n_faces, face_b + n_faces
    rows = np.concatenate([face_a, other_a])
    cols = np.concatenate([np.where(agree, face_b, other_b), np.where(agree, other_b, face_b)])
    graph = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(2 * n_faces, 2 * n_faces))
    labels = connected_components(graph, directed=False)[1]
    twisted = np.flatnonzero(labels[:n_faces] == labels[n_faces:])
    if twisted.size:
        raise MeshError(
            f"{name}: the surface is not orientable (like a Moebius strip: face {twisted[0]} = "
            f"{faces[twisted[0]].tolist()} meets itself with its orientation reversed); no consistent "
            "matching of such a surface exists"
        )
    flip = labels[:n_faces] != labels[0]
    return ~flip if flip.sum() > n_faces / 2 else flip


def nearly_closed(verts: np.ndarray, faces: np.ndarray) -> bool:
    """True if every boundary loop of the (manifold, connected) faces is a small hole."""
    spans = loop_spans(verts, faces)
    return bool(np.all(spans < SMALL_HOLE_SHARE * triangle_areas(verts, faces).sum()))


def signed_volume(verts: np.ndarray, faces: np.ndarray) -> float:
    """Volume enclosed by a closed, consistently oriented surface; negative when it faces inwards.

    On an open surface: the summed volume of the cones from the origin to its faces.
    """
    a, b, c = (verts[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def make_mesh(
    verts: np.ndarray, faces: np.ndarray, name: str = "<mesh>", notes: tuple = (), outward: bool = True
) -> Mesh:
    """Validate (verts, faces) and wrap them in a :class:`Mesh`.

    Faces are reversed where needed so that all share one orientation (the decimation and
    every normal need one, and the matching preserves it): first to the orientation most
    faces share, then, with ``outward``, all of them if the surface faces inwards
    (:func:`faces_inwards`: a closed surface enclosing a negative volume, or an open one, a
    part, clearly so), since a surface wound the other way round would be matched to its
    mirror image. A mesh derived from one already oriented (a decimation) passes
    ``outward=False``: it keeps its parent's orientation, whatever its own shape would say.
    The mesh's ``notes`` (after the given ``notes``, e.g. the loader's) and the log say how many.
    """
    flip = validate_mesh(verts, faces, name)
    faces = np.array(faces, dtype=np.int64)
    faces[flip] = faces[flip][:, ::-1]
    points = np.asarray(verts, dtype=np.float64)
    if outward and faces_inwards(points, faces):
        faces, flip = faces[:, ::-1].copy(), ~flip
    notes = tuple(notes)
    note = _orientation_note(name, flip)
    if note is not None:
        logger.warning("%s", note)
        notes += (note,)
    mesh = Mesh(points, faces, name, notes)
    mesh.cached(VALIDATED, lambda: True)
    if flip.any():
        mesh.cached(REVERSED_FACES, lambda: flip)
    return mesh


def _orientation_note(name: str, flip: np.ndarray) -> str | None:
    """What :func:`make_mesh` says about the faces ``flip`` (F,) bool it reversed (None: none)."""
    if flip.all():
        return (
            f"{name}: all {len(flip)} faces faced inwards (the surface is wound the other way round); "
            "they were reversed so that it faces outwards, else it would be matched to its mirror image"
        )
    if flip.any():
        return (
            f"{name}: {int(flip.sum())} of {len(flip)} faces were oriented against their neighbours "
            "(or the surface faced inwards); they were reversed so that all faces share one orientation"
        )
    return None


OPEN_INWARD_VOLUME = 0.002
"""An open surface faces inwards if the cones from its centroid to its faces sum to less than minus
this share of area^1.5. A part of a body (plane cut, holes, single view) curves round its
centroid: 158 random parts of FAUST_r and TOSCA_animals shapes (10-95 % of the area) ranged from
+0.004 to +0.05 facing outwards (a sphere: +0.094); a nearly flat patch, near 0, is left as it is."""


def faces_inwards(verts: np.ndarray, faces: np.ndarray) -> bool:
    """True if the consistently oriented ``faces`` face inwards.

    A (nearly) closed surface faces inwards when the volume it encloses is negative; an open
    one (a part of a shape) when that of the cones from its centroid to its faces is clearly so
    (:data:`OPEN_INWARD_VOLUME`).
    """
    volume = signed_volume(verts - verts.mean(axis=0), faces)
    if volume >= 0:
        return False
    if nearly_closed(verts, faces):
        return True
    return volume < -OPEN_INWARD_VOLUME * triangle_areas(verts, faces).sum() ** 1.5


VALIDATED = "validated"
"""Cache key :func:`make_mesh` sets: the mesh passed :func:`validate_mesh` with its faces as they are."""


REVERSED_FACES = "reversed_faces"
"""Cache key :func:`make_mesh` sets when it reversed faces: which ones, (F,) bool."""


def reversed_faces_of(mesh: Mesh) -> np.ndarray | None:
    """Which faces (F,) bool :func:`make_mesh` reversed from the order given, or None if none."""
    return mesh._cache.get(REVERSED_FACES)


def keep_reversed_faces(part: Mesh, reversed_faces: np.ndarray) -> None:
    """Mark on ``part`` (cut from a mesh make_mesh made) which of its faces (F_part,) bool were reversed."""
    if reversed_faces.any():
        part.cached(REVERSED_FACES, lambda: reversed_faces)


def bary_in_given_corners(mesh: Mesh, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (N, 3) in ``face`` (N,) of ``mesh``, in its faces' corner order as given.

    :func:`make_mesh` may have reversed faces (their corners then run the other way round):
    their coordinates are reversed with them. Rows with ``face`` -1 (none) are left as they are.
    """
    reversed_faces = reversed_faces_of(mesh)
    if reversed_faces is None:
        return bary
    face = np.asarray(face)
    swap = np.zeros(len(face), dtype=bool)
    swap[face >= 0] = reversed_faces[face[face >= 0]]
    given = np.array(bary, dtype=np.float64)
    given[swap] = given[swap][:, ::-1]
    return given


def is_validated(mesh: Mesh) -> bool:
    """True if :func:`make_mesh` made ``mesh`` (its arrays are read-only: still what it checked)."""
    return bool(mesh._cache.get(VALIDATED, False))


def mean_incident_edge_length(mesh: Mesh) -> np.ndarray:
    """Mean length of the edges at each vertex, shape (V,)."""
    edges = mesh.edges
    total = np.bincount(edges.reshape(-1), np.repeat(mesh.edge_lengths, 2), minlength=mesh.n_verts)
    count = np.bincount(edges.reshape(-1), minlength=mesh.n_verts)
    return total / np.maximum(count, 1)


SMALL_HOLE_SHARE = 0.01
"""A boundary loop that spans less than this share of its mesh's area is a small hole (see also
:data:`HOLE_ALIGNMENT`).

A raw scan of a whole surface has such holes where the scanner saw nothing (an armpit, the
top of the head, a patch the repair dropped): they do not make it a part. The area a loop
spans is the length of its vector area, the area of the cap that would close it (on a FAUST_r
body: a hole of two rings of faces 0.01-0.75 %, a wrist about 0.1 %, a cut at the waist 4 %, a
single view's silhouette 50-65 %). Measured on FAUST_r pairs (docs/partial.md, "Small holes are
not cuts"): a source with one hole spanning up to 1.6 % matches as a whole shape within 0.002 of
the partial mode's error, in half its time. A limb cut off where it is thin (a hand, a foot)
also leaves a small loop, but across a tube: such a loop is a cut (:data:`HOLE_ALIGNMENT`).
"""


@dataclass(frozen=True)
class Topology:
    """Topological type of a connected, manifold triangle mesh.

    Attributes
    ----------
    euler : int
        V - E + F.
    boundaries : int
        Number of boundary loops.
    genus : int
        (2 - euler - boundaries) / 2.
    small_holes : int
        How many of the boundary loops are small holes (:data:`SMALL_HOLE_SHARE`).
    small_hole_share : float
        The area those small holes span together, as a share of the mesh's area.
    widest_span : float
        The largest share of the mesh's area any of its boundary loops spans (0 if closed).

    """

    euler: int
    boundaries: int
    genus: int
    small_holes: int = 0
    small_hole_share: float = 0.0
    widest_span: float = 0.0

    @property
    def open_boundaries(self) -> int:
        """Boundary loops that are not small holes: the cuts that make a mesh a part."""
        return self.boundaries - self.small_holes

    def __str__(self) -> str:
        holes = (
            f"{self.small_holes} small hole(s) spanning {self.small_hole_share:.2%} of its area"
            if self.small_holes
            else ""
        )
        if not self.open_boundaries:
            loops = f"closed but for {holes}" if holes else "closed"
        else:
            loops = f"{self.open_boundaries} boundary loop(s)" + (f" and {holes}" if holes else "")
        return f"genus {self.genus}, {loops}"


EDGE_SLOT_CORNERS = np.array([[1, 2], [2, 0], [0, 1]])
"""The corners (within its face) that a face's directed edge in slot 0, 1, 2 runs from and to."""


def directed_face_edges(faces: np.ndarray) -> np.ndarray:
    """Every face's three edges as the face runs them, shape (3F, 2).

    Row r is edge slot ``r % 3`` of face ``r // 3``, from corner ``EDGE_SLOT_CORNERS[r % 3, 0]``
    to corner ``EDGE_SLOT_CORNERS[r % 3, 1]``.
    """
    return np.asarray(faces)[:, EDGE_SLOT_CORNERS.ravel()].reshape(-1, 2)


def boundary_loops(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boundary edges of manifold faces, directed as their face runs them, and the loop of each.

    Returns
    -------
    edges : np.ndarray, shape (B, 2), int64
    loop : np.ndarray, shape (B,), int64
        Index of the boundary loop (a connected component of the boundary edges) of each edge.
    """
    directed = directed_face_edges(faces)
    _, index, counts = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True, return_counts=True)
    edges = directed[counts[index.reshape(-1)] == 1]
    if not len(edges):
        return edges, np.zeros(0, dtype=np.int64)
    nodes, ends = np.unique(edges, return_inverse=True)
    ends = ends.reshape(-1, 2)
    graph = sp.coo_matrix((np.ones(len(ends)), (ends[:, 0], ends[:, 1])), shape=(nodes.size,) * 2)
    labels = connected_components(graph, directed=False)[1]
    return edges, labels[ends[:, 0]].astype(np.int64)


def boundary_vertices(faces: np.ndarray) -> np.ndarray:
    """Vertices on a boundary edge of manifold faces, sorted, shape (K,) int64 (empty if closed)."""
    return np.unique(boundary_loops(faces)[0]).astype(np.int64)


def loop_spans(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area each boundary loop spans (the length of its vector area), shape (L,).

    The vector area of a closed polygon, half the sum of p_a x p_b over its directed edges,
    is the area of any cap closing it projected onto its best plane: the size of the hole.
    """
    return spans_of_loops(verts, *boundary_loops(faces))


def spans_of_loops(verts: np.ndarray, edges: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """:func:`loop_spans` of the loops :func:`boundary_loops` returned, shape (L,)."""
    return np.linalg.norm(loop_vector_areas(verts, edges, loop), axis=1)


def loop_vector_areas(verts: np.ndarray, edges: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """Vector area of each boundary loop, half the sum of p_a x p_b over its edges, shape (L, 3)."""
    if not len(edges):
        return np.zeros((0, 3))
    points = np.asarray(verts, dtype=np.float64)
    points = points - points.mean(axis=0)  # a closed loop's vector area does not depend on it
    cross = np.cross(points[edges[:, 0]], points[edges[:, 1]])
    return 0.5 * np.stack([np.bincount(loop, cross[:, k]) for k in range(3)], axis=1)


TINY_HOLE_SHARE = 0.0005
"""A boundary loop spanning less than this share of its mesh's area is a small hole whatever its shape
(what it leaves out is too small to change a match: a fingertip, a pore of the scan)."""

HOLE_ALIGNMENT = 0.45
"""A loop spanning under :data:`SMALL_HOLE_SHARE` is a small hole only if the surface round it runs
along the cap that would close it: the mean |cos| of the angle between the cap's direction (its
vector area) and the surface normals at the loop's vertices is at least this. A hole in a surface
(a scanner's) has the surface tangent to its cap; a limb cut across (the feet cut off by the floor,
a hand off at the wrist) has it perpendicular. Measured (docs/partial.md, "Small holes are not
cuts"): 2-ring holes of FAUST_r and TOSCA copies spanning 0.05-0.75 % have 0.47-0.97, the legs of a
FAUST_r body cut by a horizontal plane 0.16-0.44, a hand or forearm cut off 0.37-0.43."""


def loop_alignments(verts: np.ndarray, faces: np.ndarray, edges: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """Mean |cos| between each boundary loop's cap direction and the surface normals on it, shape (L,).

    ``edges`` and ``loop`` as :func:`boundary_loops` returns them; the normals are the
    area-weighted normals of the vertices each loop's edges start from.
    """
    if not len(edges):
        return np.zeros(0)
    cap = loop_vector_areas(verts, edges, loop)
    cap /= np.maximum(np.linalg.norm(cap, axis=1, keepdims=True), np.finfo(float).tiny)
    rim = vertex_normals(np.asarray(verts, dtype=np.float64), faces)[edges[:, 0]]
    cosines = np.abs(np.einsum("ij,ij->i", rim, cap[loop]))
    return np.bincount(loop, cosines) / np.bincount(loop)


def small_hole_loops(
    verts: np.ndarray, faces: np.ndarray, edges: np.ndarray, loop: np.ndarray, area: float
) -> tuple[np.ndarray, np.ndarray]:
    """Which boundary loops are small holes (L,) bool, and each loop's span as a share of ``area`` (L,).

    A small hole spans under :data:`SMALL_HOLE_SHARE` and either under :data:`TINY_HOLE_SHARE` or
    with the surface running along its cap (:data:`HOLE_ALIGNMENT`): a limb cut across is a cut.
    """
    spans = spans_of_loops(verts, edges, loop) / area
    small = spans < SMALL_HOLE_SHARE
    unsure = np.flatnonzero(small & (spans >= TINY_HOLE_SHARE))
    if unsure.size:
        small[unsure] = loop_alignments(verts, faces, edges, loop)[unsure] >= HOLE_ALIGNMENT
    return small, spans


def small_holes_closed(mesh: Mesh) -> Mesh:
    """``mesh`` with each small hole (:func:`small_hole_loops`) closed by a fan to its loop's centroid.

    The mesh's vertices come first, then one vertex per closed hole (V + H, 3); the fan's faces
    follow the surface's orientation. A mesh without small holes is returned as it is.
    """
    edges, loop = boundary_loops(mesh.faces)
    is_small, spans = small_hole_loops(mesh.verts, mesh.faces, edges, loop, mesh.area)
    small = np.flatnonzero(is_small)
    if not small.size:
        return mesh
    centre = np.full(len(spans), -1, dtype=np.int64)
    centre[small] = mesh.n_verts + np.arange(small.size)
    counts = np.bincount(loop, minlength=len(spans)).astype(float)
    starts = mesh.verts[edges[:, 0]]
    sums = np.stack([np.bincount(loop, starts[:, k], minlength=len(spans)) for k in range(3)], axis=1)
    closing = np.isin(loop, small)
    fans = np.stack([edges[closing, 1], edges[closing, 0], centre[loop[closing]]], axis=1)
    verts = np.vstack([mesh.verts, sums[small] / counts[small, None]])
    return Mesh(verts, np.vstack([mesh.faces, fans]), mesh.name, mesh.notes)


def topology(mesh: Mesh) -> Topology:
    """Genus, boundary loops and small holes of a validated (connected, manifold) mesh."""
    boundary, loop = boundary_loops(mesh.faces)
    n_edges = (3 * mesh.n_faces + len(boundary)) // 2  # an inner edge has two faces, a boundary edge one
    euler = mesh.n_verts - n_edges + mesh.n_faces
    small, spans = small_hole_loops(mesh.verts, mesh.faces, boundary, loop, mesh.area)
    loops = len(spans)
    return Topology(
        int(euler),
        int(loops),
        int((2 - euler - loops) // 2),
        int(small.sum()),
        float(spans[small].sum()),
        float(spans.max(initial=0.0)),
    )
