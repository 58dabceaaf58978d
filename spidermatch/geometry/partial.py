"""Partial shapes: cut copies of a mesh with their index maps, and recognising a partial pair.

A partial shape is what a scanner leaves of a surface: a part cut off by a plane (the
floor, the edge of the field of view), holes where nothing was seen, or the side one
camera sees. :func:`plane_cut`, :func:`holes_cut` and :func:`view_cut` make such copies of a
mesh with exact ground truth (the original index of every kept vertex); the benchmarks and
the training augmentation use them. :func:`pair_kind` decides whether a source is a part of
its target, the case the partial mode matches (``docs/partial.md``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from spidermatch.geometry.mesh import (
    SMALL_HOLE_SHARE,
    Mesh,
    MeshError,
    Topology,
    face_edges,
    keep_reversed_faces,
    mean_incident_edge_length,
    reversed_faces_of,
    topology,
    vertex_fans,
)
from spidermatch.geometry.surface import occluded, surface_positions

logger = logging.getLogger(__name__)

CUT_KINDS = ("plane", "holes", "view")
"""The kinds of partial copy :func:`cut` makes."""


@dataclass(frozen=True, eq=False)
class PartialShape:
    """A connected, manifold part of a mesh.

    Attributes
    ----------
    mesh : Mesh
        The kept part (V_P vertices).
    to_original : np.ndarray, shape (V_P,), int64
        Vertex of the original mesh each kept vertex is.
    kept_area : float
        Area of the part over the area of the original, in (0, 1].
    kind : str
        How it was cut (one of :data:`CUT_KINDS`).

    """

    mesh: Mesh
    to_original: np.ndarray
    kept_area: float
    kind: str

    def positions(self, n_original: int) -> np.ndarray:
        """Part vertex of each of the original's ``n_original`` vertices, -1 where cut away (int64)."""
        position = np.full(n_original, -1, dtype=np.int64)
        position[self.to_original] = np.arange(self.mesh.n_verts)
        return position


def ids_or_missing(ids: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """``ids[indices]`` (a piece's indices told in its original's), keeping -1 (none) as -1."""
    return np.where(indices >= 0, ids[np.maximum(indices, 0)], -1)


def kept_part(mesh: Mesh, keep_faces: np.ndarray, name: str, kind: str) -> PartialShape:
    """The largest clean piece of ``mesh`` made of the faces ``keep_faces`` selects.

    Removing faces from a manifold surface can leave bow-tie vertices (two fans of kept
    faces meeting at one vertex) and several pieces. Faces at bow-tie vertices are dropped
    until none is left, then the largest piece (by area) is kept, so the result passes the
    loader's validation: connected, manifold, no unreferenced vertex.

    Parameters
    ----------
    mesh : Mesh
        A closed or open manifold mesh (V vertices, F faces).
    keep_faces : np.ndarray, shape (F,), bool
    name : str
        Name of the part.
    kind : str

    Returns
    -------
    PartialShape

    """
    faces = mesh.faces[np.asarray(keep_faces, dtype=bool)]
    while True:
        faces = _without_bowtie_faces(faces)
        faces = _largest_piece(faces, mesh.verts)
        if len(faces) == 0 or not _bowtie_vertices(faces).size:
            break
    if len(faces) == 0:
        raise ValueError(f"{mesh.name}: the cut keeps no face")
    to_original, local = np.unique(faces, return_inverse=True)
    part = Mesh(mesh.verts[to_original], local.reshape(-1, 3), name)
    kept = PartialShape(part, to_original.astype(np.int64), part.area / mesh.area, kind)
    reversed_faces = reversed_faces_of(mesh)
    if reversed_faces is not None:  # the files name the whole's faces in their given corners
        keep_reversed_faces(part, reversed_faces[original_faces(kept, mesh)])
    return kept


def original_faces(part: PartialShape, whole: Mesh) -> np.ndarray:
    """Index in ``whole.faces`` of each face of ``part.mesh`` (F_part,), int64.

    A part keeps a subset of its whole's faces, only renumbered: each face is found by its
    sorted corners (one integer key per face, exact below 2 million vertices).
    """
    n = np.int64(whole.n_verts)

    def keys(faces: np.ndarray) -> np.ndarray:
        corners = np.sort(faces.astype(np.int64), axis=1)
        return (corners[:, 0] * n + corners[:, 1]) * n + corners[:, 2]

    whole_keys = keys(whole.faces)
    order = np.argsort(whole_keys)
    wanted = keys(part.to_original[part.mesh.faces])
    found = order[np.searchsorted(whole_keys[order], wanted)]
    if not np.array_equal(whole_keys[found], wanted):
        raise ValueError(f"{part.mesh.name}: a face is not one of {whole.name}'s")
    return found.astype(np.int64)


def _bowtie_vertices(faces: np.ndarray) -> np.ndarray:
    vertex, fan = vertex_fans(faces)
    pairs = np.unique(np.stack([vertex, fan], axis=1), axis=0)
    return np.flatnonzero(np.bincount(pairs[:, 0]) > 1)


def _without_bowtie_faces(faces: np.ndarray) -> np.ndarray:
    while len(faces):
        bad = _bowtie_vertices(faces)
        if not bad.size:
            break
        faces = faces[~np.isin(faces, bad).any(axis=1)]
    return faces


def _largest_piece(faces: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """Faces of the edge-connected piece of largest area."""
    if len(faces) == 0:
        return faces
    n = int(faces.max()) + 1
    edges = face_edges(faces).reshape(-1, 2)
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    labels = connected_components(graph, directed=False)[1]
    face_label = labels[faces[:, 0]]
    areas = np.linalg.norm(
        np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]]), axis=1
    )
    return faces[face_label == np.argmax(np.bincount(face_label, weights=areas))]


