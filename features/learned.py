"""Learned descriptors: a trained :class:`DiffusionNet` behind the feature-extractor interface.

Checkpoints are written by ``train/`` (``spidermatch-train``); this module reads and
validates them so that both inference and resuming a training run share one reader.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import os
import pickle
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from features.diffusion_net import XYZ_CHANNELS, DiffusionNet, ModelConfig, ShapeInput, prepare_shape
from features.fmap import FmapLossConfig, fmap_terms
from features.orientation import (
    COORDINATE_INPUTS,
    PLACED_ORIENTATIONS,
    UNTURNED,
    Orientation,
    OrientationSearch,
    feature_partners,
    oriented_outputs,
    presented_input,
    probe_input,
    rotated_input,
    search_from_payload,
    search_points,
    searches_orientation,
)
from features.wks import normalise_rows
from spidermatch.geometry.mesh import Mesh, MeshError
from spidermatch.geometry.partial import fitted_scale

logger = logging.getLogger(__name__)

ANNOUNCED_VERTICES = 10_000
"""Meshes of at least this many vertices are announced before their learned features: at 20 000
vertices the spectral operators and the network take about half a minute without other output."""

CHECKPOINT_FORMAT = "spidermatch-diffusionnet"
CHECKPOINT_VERSION = 1
REQUIRED_KEYS = ("format", "version", "config", "step", "model")


class CheckpointError(ValueError):
    """A checkpoint is missing, unreadable or incompatible; the message names the file."""


def read_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Load a checkpoint dictionary written by ``train/`` and check its framing.

    Parameters
    ----------
    path : str or PathLike

    Returns
    -------
    dict
        With at least the keys ``format``, ``version``, ``config``, ``step`` and ``model``.

    Raises
    ------
    CheckpointError
        The file is missing, is not a readable torch checkpoint, or is not one of ours.

    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint file")
    if not zipfile.is_zipfile(path):
        raise CheckpointError(
            f"{path}: corrupt or unreadable checkpoint (not a torch.save archive; truncated or overwritten?)"
        )
    damaged = _damaged_member(path)
    if damaged is not None:
        raise CheckpointError(f"{path}: corrupt checkpoint ({damaged})")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except (
        RuntimeError,
        EOFError,
        OSError,
        pickle.UnpicklingError,
        zipfile.BadZipFile,
        ValueError,
        KeyError,
        AttributeError,
    ) as error:
        raise CheckpointError(f"{path}: corrupt or unreadable checkpoint ({_last_line(error)})") from error
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(
            f"{path}: not a spidermatch training checkpoint (expected format {CHECKPOINT_FORMAT!r})"
        )
    missing = [key for key in REQUIRED_KEYS if key not in data]
    if missing:
        raise CheckpointError(f"{path}: incomplete checkpoint, missing {', '.join(missing)}")
    if data["version"] != CHECKPOINT_VERSION:
        raise CheckpointError(
            f"{path}: checkpoint version {data['version']} is not supported (expected {CHECKPOINT_VERSION})"
        )
    return data


def _damaged_member(path: Path) -> str | None:
    """Describe the first archive member failing its CRC-32 check, or None if all pass."""
    try:
        with zipfile.ZipFile(path) as archive:
            name = archive.testzip()
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as error:
        return _last_line(error)
    return None if name is None else f"checksum error in {name}"


def _last_line(error: Exception) -> str:
    """The last non-empty line of an exception's message (torch's are long)."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return f"{type(error).__name__}: {lines[-1] if lines else ''}"


def model_config_of(checkpoint: dict[str, Any], path: str | os.PathLike) -> ModelConfig:
    """The :class:`ModelConfig` stored in a checkpoint, or :class:`CheckpointError`."""
    stored = checkpoint["config"].get("model") if isinstance(checkpoint["config"], dict) else None
    if not isinstance(stored, dict):
        raise CheckpointError(f"{path}: incompatible checkpoint config (no 'model' section)")
    try:
        return ModelConfig(**stored)
    except (TypeError, ValueError) as error:
        raise CheckpointError(f"{path}: incompatible model config in checkpoint ({error})") from error


