"""Label-free orientation search for networks that read vertex coordinates.

A network whose input includes the vertex coordinates (``xyz``, ``wks_xyz``) expects the
orientation of its training shapes. A shape turned about the vertical axis (FAUST_r's pose-8
scans are turned about 107 degrees) points it at the wrong side of the body. The search
presents the shape's coordinates in ``turns`` evenly spaced turns about the vertical axis
(y for FAUST_r's people, z for TOSCA's animals: the training data's ``up_axis``) and keeps
the turn whose unsupervised functional-map loss (the training objective) against a reference
shape in the training orientation is lowest. It reads no labels.

A shape may also arrive lying down or upside down (another up axis, a scanner's frame). With
``frames`` the search also tries the 24 rotations that carry the shape's principal axes onto
the reference's (every assignment of axes with every proper choice of signs), so that any
rotation of the input is covered, and keeps whichever of all candidates scores lowest.

Training stores its reference (the first training shape, at training resolution) in every
checkpoint (:func:`reference_payload`); validation and :class:`features.learned.LearnedExtractor`
search against it.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from features.diffusion_net import XYZ_CHANNELS, DiffusionNet, ModelConfig, ShapeInput, prepare_shape
from features.fmap import FmapLossConfig, fmap_terms
from spidermatch.geometry.mesh import Mesh, principal_axes
from spidermatch.geometry.partial import rigid_fit_residual

COORDINATE_INPUTS = ("xyz", "wks_xyz")
UP_AXES = ("x", "y", "z")
# A part's trial placements (placement_offsets): about PLACEMENT_STEP apart (the whole's
# sqrt(area)), its centre up to PLACEMENT_REACH of the whole's half extent off the whole's
# centre, for the PLACED_ORIENTATIONS best orientations found with the part centred on itself.
PLACEMENT_STEP = 0.15
PLACEMENT_REACH = 0.75
PLACED_ORIENTATIONS = 3
PART_SEARCH_POINTS = 6000
"""Vertices of the other shape a part's orientation search compares against at most.

Every presentation scored (about 350 for a part: the candidate orientations, then trial
placements of the best three) compares each probe vertex's features with every vertex of the
other shape. A raw scan's 20 000-vertex feature copy made that search take 200 s and a
(V_probe, V) similarity matrix of 160 MB per score; a template has 5000 vertices, as many as
the search needs to find a partner's region (docs/partial.md, "Orientation of a part")."""


def search_points(areas: np.ndarray, most: int = PART_SEARCH_POINTS) -> np.ndarray:
    """Sorted indices of at most ``most`` vertices spread over a surface by area, the same on every call.

    Each vertex is drawn with a probability proportional to its area (capped at 1), so that a
    scan denser in some regions is sampled evenly over its surface; a systematic draw along
    the vertex order gives exactly ``most`` of them.

    Parameters
    ----------
    areas : np.ndarray, shape (V,)
        Vertex areas (positive).
    most : int

    Returns
    -------
    np.ndarray, shape (min(V, most),)
        All vertices when there are no more than ``most``.
    """
    if len(areas) <= most:
        return np.arange(len(areas))
    inclusion = inclusion_probabilities(np.asarray(areas, dtype=np.float64), most)
    marks = np.random.default_rng(0).uniform() + np.arange(most)
    chosen = np.searchsorted(np.cumsum(inclusion), marks, side="right")
    return np.unique(np.minimum(chosen, len(areas) - 1))  # distinct unless rounding joins two marks


def inclusion_probabilities(weights: np.ndarray, count: int) -> np.ndarray:
    """Probabilities (V,) proportional to ``weights`` (V,), capped at 1, that sum to ``count`` (< V)."""
    capped = np.zeros(len(weights), dtype=bool)
    while True:
        scale = (count - capped.sum()) / weights[~capped].sum()
        newly = ~capped & (scale * weights >= 1.0)
        if not newly.any():
            return np.where(capped, 1.0, scale * weights)
        capped |= newly