def _area_quantile(values: np.ndarray, areas: np.ndarray, fraction: float) -> float:
    """The value below which faces of ``fraction`` of the total area lie."""
    order = np.argsort(values)
    cumulative = np.cumsum(areas[order]) / areas.sum()
    return float(values[order][min(np.searchsorted(cumulative, fraction), len(order) - 1)])


def plane_cut(mesh: Mesh, normal: np.ndarray, keep: float, name: str) -> PartialShape:
    """The part of ``mesh`` below a plane of normal ``normal`` holding ``keep`` of its area.

    Parameters
    ----------
    mesh : Mesh
    normal : np.ndarray, shape (3,)
        Faces whose centroids lie furthest along it are cut away.
    keep : float
        Area fraction to keep before the clean-up of :func:`kept_part`, in (0, 1).

    """
    height = mesh.verts[mesh.faces].mean(axis=1) @ np.asarray(normal, dtype=float)
    level = _area_quantile(height, mesh.face_areas, keep)
    return kept_part(mesh, height <= level, name, "plane")


def holes_cut(mesh: Mesh, centres: np.ndarray, keep: float, name: str) -> PartialShape:
    """``mesh`` with geodesic holes around ``centres`` that remove ``1 - keep`` of its area.

    Every hole has the same radius (graph distance along edges), chosen so that the faces
    left hold ``keep`` of the area.

    Parameters
    ----------
    mesh : Mesh
    centres : np.ndarray, shape (H,), int
        Vertices at the holes' centres.
    keep : float
        Area fraction to keep, in (0, 1).

    """
    distance = dijkstra(mesh.edge_graph(), indices=np.asarray(centres), min_only=True)
    face_distance = distance[mesh.faces].min(axis=1)
    level = _area_quantile(-face_distance, mesh.face_areas, keep)
    return kept_part(mesh, -face_distance <= level, name, "holes")