def inference_weights(checkpoint: dict[str, Any]) -> dict[str, Any]:
    """The weights to compute features with: the moving average when the run kept one."""
    average = checkpoint.get("ema")
    return average if average is not None else checkpoint["model"]


def load_network(path: str | os.PathLike) -> tuple[DiffusionNet, ModelConfig, dict[str, Any]]:
    """Rebuild the trained network of a checkpoint, in eval mode.

    Returns
    -------
    network : DiffusionNet
    config : ModelConfig
    checkpoint : dict
        The whole checkpoint dictionary.

    """
    checkpoint = read_checkpoint(path)
    config = model_config_of(checkpoint, path)
    network = DiffusionNet.from_config(config)
    try:
        network.load_state_dict(inference_weights(checkpoint), strict=True)
    except (RuntimeError, TypeError, AttributeError) as error:
        raise CheckpointError(
            f"{path}: network weights do not match the stored model config ({error})"
        ) from error
    network.eval()
    return network, config, checkpoint


def fmap_config_of(checkpoint: dict[str, Any]) -> FmapLossConfig:
    """The unsupervised loss settings a checkpoint was trained with (defaults if absent)."""
    stored = checkpoint["config"].get("loss") or {}
    names = {field.name for field in dataclasses.fields(FmapLossConfig)}
    return FmapLossConfig(**{key: value for key, value in stored.items() if key in names})


def training_faces_of(checkpoint: dict[str, Any]) -> int | None:
    """The face count the checkpoint's training shapes were decimated to (None: not decimated)."""
    return (checkpoint["config"].get("data") or {}).get("target_faces")


