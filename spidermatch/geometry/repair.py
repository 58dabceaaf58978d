"""The largest clean piece of a raw scan (``repair=true``).

Raw scans, and parts cut from them by selecting faces, often fail the loader's checks
(:func:`spidermatch.geometry.mesh.validate_mesh`) in a few places only: a vertex where two fans
of faces touch (a bow-tie), small islands of debris beside the body, stray points used by no
face, a sliver of zero area, a fin of three faces on one edge. Matching refuses such a mesh
and names the first problem. With ``repair=true`` it matches the mesh's largest clean piece
instead: faces of zero area or a repeated vertex and faces on edges of more than two faces are
dropped, of what remains the piece of largest area whose faces are joined through shared edges
is kept (a bow-tie vertex does not join pieces: debris touching the body at a vertex is dropped,
not the body's faces there), and where two fans of that piece still meet at a vertex only the
larger fan (by area) keeps it. What was dropped is said in the warnings, and
every output still names the vertices of the file as given (the rest get no image).

What cannot be repaired this way is still refused: numbers that are not coordinates, faces
that name missing vertices, a piece that cannot be oriented (a Moebius strip).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from spidermatch.geometry.mesh import (
    Mesh,
    MeshError,
    _check_face_indices,
    _check_finite,
    _check_number_types,
    _check_shapes,
    degenerate_faces,
    duplicate_faces,
    edge_face_counts,
    make_mesh,
    shared_edges,
    triangle_areas,
    vertex_fans,
)
from spidermatch.geometry.partial import PartialShape, kept_part, original_faces

logger = logging.getLogger(__name__)

MIN_KEPT_AREA = 0.5
"""Share of the mesh's area below which the largest clean piece is refused: not a repair any more."""


@dataclass(frozen=True)
class Repair:
    """The piece of a mesh that is matched, and what was dropped to get it.

    Attributes
    ----------
    piece : PartialShape
        The largest clean piece (``to_original``: (V_piece,) vertex of the mesh as given).
    face_ids : np.ndarray, shape (F_piece,)
        Face of the mesh as given that each face of the piece is.
    summary : str
        What is matched and what was dropped ("its largest clean piece, ...").
    n_original : int
        Vertices of the mesh as given.
    """

    piece: PartialShape
    face_ids: np.ndarray
    summary: str
    n_original: int

    @property
    def note(self) -> str:
        """What ``repair=true`` does with the mesh, for the log and the report's warnings."""
        return f"{self.piece.mesh.name}: repair=true matches {self.summary}"


def faces_on_crowded_edges(faces: np.ndarray) -> np.ndarray:
    """Faces (F,) bool with an edge that more than two faces share (a non-manifold edge)."""
    if len(faces) == 0:
        return np.zeros(0, dtype=bool)
    _, edge_of, counts = edge_face_counts(faces)
    return (counts[edge_of] > 2).reshape(-1, 3).any(axis=1)