def view_cut(mesh: Mesh, direction: np.ndarray, name: str) -> PartialShape:
    """The part of ``mesh`` one orthographic camera looking along ``direction`` sees.

    A face is seen when it faces the camera and no other face lies in front of its centroid.

    Parameters
    ----------
    mesh : Mesh
        Consistently (outward) oriented.
    direction : np.ndarray, shape (3,)
        Viewing direction (from the camera into the scene).

    """
    forward = np.asarray(direction, dtype=float)
    forward = forward / np.linalg.norm(forward)
    helper = np.eye(3)[np.argmin(np.abs(forward))]
    right = np.cross(forward, helper)
    right /= np.linalg.norm(right)
    frame = np.stack([right, np.cross(forward, right), -forward])  # camera z towards the camera
    camera = (mesh.verts - mesh.verts.mean(axis=0)) @ frame.T
    a, b, c = (mesh.verts[mesh.faces[:, k]] for k in range(3))
    facing = np.cross(b - a, c - a) @ forward < 0
    centroids = camera[mesh.faces].mean(axis=1)
    tolerance = 1e-3 * float(np.sqrt(mesh.area))
    seen = facing.copy()
    seen[facing] = ~occluded(centroids[facing], camera, mesh.faces, tolerance)
    return kept_part(mesh, seen, name, "view")


def random_cut(
    mesh: Mesh,
    kind: str,
    rng: np.random.Generator,
    keep_range: tuple[float, float] = (0.3, 0.7),
    name: str | None = None,
    attempts: int = 20,
) -> PartialShape:
    """A random partial copy of ``mesh`` of the given kind keeping an area fraction in ``keep_range``.

    Parameters
    ----------
    mesh : Mesh
    kind : str
        "plane" (a random direction, the kept fraction drawn from ``keep_range``), "holes"
        (one to three holes at random vertices) or "view" (a camera from a random direction).
    rng : np.random.Generator
    keep_range : (float, float)
        Accepted kept-area fractions; a draw outside (e.g. a single view that sees little)
        is drawn again, up to ``attempts`` times.

    Raises
    ------
    ValueError
        An unknown kind, or no draw within ``keep_range`` after ``attempts`` tries.

    """
    if kind not in CUT_KINDS:
        raise ValueError(f"cut kind {kind!r}: choose from {', '.join(CUT_KINDS)}")
    name = name or f"{mesh.name}-{kind}"
    low, high = keep_range
    for _ in range(attempts):
        if kind == "plane":
            part = plane_cut(mesh, _random_direction(rng), rng.uniform(low, high), name)
        elif kind == "holes":
            centres = rng.choice(mesh.n_verts, size=int(rng.integers(1, 4)), replace=False)
            part = holes_cut(mesh, centres, rng.uniform(low, high), name)
        else:
            part = view_cut(mesh, _random_direction(rng), name)
        if low <= part.kept_area <= high:
            return part
    raise ValueError(f"{mesh.name}: no {kind} cut kept between {low:.0%} and {high:.0%} of the area")


def _random_direction(rng: np.random.Generator) -> np.ndarray:
    vector = rng.normal(size=3)
    return vector / np.linalg.norm(vector)


@dataclass(frozen=True)
class PairKind:
    """What a pair of meshes is and how it is matched.

    Attributes
    ----------
    mode : str
        "whole" (both surfaces complete, or of the same topology), "partial" (the source
        is a part of the target: it is measured in the target's unit of length, and the
        target keeps a region without partner) or "overlap" (both are parts of one surface:
        each keeps a region without partner, :func:`overlap_kind`).
    reason : str
        Why, in one sentence for the log and ``result.json``.
    area_ratio : float
        Source area over target area, in the meshes' own units.
    caution : str
        What the user should know about this reading of the pair ("" if nothing).

    """

    mode: str
    reason: str
    area_ratio: float
    caution: str = ""


MIN_PART_SHARE = 0.01
"""The smallest share of its whole's area a partial source may have (:func:`pair_kind`).

At the default 1000 target faces, 1 % of the area is 10 faces of the target's edge length: a
part that small cannot be matched, and a source that looks that small is more likely given
in millimetres against a target in metres (a factor of 10^-6 in area)."""

