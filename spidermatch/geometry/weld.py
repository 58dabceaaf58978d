"""Vertices that repeat a position, welded: STL files and triangle soups.

An STL file has no vertices, only triangles with their own three corners; many PLY and OBJ
exporters likewise write a vertex per corner, or split vertices along texture seams. Read as
they are, such a mesh is thousands of loose triangles, or a surface cut open along its
seams, and matching would refuse it or take the seams for cuts. Vertices at exactly the same
position are therefore one vertex of the matched mesh (numbered in the order they first
appear in the file), and every output is told back in the file's own vertices: each file
vertex gets the image of the vertex it was welded into, and a target vertex is named by its
first occurrence in the file. The faces keep their number and order.

Repeats are welded where two faces meet on an edge by position (see :func:`_welded_numbering`):
an STL stores the shared corner of two facets twice with the same bits. Vertices count as one
position when they lie closer than a thousandth of the median edge (:data:`NEAR_REPEAT_SHARE`):
an exporter that places each part of a scene by its own node transform, in single precision,
leaves the two sides of a seam a rounding error apart (2e-7 m on a body 1.7 m tall). Two
coincident vertices of a valid surface stay two vertices. A vertex no face uses joins a used one
at its position (the original of a vertex split along a seam, left unused by its exporter). A
welded mesh is used only where it is valid or the mesh as given is not
(:func:`spidermatch.api.mesh_of`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from spidermatch.geometry.mesh import Mesh


@dataclass(frozen=True)
class Weld:
    """A mesh whose repeated vertices were welded, and how its vertices lie in the file's.

    Attributes
    ----------
    mesh : Mesh
        The welded mesh (V vertices, the file's F faces in order), not yet validated; its
        notes say what was welded.
    to_welded : np.ndarray, shape (V_file,), int64
        Welded vertex of each vertex of the file.
    to_file : np.ndarray, shape (V,), int64
        First vertex of the file at each welded vertex's position.
    gap : float
        Largest distance between two vertices taken as one position (0: exact repeats only).
    """

    mesh: Mesh
    to_welded: np.ndarray
    to_file: np.ndarray
    gap: float = 0.0

    @property
    def n_file(self) -> int:
        """Vertices of the mesh as given, V_file."""
        return int(self.to_welded.size)

    @property
    def note(self) -> str:
        """What was welded, for the log and the report's warnings."""
        return weld_note(self.mesh.name, self.n_file, self.mesh.n_verts, self.gap)

    def file_values(self, values: np.ndarray) -> np.ndarray:
        """Per-vertex ``values`` (V, ...) of the welded mesh, one row per file vertex (V_file, ...)."""
        return np.asarray(values)[self.to_welded]

    def file_ids(self, vertices: np.ndarray) -> np.ndarray:
        """Welded vertex ``vertices`` (any shape) named by the file's vertices; -1 (none) stays -1."""
        vertices = np.asarray(vertices)
        return np.where(vertices >= 0, self.to_file[np.maximum(vertices, 0)], -1)

    def file_rows(self, welded_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Which file vertices lie at the welded vertices ``welded_ids`` (R,), and at which of them.

        Returns
        -------
        np.ndarray, shape (R_file,), int64
            Position in ``welded_ids`` of each file vertex found, in file order.
        np.ndarray, shape (R_file,), int64
            Those file vertices.
        """
        position = np.full(self.mesh.n_verts, -1, dtype=np.int64)
        position[np.asarray(welded_ids)] = np.arange(len(welded_ids))
        row = position[self.to_welded]
        found = np.flatnonzero(row >= 0)
        return row[found], found


def welded(mesh: Mesh) -> Weld | None:
    """``mesh`` with its vertices at repeated positions welded, or None if no position repeats.

    Parameters
    ----------
    mesh : Mesh
        Read without validation: (V_file, 3) finite vertices, (F, 3) faces naming them.

    Returns
    -------
    Weld or None

    """
    verts, faces = np.asarray(mesh.verts), np.asarray(mesh.faces)
    if verts.ndim != 2 or verts.shape[0] < 2 or not np.isfinite(verts).all():
        return None  # left to the checks, which name the problem
    if faces.ndim != 2 or not np.issubdtype(faces.dtype, np.integer) or faces.size == 0:
        return None
    if faces.min() < 0 or faces.max() >= verts.shape[0]:
        return None
    position = np.unique(verts, axis=0, return_inverse=True)[1].reshape(-1)
    position, gap = _with_near_repeats(verts, faces, position)
    if position.max() + 1 == len(verts):
        return None  # no position repeats: nothing to weld
    to_welded, to_file = _welded_numbering(verts, faces, position)
    if to_file.size == verts.shape[0]:
        return None
    note = weld_note(mesh.name, to_welded.size, to_file.size, gap)
    welded_mesh = Mesh(verts[to_file], to_welded[faces], mesh.name, (note, *mesh.notes))
    return Weld(welded_mesh, to_welded, to_file, gap)


NEAR_REPEAT_SHARE = 1e-3
"""Vertices closer than this share of the median edge length are one position."""


def _with_near_repeats(
    verts: np.ndarray, faces: np.ndarray, position: np.ndarray
) -> tuple[np.ndarray, float]:
    """``position`` (V_file,) with positions closer than :data:`NEAR_REPEAT_SHARE` joined.

    Only positions, not vertices: which vertices are joined is decided by the faces that meet on
    edges (:func:`_welded_numbering`). Every position counts, not only those on an open edge: a
    fold of the surface (two faces on one triangle, as remeshing leaves where a body touches
    itself) covers its own edges, and the copies of its corners in the scene's other objects must
    be found all the same. Returns the new numbering (0.., in the order of the old one's first
    members) and the largest distance joined (0.0 if none).
    """
    first = np.zeros(position.max() + 1, dtype=np.int64)
    first[position[::-1]] = np.arange(position.size)[::-1]  # a file vertex at each position
    points = verts[first]
    lengths = np.linalg.norm(verts[faces[:, 1]] - verts[faces[:, 0]], axis=1)  # one edge a face
    reach = NEAR_REPEAT_SHARE * float(np.median(lengths))
    pairs = cKDTree(points).query_pairs(reach, output_type="ndarray")
    if len(pairs) == 0:
        return position, 0.0
    gap = float(np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1).max())
    n = len(points)
    links = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    joined = connected_components(links, directed=False)[1]
    return np.unique(joined[position], return_inverse=True)[1].reshape(-1), gap


def _welded_numbering(
    verts: np.ndarray, faces: np.ndarray, position: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Welded vertex of each file vertex (V_file,) and first file vertex of each welded one (V,).

    ``position`` (V_file,) numbers the distinct positions of ``verts``.

    Two faces that share an edge by position, and are the only two faces on it, share its two
    vertices: vertices so joined, directly or through others, are one. This rebuilds a surface
    from its triangles (every corner of a triangle soup, both sides of a split seam) without
    joining vertices that are only at one position: remeshing leaves such pairs inside valid
    surfaces (61 of the 80 FAUST_r meshes have one or two, where the surface touches itself),
    and their faces meet on edges of four faces, which :func:`_crowded_pairs` pairs within
    each side of the contact.
    """
    tail, head = faces.reshape(-1), faces[:, [1, 2, 0]].reshape(-1)  # half-edge 3f + k
    corners = position[faces]
    repeats = (
        (corners[:, 0] == corners[:, 1]) | (corners[:, 1] == corners[:, 2]) | (corners[:, 2] == corners[:, 0])
    )
    ends = np.sort(np.stack([position[tail], position[head]], axis=1), axis=1)
    # a facet with a repeated corner (a sliver) pairs with nothing: each of its edges is its own
    ends[np.repeat(repeats, 3)] = -1 - np.arange(3 * repeats.sum())[:, None]
    _, edge_of, count = np.unique(ends, axis=0, return_inverse=True, return_counts=True)
    edge_of = edge_of.reshape(-1)
    paired = np.flatnonzero(count[edge_of] == 2)
    paired = paired[np.argsort(edge_of[paired], kind="stable")].reshape(-1, 2)  # the two of each edge
    labels = _joined(verts.shape[0], tail, head, position, paired)
    crowded = np.zeros((0, 2), dtype=np.int64)
    for _ in range(PAIRING_ROUNDS):  # each edge paired joins the ends that decide its neighbours' pairing
        more = _crowded_pairs(faces, tail, head, position, edge_of, count, labels)
        if len(more) <= len(crowded):
            break
        crowded = more
        labels = _joined(verts.shape[0], tail, head, position, np.concatenate([paired, crowded]))
    labels = _with_loose_repeats(labels, faces, position)
    n = verts.shape[0]
    first_of_label = np.full(labels.max() + 1, n, dtype=np.int64)
    np.minimum.at(first_of_label, labels, np.arange(n))
    to_file = np.sort(first_of_label)  # in file order: a welded vertex comes where it first appears
    rank = np.empty(first_of_label.size, dtype=np.int64)
    rank[np.argsort(first_of_label)] = np.arange(first_of_label.size)
    return rank[labels], to_file


def _with_loose_repeats(labels: np.ndarray, faces: np.ndarray, position: np.ndarray) -> np.ndarray:
    """``labels`` (V_file,) with each vertex no face uses joined to a used vertex at its position.

    An exporter that splits vertices along a texture seam may leave the original of a split
    vertex unused (every face around it took a copy); it is the same point as its copies, not a
    stray vertex. Of several used vertices at that position (a surface touching itself) the
    first in the file is taken; an unused vertex at a position of its own stays apart (and is
    refused or repaired as any unused vertex).
    """
    used = np.zeros(labels.size, dtype=bool)
    used[faces.reshape(-1)] = True
    if used.all():
        return labels
    first_used = np.full(position.max() + 1, labels.size, dtype=np.int64)
    np.minimum.at(first_used, position[used], np.flatnonzero(used))
    loose = np.flatnonzero(~used)
    twin = first_used[position[loose]]
    joined = twin < labels.size
    labels = labels.copy()
    labels[loose[joined]] = labels[twin[joined]]
    return np.unique(labels, return_inverse=True)[1].reshape(-1)  # numbered 0.. again


def _joined(n: int, tail, head, position, paired: np.ndarray) -> np.ndarray:
    """Label (n,) of each vertex: vertices joined by the half-edge pairs ``paired`` (P, 2) share one."""
    first, second = paired[:, 0], paired[:, 1]
    same_way = position[tail[first]] == position[tail[second]]
    join_a = np.concatenate([tail[first], head[first]])
    join_b = np.concatenate(
        [np.where(same_way, tail[second], head[second]), np.where(same_way, head[second], tail[second])]
    )
    graph = sp.coo_matrix((np.ones(join_a.size), (join_a, join_b)), shape=(n, n))
    return connected_components(graph, directed=False)[1]


PAIRING_ROUNDS = 8
"""Rounds of pairing faces on crowded edges, each with the vertices the last one joined."""

MAX_FACES_ON_EDGE = 8
"""Faces sharing one edge by position beyond which that edge joins nothing (pairings are tried)."""


def _crowded_pairs(faces, tail, head, position, edge_of, count, labels: np.ndarray) -> np.ndarray:
    """Half-edges (P, 2) paired on edges that more than two faces share by position.

    Where a surface touches itself (remeshed, a hand on a hip), two edges lie on one another
    and four faces share that edge by position. Of all pairings of those faces, the one is
    taken that pairs fewest faces lying on one another (two such faces would close into a
    pillow of two triangles), then the one whose pairs' ends are most often already joined
    round them (a vertex's faces join through its other edges), then the one pairing most
    faces that run along the edge opposite ways. An edge where two pairings tie joins nothing
    (its faces are left with a boundary there).
    """
    crowded = np.flatnonzero((count > 2) & (count % 2 == 0) & (count <= MAX_FACES_ON_EDGE))
    if crowded.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    order = np.argsort(edge_of, kind="stable")
    starts = np.concatenate([[0], np.cumsum(count)])
    pairs = []
    for edge in crowded:
        halves = order[starts[edge] : starts[edge + 1]]
        pairs.extend(_best_pairing(halves, faces, tail, head, position, labels))
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


def _best_pairing(halves: np.ndarray, faces, tail, head, position, labels) -> list:
    """The pairs of ``halves`` (half-edges on one edge by position) that join them best, or none."""

    def ends_joined(a, b) -> int:  # labels join vertices at one position only
        ends_b = (labels[tail[b]], labels[head[b]])
        return int(labels[tail[a]] in ends_b) + int(labels[head[a]] in ends_b)

    def on_one_triangle(a, b) -> bool:  # two faces lying on each other: a pillow, not a surface
        return sorted(position[faces[a // 3]]) == sorted(position[faces[b // 3]])

    scored = sorted(
        (
            (
                sum(not on_one_triangle(a, b) for a, b in pairing),
                sum(ends_joined(a, b) for a, b in pairing),
                sum(position[tail[a]] == position[head[b]] for a, b in pairing),
            ),
            pairing,
        )
        for pairing in _pairings(list(halves))
    )
    if len(scored) > 1 and scored[-1][0] == scored[-2][0]:
        return []
    return scored[-1][1]


def _pairings(items: list) -> list:
    """Every way (list of lists of pairs) to split ``items`` (an even number) into pairs."""
    if not items:
        return [[]]
    first, rest = items[0], items[1:]
    return [
        [(first, other), *tail]
        for i, other in enumerate(rest)
        for tail in _pairings(rest[:i] + rest[i + 1 :])
    ]


def soup_refusal(error: Exception, weld: Weld) -> str:
    """``error`` (the mesh as given refused) with the hint that its repeated vertices could be welded."""
    repeats = weld.n_file - weld.mesh.n_verts
    return (
        f"{error}; {repeats} of its vertices repeat the position of another (a triangle soup, as "
        "STL stores it): matching and dataset folders weld them (spidermatch.geometry.weld)"
    )


def weld_note(name: str, n_file: int, n_welded: int, gap: float = 0.0) -> str:
    """The warning that ``name``'s ``n_file`` vertices were matched as ``n_welded`` (``gap``: see Weld)."""
    near = f" or lie within {gap:.2g} of another along a seam" if gap > 0 else ""
    return (
        f"{name}: {n_file - n_welded} of its {n_file} vertices repeat the position of another{near} "
        f"(a triangle soup, as STL stores it, or seams split by an exporter); matched with those "
        f"welded, {n_welded} vertices; every output names the file's own vertices"
    )