def largest_edge_connected(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces (F,) bool of the largest piece (by area) whose faces are joined through shared edges.

    A lone triangle or an island touching the body at one vertex is a piece of its own here
    (a bow-tie vertex does not join pieces), so that it is dropped, not the body's faces around
    that vertex. ``faces`` (F, 3) must have at most two faces on every edge.
    """
    if len(faces) == 0:
        return np.zeros(0, dtype=bool)
    _, first, second = shared_edges(faces)  # entry 3f + k is face f's edge k
    graph = sp.coo_matrix((np.ones(first.size), (first // 3, second // 3)), shape=(len(faces),) * 2)
    labels = connected_components(graph, directed=False)[1]
    areas = np.bincount(labels, weights=triangle_areas(verts, faces))
    return labels == np.argmax(areas)


def smaller_fans_dropped(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces (F,) bool to keep so that no bow-tie vertex is left: at each, only its largest fan by area.

    ``faces`` (F, 3) must have at most two faces on every edge. Dropping faces can make new
    bow-ties further on, so the step repeats until none is left.
    """
    keep = np.ones(len(faces), dtype=bool)
    areas = triangle_areas(verts, faces)
    while keep.any():
        kept = np.flatnonzero(keep)
        vertex, fan = vertex_fans(faces[kept])
        pairs, pair_of_corner = np.unique(np.stack([vertex, fan], axis=1), axis=0, return_inverse=True)
        pair_of_corner = pair_of_corner.reshape(-1)
        bowtie = np.bincount(pairs[:, 0], minlength=verts.shape[0]) > 1
        if not bowtie[vertex].any():
            break
        pair_area = np.bincount(pair_of_corner, weights=np.repeat(areas[kept], 3), minlength=len(pairs))
        by_vertex_then_area = np.lexsort((-pair_area, pairs[:, 0]))
        first = np.r_[True, pairs[by_vertex_then_area[1:], 0] != pairs[by_vertex_then_area[:-1], 0]]
        largest_fan = np.zeros(len(pairs), dtype=bool)
        largest_fan[by_vertex_then_area[first]] = True
        dropped_corner = bowtie[vertex] & ~largest_fan[pair_of_corner]
        keep[kept[dropped_corner.reshape(-1, 3).any(axis=1)]] = False
    return keep


def largest_clean_piece(mesh: Mesh) -> Repair:
    """The piece of ``mesh`` (possibly invalid) that ``repair=true`` matches (see the module docstring).

    Parameters
    ----------
    mesh : Mesh
        Read without validation (V vertices, F faces).

    Returns
    -------
    Repair

    Raises
    ------
    MeshError
        The arrays cannot be a mesh, no face is left, the piece keeps less than
        ``MIN_KEPT_AREA`` of the area, or the piece fails validation (named in the message).
    """
    name, verts, faces = mesh.name, mesh.verts, mesh.faces
    _check_shapes(verts, faces, name)
    _check_number_types(verts, faces, name)
    _check_finite(verts, name)
    _check_face_indices(faces, verts.shape[0], name)
    degenerate = degenerate_faces(verts, faces)
    copies = duplicate_faces(faces) & ~degenerate  # a copy's original stays (it is no defect)
    crowded = np.zeros_like(degenerate)
    crowded[~(degenerate | copies)] = faces_on_crowded_edges(faces[~(degenerate | copies)])
    keep = ~(degenerate | copies | crowded)
    if not keep.any():
        raise MeshError(f"{name}: no face is left after dropping degenerate and non-manifold ones")
    keep[keep] = largest_edge_connected(verts, faces[keep])
    keep[keep] = smaller_fans_dropped(verts, faces[keep])
    try:
        piece = kept_part(mesh, keep, name, "repaired")
    except ValueError as error:
        raise MeshError(f"{name}: no clean piece is left to match ({error})") from None
    full_area = float(triangle_areas(verts, faces[~(degenerate | copies)]).sum())
    kept_area = piece.mesh.area / full_area if full_area > 0 else 0.0
    checked = make_mesh(piece.mesh.verts, piece.mesh.faces, name)  # orientation; raises if it cannot
    piece = PartialShape(checked, piece.to_original, kept_area, piece.kind)
    face_ids = original_faces(piece, mesh)
    summary = _summary(mesh, piece, face_ids, int(degenerate.sum()), int(copies.sum()), int(crowded.sum()))
    if kept_area < MIN_KEPT_AREA:
        raise MeshError(
            f"{name}: its largest clean piece would be {summary}: too little to call a repair; clean "
            "the mesh, or cut the piece you want to match from it"
        )
    return Repair(piece, face_ids, summary, mesh.n_verts)


def _summary(mesh: Mesh, piece: PartialShape, face_ids, degenerate: int, copies: int, crowded: int) -> str:
    rest = mesh.n_faces - len(face_ids) - degenerate - copies - crowded
    dropped = [
        f"{what} {count}"
        for count, what in (
            (degenerate, "degenerate"),
            (copies, "duplicates of other faces"),
            (crowded, "on non-manifold edges"),
            (rest, "in smaller pieces or smaller fans of bow-tie vertices"),
        )
        if count
    ]
    return (
        f"its largest clean piece, {piece.mesh.n_verts} of {mesh.n_verts} vertices and "
        f"{100 * piece.kept_area:.1f} % of the area (faces dropped: {', '.join(dropped) or 'none'}; "
        f"vertices left out: {mesh.n_verts - piece.mesh.n_verts})"
    )