MAX_PART_AREA_RATIO = 2.0
"""The largest ratio of a partial source's area to its whole target's (:func:`pair_kind`).

A part has less area than its own whole, but a user's part often comes from another body than
the target (a tall person's scan against a template): FAUST_r's 80 bodies differ up to 1.88-fold
in area (its poses 7 and 9 are also scaled down, 1.18-fold in length), so an 85 % part of one
body has 1.2 times the area of another. Refusing those, or matching them as two whole shapes,
laid them wrong (docs/partial.md, "A part larger than its whole"). The smallest mix-up of
common units is 2.54-fold in length (6.45 in area), so below this ratio the source is read as a
part of a larger body in the same unit, with a caution naming the unit mix-ups it could be."""

MAX_PARTS_AREA_RATIO = 100.0
"""The largest ratio of areas two parts of one surface may have (:func:`overlap_kind`)."""

UNIT_FACTORS = {
    "millimetres and metres": 1000.0,
    "centimetres and metres": 100.0,
    "millimetres and centimetres": 10.0,
    "millimetres and inches": 25.4,
    "centimetres and inches": 2.54,
    "inches and metres": 1 / 0.0254,
    "feet and metres": 1 / 0.3048,
}
"""Length ratios of common pairs of units, for :func:`unit_hint`."""


def unit_hint(area_ratio: float, plausible: tuple[float, float] = (0.05, 1.0)) -> str:
    """A clause naming the unit mix-ups that would explain ``area_ratio`` (source over target area).

    A pair of units explains the ratio when scaling the source by their length ratio (or its
    inverse) would bring its area to a ``plausible`` share of the target's. Empty when none does.
    """
    found = []
    for units, factor in UNIT_FACTORS.items():
        for scale in (factor, 1.0 / factor):
            share = area_ratio * scale**2
            if plausible[0] <= share <= plausible[1]:
                found.append(f"the source scaled by {scale:.4g} ({units}) would have {share:.0%} of it")
    return f" ({'; '.join(found)})" if found else ""


CUT_SPAN_FACTOR = 2.0
"""A source with as many boundary loops as its target is a part of it when its widest loop spans
this many times the target's widest and its area is the smaller (:func:`cut_against_hole`)."""


def cut_against_hole(top_x: Topology, top_y: Topology, ratio: float) -> bool:
    """Whether a source with as many (open) boundary loops as its target is still a part of it.

    Counting loops alone, a part cut by a plane (its cut spanning 3-65 % of its area) against a
    whole scan with one larger hole (1-2 %, a sole, the crown) makes a pair of two whole shapes,
    and the whole mode, measuring each in its own unit, maps the part onto all of the target
    (measured on FAUST_r: dense error 0.61 and 0.77 where the partial mode gives 0.023 and 0.034;
    docs/partial.md, "A part against a scan with a larger hole"). The source counts as a part when
    its widest loop spans at least :data:`CUT_SPAN_FACTOR` times the target's widest and its area
    ``ratio`` (source over target) is a part's: at least :data:`MIN_PART_SHARE` and under
    :data:`MAX_PART_AREA_RATIO`.
    """
    if not top_x.open_boundaries or not MIN_PART_SHARE <= ratio < MAX_PART_AREA_RATIO:
        return False
    return top_x.widest_span >= CUT_SPAN_FACTOR * top_y.widest_span


INCOMPLETE_TARGET = (
    "the target has boundary loops too: if it is incomplete as well, parts of the source may have no "
    "partner, and the map still gives every source vertex one (partial=both matches two incomplete shapes "
    "on their estimated overlap)"
)


def announce_pair(kind: PairKind) -> None:
    """Log how a pair is matched and why, and any caution as a warning."""
    logger.info("%s mode: %s", kind.mode, kind.reason)
    if kind.caution:
        logger.warning("%s", kind.caution)