class LearnedExtractor:
    """Descriptors of a trained DiffusionNet, computed at full resolution.

    Parameters
    ----------
    checkpoint : str
        A ``last.pt`` or ``best.pt`` written by ``spidermatch-train``.
    n_eig : int, optional
        Eigenpairs K; must equal the value the network was trained with (None: take it
        from the checkpoint).
    adapt_steps : int
        Test-time adaptation steps in :meth:`pair_features` (0 disables it).
    adapt_lr : float
        Adam learning rate of the adaptation.
    adapt_faces : int, optional
        Decimate both shapes to about this many faces for adaptation (default: the
        training resolution stored in the checkpoint; full resolution if none).
    use_cache : bool
        Use the on-disk operator cache.
    orientation_turns : int, optional
        For networks that read coordinates: present each mesh in this many turns about the
        vertical axis and keep the one whose unsupervised loss against the checkpoint's
        reference shape is lowest (:mod:`features.orientation`). None: the checkpoint's
        setting; 0: off.
    orientation_frames : bool
        With the search on, also try the 24 alignments of each mesh's principal axes with the
        reference's, so that a mesh in any rotation (lying down, another up axis) is presented
        as the network was trained.
    turn_part_targets : bool
        With the search on, turn the target of two parts (:meth:`parts_features`) onto the
        reference shape before its features, for two scans given in frames of their own; False
        takes the target's frame as given (docs/partial.md, "Two scans in frames of their own").

    """

    name = "learned"

    def __init__(
        self,
        checkpoint: str,
        n_eig: int | None = None,
        adapt_steps: int = 0,
        adapt_lr: float = 1e-3,
        adapt_faces: int | None = None,
        use_cache: bool = True,
        orientation_turns: int | None = None,
        orientation_frames: bool = True,
        turn_part_targets: bool = False,
    ) -> None:
        self.checkpoint = str(checkpoint)
        self.network, self.config, stored = load_network(checkpoint)
        n_eig = self.config.n_eig if n_eig is None else n_eig
        if n_eig != self.config.n_eig:
            raise CheckpointError(
                f"{checkpoint}: the network was trained with n_eig = "
                f"{self.config.n_eig}, but n_eig = {n_eig} was requested"
            )
        if adapt_steps < 0:
            raise ValueError(f"adapt_steps must be >= 0, got {adapt_steps}")
        self.n_eig = n_eig
        self.adapt_steps = adapt_steps
        self.adapt_lr = adapt_lr
        self.train_faces = training_faces_of(stored)
        self.adapt_faces = adapt_faces if adapt_faces is not None else self.train_faces
        self.loss_config = fmap_config_of(stored)
        self.use_cache = use_cache
        self.orientation = orientation_search_of(
            stored,
            self.config,
            self.loss_config,
            orientation_turns,
            checkpoint,
            use_cache,
            orientation_frames,
        )
        self.turn_part_targets = turn_part_targets
        self.orientations: dict[str, Orientation] = {}  # mesh name -> how its input was presented

    @property
    def turns(self) -> dict[str, float]:
        """Mesh name -> the turn about the vertical (degrees) the search chose, where it chose one."""
        return {name: found.degrees for name, found in self.orientations.items() if found.degrees is not None}

    def __call__(self, mesh: Mesh) -> np.ndarray:
        """Return descriptors of shape (V, C_out), rows L2-normalised, float64."""
        self._check_size(mesh)
        return self._features(self.network, mesh)

    def _check_size(self, *meshes: Mesh) -> None:
        """Refuse, naming the mesh, one with too few vertices for the functional map's eigenpairs."""
        needed = self.loss_config.n_fmap + 1
        for mesh in meshes:
            if mesh.n_verts < needed:
                raise MeshError(
                    f"{mesh.name}: {mesh.n_verts} vertices are too few for the learned features of "
                    f"{self.checkpoint} (they need at least {needed}: n_fmap = {self.loss_config.n_fmap} "
                    "eigenpairs); match so small a mesh with features=wks"
                )

    def pair_features(self, mesh_x: Mesh, mesh_y: Mesh) -> tuple[np.ndarray, np.ndarray]:
        """Descriptors of a pair, after test-time adaptation if ``adapt_steps > 0``.

        Adaptation fine-tunes a copy of the network on the pair's unsupervised loss;
        the extractor's own network is left unchanged.

        Returns
        -------
        feat_x : np.ndarray, shape (V_x, C_out)
        feat_y : np.ndarray, shape (V_y, C_out)

        """
        self._check_size(mesh_x, mesh_y)
        if self.adapt_steps == 0:
            return self(mesh_x), self(mesh_y)
        network = self.adapt(mesh_x, mesh_y)
        return self._features(network, mesh_x), self._features(network, mesh_y)

    @property
    def reference_mesh(self) -> Mesh | None:
        """The checkpoint's reference shape (a whole training shape, in its unit), or None without one.

        ``partial="both"`` reads the overlap of two parts through it
        (``overlap_method="reference"``: each part is placed on it as on its whole).
        """
        return None if self.orientation is None else self.orientation.reference_mesh

    def part_features(self, part: Mesh, whole: Mesh) -> tuple[np.ndarray, np.ndarray]:
        """Descriptors of a partial source and of the whole target it is a part of.

        The part is measured in the whole's unit of length (both meshes are assumed to share
        one unit, as the partial mode does) and, with an orientation search, presented in
        the orientation whose feature matches on the whole one rigid motion explains best
        (:meth:`features.orientation.OrientationSearch.best_for_part`). Test-time adaptation
        is skipped: its loss assumes two whole shapes.

        Returns
        -------
        feat_part : np.ndarray, shape (V_part, C_out)
        feat_whole : np.ndarray, shape (V_whole, C_out)

        """
        options, feat_whole = self.part_feature_options(part, whole, count=1)
        return options[0][1], feat_whole

    def part_feature_options(
        self, part: Mesh, whole: Mesh, count: int = PLACED_ORIENTATIONS
    ) -> tuple[list[tuple[str, np.ndarray]], np.ndarray]:
        """Descriptors of a partial source in each of its ``count`` best presentations, and of the whole.

        As :meth:`part_features`, but the part is shown to the network in each of the best
        presentations of the orientation search
        (:meth:`features.orientation.OrientationSearch.ranked_for_part`), best first, so that
        a caller can choose among them (``bench/bench_presentations.py``; docs/partial.md, "Several
        presentations").
        Without an orientation search there is one presentation.

        Returns
        -------
        options : list of (str, np.ndarray (V_part, C_out))
            Each presentation's description and the part's features in it.
        feat_whole : np.ndarray, shape (V_whole, C_out)
        """
        self._check_size(part, whole)
        if self.adapt_steps:
            logger.warning("%s: test-time adaptation skipped for a partial source", part.name)
        feat_whole = self._features(self.network, whole)
        shown = self.orientations.get(whole.name)
        whole_points = whole.verts if shown is None else whole.verts @ shown.rotation.double().numpy().T
        options = self._part_options(part, feat_whole, whole_points, whole.vertex_areas, whole.area, count)
        return options, feat_whole

    def parts_features(self, part_x: Mesh, part_y: Mesh) -> tuple[np.ndarray, np.ndarray]:
        """Descriptors of two parts of one surface (partial-to-partial), in one unit of length.

        Neither area is the whole's, so both are measured in the larger part's sqrt(area)
        (the smaller one would inflate the coordinates more). The target is presented as it
        is given, or, with ``turn_part_targets``, turned as a part onto the checkpoint's
        reference shape (for two scans in frames of their own: the network reads coordinates
        in the frame it was trained in) and shown centred on itself; with an orientation
        search, the source is turned and placed as a part onto the target
        (:meth:`part_features`). No test-time adaptation (its loss compares two whole shapes).

        Returns
        -------
        feat_x : np.ndarray, shape (V_x, C_out)
        feat_y : np.ndarray, shape (V_y, C_out)

        """
        self._check_size(part_x, part_y)
        if self.adapt_steps:
            logger.warning("%s: test-time adaptation skipped for two partial shapes", part_x.name)
        unit_area = max(part_x.area, part_y.area)
        shape_y = prepare_shape(part_y, self.config, use_cache=self.use_cache, scale_area=unit_area)
        points_y = part_y.verts
        turn = self._part_turn_on_reference(part_y, unit_area) if self.turn_part_targets else None
        if turn is not None:
            shape_y = rotated_input(shape_y, turn.rotation)
            points_y = part_y.verts @ turn.rotation.double().numpy().T
        with torch.no_grad():
            feat_y = normalise_rows(self.network(shape_y.features, shape_y.ops).double().numpy())
        options = self._part_options(part_x, feat_y, points_y, part_y.vertex_areas, unit_area, 1)
        return options[0][1], feat_y

    def _part_turn_on_reference(self, part: Mesh, unit_area: float) -> Orientation | None:
        """The rotation that turns ``part`` (in ``unit_area``'s unit) onto the search's reference shape.

        The part orientation search of :meth:`part_features` with the checkpoint's reference (a
        whole shape in the training frame) as the whole; the rotation of its best presentation,
        without the placement (the part is shown centred on itself). None without a search.
        """
        if self.orientation is None:
            return None
        reference = self.orientation.reference
        with torch.no_grad():
            feat_reference = self.network(reference.features, reference.ops).double().numpy()
        # the reference is shown in its own unit; the part search divides by sqrt(unit_area)
        points = reference.features[:, -XYZ_CHANNELS:].double().numpy() * np.sqrt(unit_area)
        areas = reference.ops.mass.double().numpy()
        found = self._ranked_for_part(part, normalise_rows(feat_reference), points, areas, unit_area)[0]
        turn = Orientation(found.rotation, found.degrees)
        self.orientations[part.name] = turn
        if turn.degrees != 0.0:
            logger.info(
                "%s: input %s (orientation search for a part, on the reference)", part.name, turn.describe()
            )
        return turn

    def _part_options(
        self,
        part: Mesh,
        feat_other: np.ndarray,
        other_points: np.ndarray,
        other_areas: np.ndarray,
        unit_area: float,
        count: int,
    ) -> list[tuple[str, np.ndarray]]:
        """``part``'s descriptors (V_part, C_out) in its ``count`` best presentations on the other shape.

        Each in ``unit_area``'s unit, turned and placed on the other shape, best first.
        ``feat_other`` (V_other, C_out) are the other shape's features, ``other_points`` (V_other, 3)
        its vertices as they were computed on (rotated by its own orientation, in the same unit as
        given) and ``other_areas`` (V_other,) their vertex areas.
        """
        if self.orientation is None:
            presentations = [UNTURNED]
        else:
            presentations = self._ranked_for_part(part, feat_other, other_points, other_areas, unit_area)
            presentations = presentations[: max(1, count)]
            self.orientations[part.name] = presentations[0]
            if presentations[0].degrees != 0.0 or any(presentations[0].offset):
                logger.info(
                    "%s: input %s (orientation search for a part)", part.name, presentations[0].describe()
                )
        shown_area = unit_area / presentations[0].size ** 2  # shown at its size: in a smaller unit
        shape = prepare_shape(part, self.config, use_cache=self.use_cache, scale_area=shown_area)
        options = []
        with torch.no_grad():
            for presentation in presentations:
                shown = presented_input(shape, presentation)
                features = self.network(shown.features, shown.ops).double().numpy()
                options.append((presentation.describe(), normalise_rows(features)))
        return options

    def _ranked_for_part(
        self, part: Mesh, feat_other: np.ndarray, other_points: np.ndarray, other_areas: np.ndarray, unit_area
    ) -> list[Orientation]:
        """The orientation search's presentations of ``part`` on the other shape, best first.

        The other shape is compared through at most ``PART_SEARCH_POINTS`` of its vertices, sampled
        by area (:func:`features.orientation.search_points`): every presentation scored compares the
        part's features with each of them, and a raw scan has thousands.
        A part with more area than its whole (``unit_area``) cannot be of the whole's size: it
        comes from a larger body (docs/partial.md, "A part larger than its whole"). Its size
        relative to the whole is then read from its best presentation's feature partners
        (:func:`spidermatch.geometry.partial.fitted_scale`; at most what leaves it the whole's
        area), and the search is run again with the part shown at that size.
        """
        sample = search_points(other_areas)
        whole = torch.from_numpy(feat_other[sample]).float()
        probe = probe_input(part, self.config, self.train_faces, self.use_cache, scale_area=unit_area)
        whole_points = other_points[sample] / np.sqrt(unit_area)
        ranked = self.orientation.ranked_for_part(self.network, probe, whole, whole_points)
        if part.area <= unit_area:
            return ranked
        with torch.no_grad():
            _, partners = feature_partners(self.network, probe, ranked[0], whole)
        points = probe.features[:, -XYZ_CHANNELS:].double().numpy()
        size = fitted_scale(points, whole_points[partners.numpy()])
        size = min(size, float(np.sqrt(unit_area / part.area)))
        logger.info(
            "%s has %.2f times the area of its whole: shown at %.3f times its given size",
            part.name,
            part.area / unit_area,
            size,
        )
        shown_area = unit_area / size**2
        probe = probe_input(part, self.config, self.train_faces, self.use_cache, scale_area=shown_area)
        ranked = self.orientation.ranked_for_part(self.network, probe, whole, whole_points)
        return [dataclasses.replace(presentation, size=size) for presentation in ranked]

    def adapt(self, mesh_x: Mesh, mesh_y: Mesh) -> DiffusionNet:
        """A copy of the network fine-tuned for ``adapt_steps`` Adam steps on this pair."""
        inputs = [self._adaptation_input(mesh) for mesh in (mesh_x, mesh_y)]
        inputs = [
            self._oriented(self.network, item, mesh, item)[0] for item, mesh in zip(inputs, (mesh_x, mesh_y))
        ]
        network = copy.deepcopy(self.network)
        network.train()
        optimiser = torch.optim.Adam(network.parameters(), lr=self.adapt_lr)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(0)
            for step in range(self.adapt_steps):
                optimiser.zero_grad()
                feats = [network(item.features, item.ops) for item in inputs]
                terms = fmap_terms(feats[0], feats[1], inputs[0].ops, inputs[1].ops, self.loss_config)
                loss = terms.weighted(self.loss_config)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(network.parameters(), 1.0)
                optimiser.step()
                logger.debug("adaptation step %d: loss %.4f", step, loss.item())
        network.eval()
        return network

    def _adaptation_input(self, mesh: Mesh) -> ShapeInput:
        return probe_input(mesh, self.config, self.adapt_faces, self.use_cache)

    def _features(self, network: DiffusionNet, mesh: Mesh) -> np.ndarray:
        if mesh.n_verts >= ANNOUNCED_VERTICES:
            search = "" if self.orientation is None else ", with the orientation search"
            logger.info(
                "%s: learned features of its %d vertices (the Laplacian's eigenvectors, then the network%s)",
                mesh.name,
                mesh.n_verts,
                search,
            )
        shape = prepare_shape(mesh, self.config, use_cache=self.use_cache)
        _, features = self._oriented(network, shape, mesh)
        return normalise_rows(features.double().numpy())

    def _oriented(
        self, network: DiffusionNet, shape: ShapeInput, mesh: Mesh, probe: ShapeInput | None = None
    ) -> tuple[ShapeInput, torch.Tensor]:
        """``shape`` of ``mesh`` in the orientation the search picks, and its output.

        The orientation is chosen on ``probe`` (default: ``mesh`` at the training resolution);
        without a search, ``shape`` is returned as it is.
        """
        if self.orientation is not None and probe is None:
            probe = probe_input(mesh, self.config, self.train_faces, self.use_cache)
        probes = None if probe is None else [probe]
        [(chosen, features)] = oriented_outputs(network, [shape], self.orientation, probes)
        if self.orientation is not None:
            self.orientations[mesh.name] = chosen
        if chosen.degrees != 0.0:
            logger.info("%s: input %s (orientation search)", mesh.name, chosen.describe())
        return rotated_input(shape, chosen.rotation), features


