"""Label-free orientation search for networks that read vertex coordinates.

A network whose input includes the vertex coordinates (``xyz``, ``wks_xyz``) expects the
orientation of its training shapes. A shape turned about the vertical axis (FAUST_r's pose-8
scans are turned about 107 degrees) points it at the wrong side of the body. The search
presents the shape's coordinates in ``turns`` evenly spaced turns about the vertical (y)
axis and keeps the turn whose unsupervised functional-map loss (the training objective)
against a reference shape in the training orientation is lowest. It reads no labels.

Training stores its reference (the first training shape, at training resolution) in every
checkpoint (:func:`reference_payload`); validation and :class:`features.learned.LearnedExtractor`
search against it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from features.diffusion_net import DiffusionNet, ModelConfig, ShapeInput, prepare_shape
from features.fmap import FmapLossConfig, fmap_terms
from spidermatch.mesh import Mesh

COORDINATE_INPUTS = ("xyz", "wks_xyz")


def turn_about_vertical(angle: float) -> torch.Tensor:
    """The rotation (3, 3) by ``angle`` radians about the y (vertical) axis."""
    cos, sin = math.cos(angle), math.sin(angle)
    return torch.tensor([[cos, 0.0, sin], [0.0, 1.0, 0.0], [-sin, 0.0, cos]])


def rotated_coordinates(features: torch.Tensor, rotation: torch.Tensor) -> torch.Tensor:
    """Network input (V, C) whose last 3 (coordinate) columns are turned by ``rotation`` (3, 3)."""
    rotation = rotation.to(features.dtype)
    return torch.cat([features[:, :-3], features[:, -3:] @ rotation.T], dim=1)


def turned_input(shape: ShapeInput, degrees: float) -> ShapeInput:
    """``shape`` with its coordinate columns turned by ``degrees`` about the vertical axis."""
    if degrees == 0.0:
        return shape
    return replace(
        shape, features=rotated_coordinates(shape.features, turn_about_vertical(math.radians(degrees)))
    )


@dataclass
class OrientationSearch:
    """Choose, per shape, the turn about the vertical axis that the network matches best.

    Attributes
    ----------
    reference : ShapeInput
        A shape in the orientation the network was trained in.
    turns : int
        Evenly spaced turns to try (8: every 45 degrees).
    loss : FmapLossConfig
        The unsupervised loss that scores each turn against the reference.
    """

    reference: ShapeInput
    turns: int
    loss: FmapLossConfig

    def angles(self) -> list[float]:
        """The turns tried, in degrees, starting with 0."""
        return [360.0 * k / self.turns for k in range(self.turns)]

    def search(
        self, network: DiffusionNet, shapes: list[ShapeInput], probes: list[ShapeInput] | None = None
    ) -> list[tuple[float, torch.Tensor]]:
        """Best turn (degrees) and the network output (V, C_out) in it, for every shape.

        Parameters
        ----------
        network : DiffusionNet
            Run without gradients in whatever mode it is in.
        shapes : list of ShapeInput
        probes : list of ShapeInput, optional
            The same shapes at the resolution the network was trained at (see
            :func:`probe_input`), one per shape: the turns are chosen on them, which is
            both faster and more reliable than at a finer resolution. None: on ``shapes``.
        """
        with torch.no_grad():
            reference = network(self.reference.features, self.reference.ops)
            if probes is None:
                return [self._best_turn(network, reference, shape) for shape in shapes]
            found = []
            for shape, probe in zip(shapes, probes, strict=True):
                angle = self._best_turn(network, reference, probe)[0]
                turned = turned_input(shape, angle)
                found.append((angle, network(turned.features, turned.ops)))
            return found

    def _best_turn(
        self, network: DiffusionNet, reference: torch.Tensor, shape: ShapeInput
    ) -> tuple[float, torch.Tensor]:
        best = (math.inf, 0.0, None)
        for angle in self.angles():
            out = network(turned_input(shape, angle).features, shape.ops)
            terms = fmap_terms(reference, out, self.reference.ops, shape.ops, self.loss)
            loss = terms.weighted(self.loss).item()
            if loss < best[0]:
                best = (loss, angle, out)
        return best[1], best[2]


def oriented_outputs(
    network: DiffusionNet,
    shapes: list[ShapeInput],
    search: OrientationSearch | None,
    probes: list[ShapeInput] | None = None,
) -> list[tuple[float, torch.Tensor]]:
    """Turn (degrees) and network output (V, C_out) of every shape, without gradients.

    With ``search`` the turns are the search's (chosen on ``probes`` when given, see
    :meth:`OrientationSearch.search`); without it every shape is taken as it is (turn 0).
    """
    if search is not None:
        return search.search(network, shapes, probes)
    with torch.no_grad():
        return [(0.0, network(shape.features, shape.ops)) for shape in shapes]


def probe_input(mesh: Mesh, model: ModelConfig, faces: int | None, use_cache: bool = True) -> ShapeInput:
    """Network input of ``mesh`` decimated to about ``faces`` faces (as it is if it has fewer or None)."""
    if faces is not None and mesh.n_faces > faces:
        from spidermatch.remesh import decimate

        mesh = decimate(mesh, int(faces)).mesh
    return prepare_shape(mesh, model, use_cache=use_cache)


def searches_orientation(model: ModelConfig, turns: int) -> bool:
    """True when ``turns`` > 1 and the network reads coordinates (WKS alone is invariant)."""
    return turns > 1 and model.input in COORDINATE_INPUTS


def reference_payload(mesh: Mesh, turns: int) -> dict[str, Any]:
    """What a checkpoint stores of the search: the reference mesh and the number of turns."""
    return {
        "turns": int(turns),
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
) -> OrientationSearch | None:
    """The search a checkpoint's payload describes (None if it is off for this network).

    Parameters
    ----------
    payload : dict
        From :func:`reference_payload`.
    model : ModelConfig
    loss : FmapLossConfig
    turns : int, optional
        Override the stored number of turns (0 or 1: no search).
    use_cache : bool
        Use the on-disk operator cache for the reference shape.
    """
    turns = int(payload["turns"]) if turns is None else turns
    if not searches_orientation(model, turns):
        return None
    mesh = Mesh(
        payload["verts"].numpy(), payload["faces"].numpy(), name=str(payload.get("name", "reference"))
    )
    return OrientationSearch(prepare_shape(mesh, model, use_cache=use_cache), turns, loss)