def pair_kind(source: Mesh, target: Mesh, partial: bool = True) -> PairKind:
    """Recognise a partial source: boundary loops the target lacks, a smaller area, no more genus.

    Parameters
    ----------
    source, target : Mesh
        Validated (connected, manifold) meshes.
    partial : bool
        Recognise partial sources; False refuses them as any other difference in topology.

    Returns
    -------
    PairKind

    Raises
    ------
    MeshError
        The meshes differ in topology in a way no partial mode explains (another genus, a
        target with more boundary loops than its source, a "part" of
        :data:`MAX_PART_AREA_RATIO` times its whole's area or more),
        or ``partial`` is False and the source is partial; the message names both meshes
        and what to do.

    """
    top_x, top_y = topology(source), topology(target)
    ratio = source.area / target.area
    same = (top_x.genus, top_x.open_boundaries) == (top_y.genus, top_y.open_boundaries)
    if same and not cut_against_hole(top_x, top_y, ratio):
        caution = two_parts_caution(source, target, top_x, top_y) if top_x.open_boundaries else ""
        return PairKind("whole", whole_reason(source, target, top_x, top_y), ratio, caution)
    refusal = (
        f"the meshes differ in topology: {source.name} has {top_x}, {target.name} has {top_y}. "
        "SpiderMatch maps a curve through all of the source onto the target"
    )
    if same:  # as many loops, but the source's is a cut and the target's a hole
        if not partial:
            raise MeshError(
                f"{refusal}; the source's widest boundary loop spans {top_x.widest_span:.1%} of its area, "
                f"the target's {top_y.widest_span:.1%}: the source looks like a part of the target: set "
                "partial=auto to match it"
            )
        reason = (
            f"{source.name} has {top_x} and {ratio:.0%} of the area of {target.name} ({top_y}): as many "
            f"boundary loops, but the source's widest spans {top_x.widest_span:.1%} of its area against "
            f"{top_y.widest_span:.1%}, a cut against a hole: matched as a part of it"
        )
        caution = part_cautions(source, target, ratio, incomplete_target=True)
        return PairKind("partial", reason, ratio, caution)
    if top_x.open_boundaries > top_y.open_boundaries and top_x.genus <= top_y.genus:
        if not partial:
            raise MeshError(
                f"{refusal}; the source looks like a part of the target: set partial=auto to match it"
            )
        if ratio >= MAX_PART_AREA_RATIO:
            raise MeshError(
                f"{refusal}. The source has boundary loops the target lacks, like a part of it, but its "
                f"area is {ratio:.3g} times the target's: a part is matched in its whole's unit of length, "
                f"so give both meshes in the same unit{unit_hint(ratio)}"
            )
        if ratio < MIN_PART_SHARE:
            raise MeshError(
                f"{refusal}. The source has boundary loops the target lacks, like a part of it, but only "
                f"{ratio:.2g} of its area: a part under {MIN_PART_SHARE:.0%} of its whole is too small to be "
                "matched at a resolution the target can have, and a part this small is most often given in "
                f"another unit of length than its whole{unit_hint(ratio)}. Give both meshes in the same unit"
            )
        reason = (
            f"{source.name} has {top_x} and {ratio:.0%} of the area of {target.name} ({top_y}): "
            "matched as a part of it"
        )
        caution = part_cautions(source, target, ratio, incomplete_target=bool(top_y.open_boundaries))
        return PairKind("partial", reason, ratio, caution)
    if top_y.open_boundaries > top_x.open_boundaries and top_y.genus <= top_x.genus:
        if top_y.widest_span < SMALL_HOLE_SHARE:  # small, yet not a scanner's hole: across a limb
            why = (
                f"its widest loop spans only {top_y.widest_span:.1%} of its area, but runs across a limb, "
                "like a cut-off fingertip or foot, not along the surface as a scanner's hole does"
            )
        else:
            why = f"its widest loop spans {top_y.widest_span:.1%} of its area"
        raise MeshError(
            f"{refusal}; the target looks like a part of the source ({why}). The partial mode maps a part "
            f"onto its whole: swap source and target. Holes under {SMALL_HOLE_SHARE:.0%} of the area in "
            f"the surface count as a scanner's and are ignored; if {target.name} is a whole scan with "
            "other holes, allow_topology_mismatch=true matches the two as whole shapes"
        )
    raise MeshError(
        f"{refusal}; across different genus no consistent matching may exist and the solver can "
        "search for hours. Repair the meshes, or set allow_topology_mismatch=true to try anyway"
    )