def turn_about_vertical(angle: float, up_axis: str = "y") -> torch.Tensor:
    """The rotation (3, 3) by ``angle`` radians about the vertical axis ``up_axis`` (x, y or z)."""
    if up_axis not in UP_AXES:
        raise ValueError(f"the up axis must be one of {UP_AXES}, got {up_axis!r}")
    up = UP_AXES.index(up_axis)
    first, second = (up + 1) % 3, (up + 2) % 3  # right-handed: a turn carries first onto second
    cos, sin = math.cos(angle), math.sin(angle)
    rotation = torch.eye(3)
    rotation[first, first] = rotation[second, second] = cos
    rotation[second, first], rotation[first, second] = sin, -sin
    return rotation


def rotated_coordinates(features: torch.Tensor, rotation: torch.Tensor) -> torch.Tensor:
    """Network input (V, C) whose last 3 (coordinate) columns are turned by ``rotation`` (3, 3)."""
    rotation = rotation.to(features.dtype)
    return torch.cat([features[:, :-3], features[:, -3:] @ rotation.T], dim=1)


def moved_coordinates(features: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
    """Network input (V, C) whose last 3 (coordinate) columns are moved by ``offset`` (3,)."""
    return torch.cat([features[:, :-3], features[:, -3:] + offset.to(features.dtype)], dim=1)


def rotated_input(shape: ShapeInput, rotation: torch.Tensor) -> ShapeInput:
    """``shape`` with its coordinate columns rotated by ``rotation`` (3, 3)."""
    return replace(shape, features=rotated_coordinates(shape.features, rotation))


def presented_input(shape: ShapeInput, orientation: Orientation) -> ShapeInput:
    """``shape`` with its coordinate columns rotated, then moved by the orientation's offset."""
    turned = rotated_input(shape, orientation.rotation)
    if not any(orientation.offset):
        return turned
    return replace(
        turned,
        features=moved_coordinates(turned.features, torch.tensor(orientation.offset, dtype=torch.float64)),
    )


def feature_partners(
    network: DiffusionNet, part: ShapeInput, presentation: Orientation, whole: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Each part vertex's nearest feature on the whole: cosine similarity (V_p,) and index (V_p,).

    The part is shown in ``presentation``; ``whole`` (V, C_out) has L2-normalised rows.
    """
    out = network(presented_input(part, presentation).features, part.ops)
    return (torch.nn.functional.normalize(out, dim=-1) @ whole.T).max(dim=1)


def placement_offsets(whole_points: np.ndarray) -> np.ndarray:
    """Trial positions (P, 3) of a part's centre relative to its whole's centre, (0, 0, 0) first.

    A part's coordinates are centred on the part itself, so the network cannot tell where on
    the whole it lies (the upper or the lower half, the left or the right side). The
    placements cover the middle ``PLACEMENT_REACH`` of the whole's extent along each axis of
    ``whole_points`` (the whole as the network is shown it, in its unit of length), about
    ``PLACEMENT_STEP`` apart, at least one step to either side.
    """
    half_extent = (whole_points.max(axis=0) - whole_points.min(axis=0)) / 2
    axes = []
    for half in PLACEMENT_REACH * half_extent:
        steps = max(1, int(round(half / PLACEMENT_STEP)))
        axes.append(np.linspace(-half, half, 2 * steps + 1))
    offsets = np.array(list(itertools.product(*axes)))
    return offsets[np.argsort(np.linalg.norm(offsets, axis=1), kind="stable")]


def axis_assignments() -> list[torch.Tensor]:
    """The 24 proper signed permutation matrices (3, 3): the rotations of a cube."""
    found = []
    for order in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            matrix = torch.zeros(3, 3, dtype=torch.float64)
            matrix[list(order), [0, 1, 2]] = torch.tensor(signs, dtype=torch.float64)
            if torch.linalg.det(matrix) > 0:
                found.append(matrix)
    return found


@dataclass(frozen=True)
class Orientation:
    """A candidate orientation: the rotation (3, 3) applied to the input coordinates and its name.

    ``degrees`` is the turn about the vertical axis for those candidates, None for the
    principal-axis alignments. ``offset`` (3,) moves a part's rotated coordinates, so that it
    is shown where on its whole it lies (:func:`placement_offsets`); (0, 0, 0) for whole shapes.
    ``size``: the part was shown at this many times its given size (a part with more area than
    its whole, ``features.learned.LearnedExtractor.part_feature_options``); 1 otherwise.
    """

    rotation: torch.Tensor
    degrees: float | None
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    size: float = 1.0

    def describe(self) -> str:
        """How the input was presented, for logs."""
        if self.degrees is not None:
            said = f"turned {self.degrees:.0f} degrees about the vertical axis"
        else:
            angle, axis = rotation_angle_axis(self.rotation)
            said = (
                f"rotated {angle:.0f} degrees about the axis ({axis[0]:.2f}, {axis[1]:.2f}, {axis[2]:.2f}) "
                "(its principal axes onto the training reference's)"
            )
        if any(self.offset):
            said += ", its centre placed at ({:.2f}, {:.2f}, {:.2f}) from the whole's".format(*self.offset)
        if self.size != 1.0:
            said += f", shown at {self.size:.3f} times its given size"
        return said


def rotation_angle_axis(rotation: torch.Tensor) -> tuple[float, list[float]]:
    """Angle (degrees) and unit axis of a rotation matrix (3, 3)."""
    matrix = rotation.double()
    cos = float(((torch.trace(matrix) - 1) / 2).clamp(-1, 1))
    angle = math.degrees(math.acos(cos))
    if angle < 1e-6:
        return 0.0, [0.0, 1.0, 0.0]
    if angle > 179.0:  # the axis is the eigenvector of eigenvalue 1
        values, vectors = torch.linalg.eigh((matrix + matrix.T) / 2)
        axis = vectors[:, int(torch.argmax(values))]
    else:
        axis = torch.stack(
            [matrix[2, 1] - matrix[1, 2], matrix[0, 2] - matrix[2, 0], matrix[1, 0] - matrix[0, 1]]
        )
    axis = axis / axis.norm()
    return angle, [float(v) for v in axis]


@dataclass
class OrientationSearch:
    """Choose, per shape, the orientation of its coordinates that the network matches best.

    Attributes
    ----------
    reference : ShapeInput
        A shape in the orientation the network was trained in.
    turns : int
        Evenly spaced turns about the vertical axis to try (8: every 45 degrees).
    loss : FmapLossConfig
        The unsupervised loss that scores each candidate against the reference.
    frames : bool
        Also try the 24 alignments of the shape's principal axes with the reference's
        (covers shapes lying down, upside down or in any frame).
    up_axis : str
        The vertical axis of the training shapes (``"x"``, ``"y"`` or ``"z"``).
    reference_mesh : Mesh, optional
        The reference as a mesh (the checkpoint stores it so), in the training shapes' unit: the
        whole shape two parts are read against (:attr:`features.learned.LearnedExtractor.reference_mesh`).
    """

    reference: ShapeInput
    turns: int
    loss: FmapLossConfig
    frames: bool = False
    up_axis: str = "y"
    reference_mesh: Mesh | None = None

    def angles(self) -> list[float]:
        """The turns tried, in degrees, starting with 0."""
        return [360.0 * k / self.turns for k in range(self.turns)]

    def candidates(self, shape: ShapeInput) -> list[Orientation]:
        """Every orientation tried for ``shape``: the vertical turns, then the axis alignments."""
        found = [
            Orientation(turn_about_vertical(math.radians(angle), self.up_axis).double(), angle)
            for angle in self.angles()
        ]
        if self.frames:
            ours, theirs = (
                torch.from_numpy(principal_axes(coordinates.features[:, -3:].double().numpy()))
                for coordinates in (shape, self.reference)
            )
            found += [Orientation(theirs @ assignment @ ours.T, None) for assignment in axis_assignments()]
        return found

    def search(
        self, network: DiffusionNet, shapes: list[ShapeInput], probes: list[ShapeInput] | None = None
    ) -> list[tuple[Orientation, torch.Tensor]]:
        """Best orientation and the network output (V, C_out) in it, for every shape.

        Parameters
        ----------
        network : DiffusionNet
            Run without gradients in whatever mode it is in.
        shapes : list of ShapeInput
        probes : list of ShapeInput, optional
            The same shapes at the resolution the network was trained at (see
            :func:`probe_input`), one per shape: the orientations are chosen on them, which
            is both faster and more reliable than at a finer resolution. None: on ``shapes``.
        """
        with torch.no_grad():
            reference = network(self.reference.features, self.reference.ops)
            if probes is None:
                return [self._best(network, reference, shape) for shape in shapes]
            found = []
            for shape, probe in zip(shapes, probes, strict=True):
                best = self._best(network, reference, probe)[0]
                presented = rotated_input(shape, best.rotation)
                found.append((best, network(presented.features, presented.ops)))
            return found

    def best_for_part(
        self, network: DiffusionNet, part: ShapeInput, whole: torch.Tensor, whole_points: np.ndarray
    ) -> Orientation:
        """The orientation and place of a partial shape whose feature matches are most alike and rigid.

        The first of :meth:`ranked_for_part` (see there).
        """
        return self.ranked_for_part(network, part, whole, whole_points)[0]

    def ranked_for_part(
        self, network: DiffusionNet, part: ShapeInput, whole: torch.Tensor, whole_points: np.ndarray
    ) -> list[Orientation]:
        """The best presentations of a partial shape, best first: one per orientation placed.

        The unsupervised loss of :meth:`search` compares two whole shapes. A part is judged
        instead by where its vertices' features find their nearest features on the whole: each
        candidate scores the median distance of those partners from where a single rigid motion
        puts the vertices (:func:`spidermatch.geometry.partial.rigid_fit_residual`) times one
        minus the mean similarity of the matched features; the smaller the better (no labels).
        Every orientation is scored with the part centred on itself; the ``PLACED_ORIENTATIONS``
        best are then scored again with the part's centre at every trial placement on the whole
        (:func:`placement_offsets`), since a part centred on itself hides which region of the
        whole it is (docs/partial.md, "Placement of a part"). Each of those orientations gives
        its best-scored presentation (centred or placed); they are returned by score.

        Parameters
        ----------
        network : DiffusionNet
        part : ShapeInput
            The partial shape (V_p vertices), at the training resolution, its last three input
            channels the coordinates in the whole's unit.
        whole : torch.Tensor, shape (V, C_out)
            Features of the whole, L2-normalised rows.
        whole_points : np.ndarray, shape (V, 3)
            The whole's vertices in the same unit, as the network was shown them (rotated
            by the whole's own orientation), which sets the trial placements.

        Returns
        -------
        list of Orientation
            ``PLACED_ORIENTATIONS`` presentations (fewer if there are fewer candidates).
        """
        points = part.features[:, -XYZ_CHANNELS:].double().numpy()

        def score(candidate: Orientation) -> float:
            similarity, partners = feature_partners(network, part, candidate, whole)
            residual = rigid_fit_residual(points, whole_points[partners.numpy()])
            return residual * (1.0 - similarity.double().mean().item())

        offsets = placement_offsets(whole_points)[1:]  # the centred placement is scored first
        ranked = []
        with torch.no_grad():
            # stable sorts: of equal scores the earlier candidate wins
            centred = sorted(
                ((score(candidate), candidate) for candidate in self.candidates(part)),
                key=lambda item: item[0],
            )
            for best_score, candidate in centred[:PLACED_ORIENTATIONS]:
                best = candidate
                for offset in offsets:
                    placed = replace(candidate, offset=tuple(float(v) for v in offset))
                    placed_score = score(placed)
                    if placed_score < best_score:
                        best_score, best = placed_score, placed
                ranked.append((best_score, best))
        return [presentation for _, presentation in sorted(ranked, key=lambda item: item[0])]

    def _best(
        self, network: DiffusionNet, reference: torch.Tensor, shape: ShapeInput
    ) -> tuple[Orientation, torch.Tensor]:
        best = (math.inf, None, None)
        for candidate in self.candidates(shape):
            out = network(rotated_input(shape, candidate.rotation).features, shape.ops)
            terms = fmap_terms(reference, out, self.reference.ops, shape.ops, self.loss)
            loss = terms.weighted(self.loss).item()
            if loss < best[0]:
                best = (loss, candidate, out)
        return best[1], best[2]


UNTURNED = Orientation(torch.eye(3, dtype=torch.float64), 0.0)


def oriented_outputs(
    network: DiffusionNet,
    shapes: list[ShapeInput],
    search: OrientationSearch | None,
    probes: list[ShapeInput] | None = None,
) -> list[tuple[Orientation, torch.Tensor]]:
    """Orientation and network output (V, C_out) of every shape, without gradients.

    With ``search`` the orientations are the search's (chosen on ``probes`` when given, see
    :meth:`OrientationSearch.search`); without it every shape is taken as it is.
    """
    if search is not None:
        return search.search(network, shapes, probes)
    with torch.no_grad():
        return [(UNTURNED, network(shape.features, shape.ops)) for shape in shapes]


def probe_input(
    mesh: Mesh, model: ModelConfig, faces: int | None, use_cache: bool = True, scale_area: float | None = None
) -> ShapeInput:
    """Network input of ``mesh`` decimated to about ``faces`` faces (as it is if it has fewer or None).

    ``scale_area`` sets the unit of length (see :func:`features.diffusion_net.input_features`).
    """
    if faces is not None and mesh.n_faces > faces:
        from spidermatch.geometry.remesh import decimate

        mesh = decimate(mesh, int(faces)).mesh
    return prepare_shape(mesh, model, use_cache=use_cache, scale_area=scale_area)


def searches_orientation(model: ModelConfig, turns: int) -> bool:
    """True when ``turns`` > 1 and the network reads coordinates (WKS alone is invariant)."""
    return turns > 1 and model.input in COORDINATE_INPUTS


def reference_payload(mesh: Mesh, turns: int, up_axis: str = "y") -> dict[str, Any]:
    """What a checkpoint stores of the search: the reference mesh, the number of turns and the up axis."""
    return {
        "turns": int(turns),
        "up_axis": up_axis,
        "name": mesh.name,
        "verts": torch.from_numpy(np.array(mesh.verts)),
        "faces": torch.from_numpy(np.array(mesh.faces)),
    }


def search_from_payload(
    payload: dict[str, Any],
    model: ModelConfig,
    loss: FmapLossConfig,
    turns: int | None = None,
    use_cache: bool = True,
    frames: bool = False,
) -> OrientationSearch | None:
    """The search a checkpoint's payload describes (None if it is off for this network).

    Parameters
    ----------
    payload : dict
        From :func:`reference_payload` (checkpoints written before the up axis was stored
        were all trained upright in y).
    model : ModelConfig
    loss : FmapLossConfig
    turns : int, optional
        Override the stored number of turns (0 or 1: no search).
    use_cache : bool
        Use the on-disk operator cache for the reference shape.
    frames : bool
        Also try the principal-axis alignments (:class:`OrientationSearch`).
    """
    turns = int(payload["turns"]) if turns is None else turns
    if not searches_orientation(model, turns):
        return None
    mesh = Mesh(
        payload["verts"].numpy(), payload["faces"].numpy(), name=str(payload.get("name", "reference"))
    )
    reference = prepare_shape(mesh, model, use_cache=use_cache)
    return OrientationSearch(reference, turns, loss, frames, str(payload.get("up_axis", "y")), mesh)