def orientation_search_of(
    checkpoint: dict[str, Any],
    model: ModelConfig,
    loss: FmapLossConfig,
    turns: int | None,
    path: str | os.PathLike,
    use_cache: bool = True,
    frames: bool = False,
) -> OrientationSearch | None:
    """The orientation search a checkpoint asks for, with ``turns`` overriding its setting."""
    payload = checkpoint.get("orientation")
    if turns is not None and turns < 0:
        raise ValueError(f"orientation_turns must be >= 0, got {turns}")
    if payload is None:
        if turns is None and model.input in COORDINATE_INPUTS:
            logger.warning(
                "%s: no orientation reference; shapes must share the training shapes' orientation", path
            )
        if turns and searches_orientation(model, turns):
            raise CheckpointError(
                f"{path}: the checkpoint has no orientation reference (written before the search existed, "
                "or trained with data.orientation_turns=0); retrain it or set orientation_turns=0"
            )
        return None
    try:
        return search_from_payload(payload, model, loss, turns, use_cache, frames)
    except (KeyError, TypeError, ValueError, AttributeError) as error:
        raise CheckpointError(f"{path}: unreadable orientation reference ({error})") from error


class EnsembleOrientations:
    """The orientations the members of an :class:`EnsembleExtractor` chose, read and cleared as one dict."""

    def __init__(self, members: list[LearnedExtractor]) -> None:
        self.members = members

    def items(self):
        """(mesh name and network number, :class:`Orientation`) of every choice of every member."""
        for number, member in enumerate(self.members, start=1):
            for name, chosen in member.orientations.items():
                yield f"{name} (network {number})", chosen

    def get(self, name: str, default=None):
        """The first member's choice for ``name`` (the one its search reports), else ``default``."""
        return self.members[0].orientations.get(name, default)

    def clear(self) -> None:
        """Forget every member's choices (the next pair reports its own)."""
        for member in self.members:
            member.orientations.clear()

    def __len__(self) -> int:
        return sum(len(member.orientations) for member in self.members)