def part_cautions(source: Mesh, target: Mesh, ratio: float, incomplete_target: bool) -> str:
    """A partial pair's cautions, joined: a target with boundary loops of its own, a part larger than it."""
    cautions = [INCOMPLETE_TARGET] if incomplete_target else []
    if ratio >= 1.0:
        cautions.append(larger_part_caution(source, target, ratio))
    return "; ".join(cautions)


def larger_part_caution(source: Mesh, target: Mesh, ratio: float) -> str:
    """Why a partial source with more area than its target is still read as a part of it."""
    return (
        f"{source.name} has boundary loops {target.name} lacks but {ratio:.2f} times its area: read as a "
        f"part of a larger body in the same unit of length (under {MAX_PART_AREA_RATIO:g} times the area), "
        "shown to a network that reads coordinates at the size its features say; give both meshes in the "
        "same unit if they are not"
        f"{unit_hint(ratio)}"
    )


def whole_reason(source: Mesh, target: Mesh, top_x: Topology, top_y: Topology) -> str:
    """Why a pair is matched as two whole shapes: both the same, small holes tolerated (named)."""
    if top_x.open_boundaries:  # cut loops on both (as many): parts of the same extent, or not
        return (
            f"{source.name} is {top_x} and {target.name} {top_y}: as many cut loops (boundaries that are "
            "not where a scanner saw nothing) on each, so both are matched as whole shapes of that topology"
        )
    if not (top_x.small_holes or top_y.small_holes):  # then the two topologies are equal
        return f"both meshes are {top_x}"
    return (
        f"{source.name} is {top_x} and {target.name} {top_y}: small holes (each spanning under "
        f"{SMALL_HOLE_SHARE:.1%} of its mesh's area, in the surface, not across a limb) are where a scanner "
        "saw nothing, not cuts, so both are "
        "matched as whole shapes"
    )


def two_parts_caution(source: Mesh, target: Mesh, top_x: Topology, top_y: Topology) -> str:
    """What matching two cut meshes as whole shapes assumes: they cover the same region."""
    return (
        f"{source.name} and {target.name} are both cut open (their widest boundary loops span "
        f"{top_x.widest_span:.1%} and {top_y.widest_span:.1%} of their areas): matched as whole shapes, "
        "which is right only if they cover the same region of the shape. If they are different parts "
        "of one body (two views, an upper and a lower half), partial=both matches them on their "
        "estimated overlap instead; a map of one part laid over another is not caught by the quality "
        "verdict on a target with boundaries"
    )


def overlap_kind(source: Mesh, target: Mesh) -> PairKind:
    """The pair as two parts of one surface (``partial=both``): the overlap is estimated, not assumed.

    Topology cannot tell two parts of one surface from a part and its whole, so this mode is
    the user's choice; a mesh without boundary loops is still accepted (its overlap may be
    all of it) with a caution.
    """
    top_x, top_y = topology(source), topology(target)
    ratio = source.area / target.area
    if not 1.0 / MAX_PARTS_AREA_RATIO <= ratio <= MAX_PARTS_AREA_RATIO:
        raise MeshError(
            f"partial=both: {source.name} has {ratio:.3g} times the area of {target.name}: two scans of "
            f"one surface that differ more than {MAX_PARTS_AREA_RATIO:.0f}-fold in area are most often given "
            f"in two units of length{unit_hint(ratio, (0.1, 10.0))}. Give both meshes in the same unit"
        )
    reason = (
        f"partial=both: {source.name} ({top_x}) and {target.name} ({top_y}) are matched as two parts "
        "of one surface in one unit; only the source region estimated to overlap the target is matched"
    )
    whole = [mesh.name for mesh, top in ((source, top_x), (target, top_y)) if top.open_boundaries == 0]
    caution = ""
    if whole:
        caution = (
            f"{' and '.join(whole)} has no boundary loop, so looks complete: a part against a whole "
            "is matched more surely with partial=auto (the part as the source)"
        )
    return PairKind("overlap", reason, ratio, caution)


STAR_WEIGHT = 1e-6
"""Barycentric weight above which an image point lies in a target vertex's star (not on the
far edge of a face around it)."""


def covered_target(
    target: Mesh,
    image_faces: np.ndarray,
    image_bary: np.ndarray,
    source_edge: float,
    closing_rings: int = 2,
) -> np.ndarray:
    """Target vertices the image of a part covers.

    A vertex is hit when the image reaches into its star: an image point lies in one of the
    faces around it with a weight on it. That is how a part names the vertices of its whole
    (a vertex is kept when one of the faces around it is), so the covered region is told as
    the part itself is. Counting only the vertices within half an edge of an image point left
    out the rim where the image ends inside a face: on the 60 FAUST_r partial-to-full runs at
    1000 faces (the same maps), the IoU with the true region is 0.804 this way against 0.790,
    the single views' 0.684 against 0.659 (docs/partial.md, "Outputs"). A vertex within half
    an edge of an image point (half the longer of its own mean edge and the source's) is hit
    as well, so that a source coarser than the target leaves no gaps. The hit set is then
    closed on the target's edge graph (grown by ``closing_rings`` rings, then shrunk by as
    many): a many-to-one map leaves unhit vertices and small gaps inside the region it
    covers, and the closing fills them without growing its rim. Two rings fill the gaps
    where the dense map reaches only part of the target vertices of the true region
    (measurements: bench/README.md, solver constants).

    Parameters
    ----------
    target : Mesh
        V_Y vertices.
    image_faces : np.ndarray, shape (V_X,), int
        Target face holding the image of every source vertex (the dense map's faces).
    image_bary : np.ndarray, shape (V_X, 3)
        Barycentric coordinates of each image point in its face.
    source_edge : float
        Mean edge length of the source, in the target's coordinates.
    closing_rings : int
        Rings of the closing (0: the hit vertices only).

    Returns
    -------
    np.ndarray, shape (V_Y,), bool
    """
    image_faces = np.asarray(image_faces, dtype=np.int64)
    image_bary = np.asarray(image_bary, dtype=float)
    hit = np.zeros(target.n_verts, dtype=bool)
    hit[target.faces[image_faces][image_bary > STAR_WEIGHT]] = True
    radius = 0.5 * np.maximum(mean_incident_edge_length(target), source_edge)
    points = surface_positions(target, image_faces, image_bary)
    distance, _ = cKDTree(points).query(target.verts, distance_upper_bound=radius.max())
    return closed_region(hit | (distance <= radius), edge_adjacency(target), closing_rings)


def edge_adjacency(mesh: Mesh) -> sp.csr_matrix:
    """The mesh's edge graph as a symmetric (V, V) matrix of ones."""
    edges = mesh.edges
    return sp.coo_matrix(
        (np.ones(2 * len(edges)), (edges.reshape(-1), edges[:, ::-1].reshape(-1))), shape=(mesh.n_verts,) * 2
    ).tocsr()