class EnsembleExtractor:
    """Descriptors of several trained networks side by side: each row the members' rows over sqrt(n).

    Two trainings of one recipe place the same hard parts differently (docs/partial.md): one
    network confuses the front of a single view with the back where another does not. Joined,
    the similarity of two vertices is the mean of the members' similarities, so a member that
    is sure outweighs one that is torn. Each member searches its own orientation (and, for a
    part, placement) and adapts on its own; the rows stay unit-norm, so every cost that reads
    descriptors reads these unchanged.

    Parameters
    ----------
    checkpoints : list of str
        Two or more checkpoints written by ``spidermatch-train`` (same ``n_eig``, any widths).
    **options
        Passed to every member's :class:`LearnedExtractor`.

    """

    name = "learned"

    def __init__(self, checkpoints, **options) -> None:
        checkpoints = [str(path) for path in checkpoints]
        if len(checkpoints) < 2:
            raise ValueError(f"an ensemble needs at least two checkpoints, got {len(checkpoints)}")
        self.members = [LearnedExtractor(path, **options) for path in checkpoints]
        self.checkpoint = ", ".join(checkpoints)
        self.orientations = EnsembleOrientations(self.members)

    @property
    def turns(self) -> dict[str, float]:
        """Mesh name -> the first member's turn about the vertical (degrees), where it chose one."""
        return self.members[0].turns

    def _joined(self, parts: list[np.ndarray]) -> np.ndarray:
        return np.hstack(parts) / np.sqrt(len(parts))

    def _joined_pairs(self, pairs: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
        return self._joined([x for x, _ in pairs]), self._joined([y for _, y in pairs])

    def __call__(self, mesh: Mesh) -> np.ndarray:
        """Descriptors of shape (V, n * C_out), rows L2-normalised, float64."""
        return self._joined([member(mesh) for member in self.members])

    def pair_features(self, mesh_x: Mesh, mesh_y: Mesh) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`LearnedExtractor.pair_features` of every member, joined, (V_x, D) and (V_y, D)."""
        return self._joined_pairs([member.pair_features(mesh_x, mesh_y) for member in self.members])

    def part_features(self, part: Mesh, whole: Mesh) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`LearnedExtractor.part_features` of every member, joined, (V_part, D) and (V_whole, D)."""
        return self._joined_pairs([member.part_features(part, whole) for member in self.members])

    def part_feature_options(
        self, part: Mesh, whole: Mesh, count: int = PLACED_ORIENTATIONS
    ) -> tuple[list[tuple[str, np.ndarray]], np.ndarray]:
        """:meth:`LearnedExtractor.part_feature_options` of every member, the k-th options joined."""
        found = [member.part_feature_options(part, whole, count) for member in self.members]
        options = [
            (" + ".join(label for label, _ in row), self._joined([features for _, features in row]))
            for row in zip(*(member_options for member_options, _ in found))
        ]
        return options, self._joined([feat_whole for _, feat_whole in found])

    def parts_features(self, part_x: Mesh, part_y: Mesh) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`LearnedExtractor.parts_features` of every member, joined, (V_x, D) and (V_y, D)."""
        return self._joined_pairs([member.parts_features(part_x, part_y) for member in self.members])