def closed_region(region: np.ndarray, adjacency: sp.csr_matrix, rings: int) -> np.ndarray:
    """Morphological closing (V,) bool of a vertex set on a graph: ``rings`` dilations, then erosions."""
    grown = region.copy()
    for _ in range(rings):
        grown |= adjacency @ grown.astype(float) > 0
    for _ in range(rings):
        grown &= ~(adjacency @ (~grown).astype(float) > 0)
    return grown | region


def mean_edge_length(mesh: Mesh) -> float:
    """Mean length of the mesh's edges."""
    return float(mesh.edge_lengths.mean())


def overlap_summary(target: Mesh, covered: np.ndarray) -> dict:
    """Share of the target's vertices and area the map covers, for ``result.json``."""
    return {
        "target_covered_vertices": int(covered.sum()),
        "target_covered_area": round(float(target.vertex_areas[covered].sum() / target.area), 4),
    }


def rigid_fit_residual(
    points: np.ndarray, partners: np.ndarray, share: float = 0.5, rounds: int = 5
) -> float:
    """Median distance of points to their partners after a trimmed best rigid motion.

    How well tentative correspondences (a part's vertices and the whole's vertices their
    features point at) agree with one rotation and translation: the fit (Kabsch, no
    reflection) is repeated on the ``share`` of pairs it explains best, so wrong partners or a
    limb in another pose do not decide it. Small means consistent.

    Parameters
    ----------
    points : np.ndarray, shape (N, 3)
    partners : np.ndarray, shape (N, 3)
        Partner of each point, in the same unit of length.
    share : float
        Share of pairs each refit uses.
    rounds : int
        Refits.

    Returns
    -------
    float
        Median residual over all N pairs, in the points' unit.
    """
    residuals, _ = _trimmed_fit(points, partners, share, rounds, with_scale=False)
    return float(np.median(residuals))


def fitted_scale(points: np.ndarray, partners: np.ndarray, share: float = 0.5, rounds: int = 5) -> float:
    """Scale of the trimmed best similarity motion (rotation, scale, translation) onto the partners.

    As :func:`rigid_fit_residual`, with a scale fitted too (Umeyama): how many times larger the
    partners' surface is than the points' where the two correspond. A part's vertices and the
    whole's vertices their features point at give the part's size relative to the whole
    (within 1-4 % on FAUST_r parts of 70-90 % of the area; docs/partial.md, "A part larger than
    its whole"). Parameters as :func:`rigid_fit_residual`; returns the scale that carries
    ``points`` (N, 3) onto ``partners`` (N, 3).
    """
    return _trimmed_fit(points, partners, share, rounds, with_scale=True)[1]


def _trimmed_fit(
    points: np.ndarray, partners: np.ndarray, share: float, rounds: int, with_scale: bool
) -> tuple[np.ndarray, float]:
    """Residuals (N,) and scale of the last of ``rounds`` fits, each on the previous one's best ``share``."""
    used = np.ones(len(points), dtype=bool)
    for _ in range(rounds):
        rotation, scale, translation = _best_motion(points[used], partners[used], with_scale)
        residuals = np.linalg.norm(scale * points @ rotation.T + translation - partners, axis=1)
        used = residuals <= np.quantile(residuals, share)
    return residuals, scale


def _best_motion(
    points: np.ndarray, partners: np.ndarray, with_scale: bool
) -> tuple[np.ndarray, float, np.ndarray]:
    """Rotation (3, 3), scale and translation (3,) moving ``points`` (N, 3) closest to ``partners`` (N, 3).

    No reflection; the scale is 1 unless ``with_scale`` (Umeyama's).
    """
    centre_p, centre_q = points.mean(axis=0), partners.mean(axis=0)
    u, singular, vt = np.linalg.svd((points - centre_p).T @ (partners - centre_q))
    signs = np.array([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rotation = vt.T @ np.diag(signs) @ u.T
    scale = 1.0
    if with_scale:
        scale = float((singular * signs).sum() / max(((points - centre_p) ** 2).sum(), 1e-300))
    return rotation, scale, centre_q - scale * centre_p @ rotation.T
