"""Validation of a training run, with and without labels.

Two figures, both on held-out pairs (see :func:`train.data.validation_pairs`):

* ``val_error`` (needs ``corr/`` ground truth on every shape of the pairs): the mean
  geodesic error of the nearest-neighbour feature map at full resolution
  (:class:`train.data.Validator`);
* ``val_unsup`` (needs no labels): the unsupervised training objective (bijectivity,
  orthogonality and coupling, without the supervised term) of the evaluation
  network on the pairs at training resolution;
* ``val_partial`` (recipes with partial copies, ``data.partial_copies > 0``, and labels):
  the same nearest-neighbour error for partial copies of the held-out shapes (a plane cut,
  holes and a single view of each) against whole shapes they are paired with, each copy
  shown at its place on its whole (:class:`PartValidator`).

The checkpoint is selected on ``val_partial`` when it is computed (a partial recipe trains
for parts, and its whole-shape error can be lowest early in a run while its parts still
improve), else on ``val_error`` when labels exist, else on ``val_unsup``.
"""

from __future__ import annotations

import logging
import math
import zlib
from dataclasses import dataclass

import numpy as np
import torch

from features.diffusion_net import DiffusionNet, ModelConfig, ShapeInput
from features.fmap import FmapLossConfig, fmap_terms
from features.orientation import (
    COORDINATE_INPUTS,
    Orientation,
    OrientationSearch,
    presented_input,
    probe_input,
    searches_orientation,
)
from features.wks import normalise_rows
from spidermatch.geometry.partial import CUT_KINDS
from train.data import TrainShape, Validator, ValShape, cut_input, network_outputs

logger = logging.getLogger(__name__)

TERMS = ("bij", "orth", "couple")
PART_TARGETS = 2  # whole shapes each validation part is matched to (evenly among its pair partners)


def evenly_spaced(items: list, count: int) -> list:
    """At most ``count`` items of ``items``, evenly spaced, in order."""
    if len(items) <= count:
        return list(items)
    picks = np.unique(np.linspace(0, len(items) - 1, count).round().astype(np.int64))
    return [items[i] for i in picks]


class LossValidator:
    """Mean unsupervised loss of the network on shape pairs (a label-free figure).

    Parameters
    ----------
    shapes : list of TrainShape
        Shapes at training resolution.
    pairs : list of (int, int)
        Ordered pairs of indices into ``shapes``.
    loss : FmapLossConfig
        The training loss settings (its supervised weight, if any, is ignored).
    orientation : OrientationSearch, optional
        Present every shape in the turn the search chooses (None: as it is).
    """

    def __init__(
        self,
        shapes: list[TrainShape],
        pairs: list[tuple[int, int]],
        loss: FmapLossConfig,
        orientation: OrientationSearch | None = None,
    ) -> None:
        if not pairs:
            raise ValueError("LossValidator needs at least one pair")
        self.shapes, self.pairs, self.loss = shapes, list(pairs), loss
        self.orientation = orientation

    def __call__(self, network: DiffusionNet) -> dict[str, float]:
        """``{"val_unsup": mean weighted loss, "val_bij": ..., "val_orth": ..., "val_couple": ...}``."""
        was_training = network.training
        network.eval()
        sums = dict.fromkeys(("val_unsup", *(f"val_{t}" for t in TERMS)), 0.0)
        feats = network_outputs(network, self.shapes, self.orientation)
        with torch.no_grad():
            for i, j in self.pairs:
                x, y = self.shapes[i], self.shapes[j]
                terms = fmap_terms(feats[i], feats[j], x.input.ops, y.input.ops, self.loss)
                sums["val_unsup"] += terms.weighted(self.loss).item()
                for name in TERMS:
                    sums[f"val_{name}"] += getattr(terms, name).item()
        network.train(was_training)
        return {key: value / len(self.pairs) for key, value in sums.items()}


@dataclass(frozen=True, eq=False)
class ValPart:
    """A partial copy of a validation shape at full resolution, in its whole's unit of length.

    Attributes
    ----------
    name : str
    whole : int
        Index of the shape it was cut from (into :attr:`Validator.shapes`).
    input : ShapeInput
        Features (V_p, C_in) and operators of the part, centred on itself.
    position : np.ndarray, shape (V_whole,), int64
        Vertex of the part each vertex of the whole is (-1 where the cut removed it).
    offset : np.ndarray, shape (3,)
        Where the part's centre lies relative to the whole's, in the whole's unit
        (:func:`train.data.place_of_part`).
    targets : tuple of int
        Whole shapes (indices) the part is matched to.
    """

    name: str
    whole: int
    input: ShapeInput
    position: np.ndarray
    offset: np.ndarray
    targets: tuple[int, ...]


def validation_parts(
    validator: Validator, sources: list[int], model: ModelConfig, keep: tuple[float, float], use_cache: bool
) -> list[ValPart]:
    """A plane cut, holes and a single view of every shape in ``sources``, seeded by its name.

    Each part keeps an area fraction in ``keep`` and is paired with at most
    :data:`PART_TARGETS` of the shapes its whole is paired with in ``validator.pairs``. A cut
    that keeps no part within ``keep`` is skipped with a warning, as in training.
    """
    parts = []
    for i in sources:
        shape: ValShape = validator.shapes[i]
        partners = [j for a, j in validator.pairs if a == i]
        targets = tuple(evenly_spaced(partners, PART_TARGETS))
        rng = np.random.default_rng(zlib.crc32(f"validation part of {shape.name}".encode()))
        for kind in CUT_KINDS:
            try:
                cut, part_input, offset = cut_input(
                    shape.mesh, kind, rng, keep, f"{shape.name}#{kind}", model, use_cache
                )
            except ValueError as error:
                logger.warning("validation part %s of %s skipped: %s", kind, shape.name, error)
                continue
            position = cut.positions(shape.mesh.n_verts)
            parts.append(ValPart(cut.mesh.name, i, part_input, position, offset, targets))
    return parts


class PartValidator:
    """Mean geodesic error of the nearest-neighbour map from partial copies to whole shapes.

    The partial mode presents a part in its target's unit, turned and placed on it by a
    search (docs/partial.md); here each part is shown as that search means to show it: turned
    as its whole was presented, its centre at its place on the whole. The error of a part
    against a target is the mean over the validator's reference points the part kept, on
    the validator's geodesic tables.

    Parameters
    ----------
    validator : Validator
        Supplies the whole shapes, their reference points and geodesic tables.
    parts : list of ValPart
    places_parts : bool
        Whether the network reads coordinates (only then is a part turned and placed).
    """

    def __init__(self, validator: Validator, parts: list[ValPart], places_parts: bool) -> None:
        if not parts:
            raise ValueError("PartValidator needs at least one part")
        self.validator, self.parts, self.places_parts = validator, parts, places_parts

    def part_input(self, part: ValPart, orientation: Orientation) -> ShapeInput:
        """The part's input turned as its whole was (``orientation``) and placed on it."""
        if not self.places_parts:
            return part.input
        rotation = orientation.rotation.double()
        offset = rotation.numpy() @ part.offset
        return presented_input(part.input, Orientation(rotation, None, tuple(float(x) for x in offset)))

    def part_errors(
        self, part: ValPart, feat_part: np.ndarray, feat_target: np.ndarray, target: int
    ) -> np.ndarray:
        """Errors (K_kept,) of the part's nearest-feature map onto ``target``, at its kept reference points.

        ``feat_part`` (V_p, C) and ``feat_target`` (V_target, C) are L2-normalised.
        """
        rows = self.validator.rows
        kept_at = part.position[self.validator.shapes[part.whole].corr[rows]]
        kept = kept_at >= 0
        predicted = np.argmax(feat_part[kept_at[kept]] @ feat_target.T, axis=1)
        table = self.validator.distance_tables()[target]
        return table[np.flatnonzero(kept), predicted].astype(np.float64)

    def __call__(
        self, network: DiffusionNet, orientations: list[Orientation], feats: list[np.ndarray]
    ) -> float:
        """Mean over (part, target) of the mean error, given the whole shapes' orientations and features."""
        was_training = network.training
        network.eval()
        errors = []
        with torch.no_grad():
            for part in self.parts:
                shown = self.part_input(part, orientations[part.whole])
                feat_part = normalise_rows(network(shown.features, shown.ops).double().numpy())
                for j in part.targets:
                    kept = self.part_errors(part, feat_part, feats[j], j)
                    if kept.size:  # a part may keep none of a sparse set of reference points
                        errors.append(kept.mean())
        network.train(was_training)
        return float(np.mean(errors)) if errors else math.nan


@dataclass
class Validation:
    """The validation figures of a run.

    Attributes
    ----------
    label_free : LossValidator
    labelled : Validator, optional
        None when some shape of the validation pairs has no ground truth.
    wks_error : float
        ``val_error`` of WKS descriptors on the same pairs (nan without labels).
    partial : PartValidator, optional
        For recipes with partial copies (and labels).
    """

    label_free: LossValidator
    labelled: Validator | None = None
    wks_error: float = math.nan
    partial: PartValidator | None = None

    @property
    def criterion(self) -> str:
        """The figure that selects ``best.pt``: ``"val_partial"``, ``"val_error"`` or ``"val_unsup"``."""
        if self.partial is not None:
            return "val_partial"
        return "val_error" if self.labelled is not None else "val_unsup"

    def __call__(self, network: DiffusionNet) -> dict[str, float]:
        """All figures of ``network`` (evaluated in eval mode), keyed by name."""
        figures = self.label_free(network)
        figures["val_error"] = math.nan
        if self.labelled is not None:
            orientations, feats = self.labelled.oriented_features(network)
            figures["val_error"] = self.labelled.error_of(feats)
            if self.partial is not None:
                figures["val_partial"] = self.partial(network, orientations, feats)
        figures["wks_error"] = self.wks_error
        return figures


def label_free_validator(
    dataset,
    pairs: list[tuple[str, str]],
    known: dict[str, TrainShape],
    model,
    config,
    orientation: OrientationSearch | None = None,
) -> LossValidator:
    """LossValidator on at most ``data.label_free_pairs`` of ``pairs``, at training resolution.

    ``known`` maps names to already prepared training shapes; the others are prepared here.
    """
    from train.data import check_fmap_room, prepare_train_shape

    chosen = evenly_spaced(pairs, config.data.label_free_pairs)
    names = list(dict.fromkeys(name for pair in chosen for name in pair))
    shapes = [
        known[name]
        if name in known
        else check_fmap_room(
            prepare_train_shape(dataset.load(name), model, config.data), config.loss.n_fmap, dataset
        )
        for name in names
    ]
    index = {name: i for i, name in enumerate(names)}
    return LossValidator(shapes, [(index[a], index[b]) for a, b in chosen], config.loss, orientation)


def labelled_validator(
    dataset, pairs: list[tuple[str, str]], config, orientation: OrientationSearch | None = None
) -> Validator | None:
    """Validator at full resolution on ``pairs``, or None if a shape has no ground truth."""
    from tqdm.auto import tqdm

    from train.data import prepare_val_shape

    names = list(dict.fromkeys(name for pair in pairs for name in pair))
    loaded = [dataset.load(name) for name in names]
    unlabelled = [shape.name for shape in loaded if shape.corr is None]
    if unlabelled:
        logger.info("no ground truth for %s: validating without labels", unlabelled[0])
        return None
    bar = tqdm(loaded, desc="prepare validation shapes", disable=not config.run.progress, leave=False)
    shapes = [prepare_val_shape(shape, config.model, config.data) for shape in bar]
    index = {name: i for i, name in enumerate(names)}
    pair_indices = [(index[a], index[b]) for a, b in pairs]
    probes = None
    if orientation is not None:
        faces = config.data.target_faces
        probes = [probe_input(shape.mesh, config.model, faces, config.data.use_cache) for shape in shapes]
    return Validator(shapes, config.data.val_points, config.run.progress, pair_indices, orientation, probes)


def prepare_validation(
    dataset, pairs: list[tuple[str, str]], train_shapes: list[TrainShape], config
) -> Validation:
    """Both validators for ``pairs`` and the WKS figure on the labelled ones.

    Parameters
    ----------
    dataset : ShapeFolder or SyntheticShapes
    pairs : list of (str, str)
        From :func:`train.data.validation_pairs`.
    train_shapes : list of TrainShape
        Reused where a pair names a training shape.
    config : TrainConfig
    """
    known = {shape.name: shape for shape in train_shapes}
    orientation = None
    if searches_orientation(config.model, config.data.orientation_turns):
        orientation = OrientationSearch(
            train_shapes[0].input, config.data.orientation_turns, config.loss, up_axis=config.data.up_axis
        )
        logger.info(
            "validation: orientation search over %d turns against %s",
            config.data.orientation_turns,
            train_shapes[0].name,
        )
    label_free = label_free_validator(dataset, pairs, known, config.model, config, orientation)
    labelled = labelled_validator(dataset, pairs, config, orientation)
    wks = labelled.wks_error(config.data.use_cache) if labelled is not None else math.nan
    if labelled is not None:
        logger.info("validation: %d labelled pairs; WKS scores %.4f on them", len(labelled.pairs), wks)
    logger.info("validation: %d label-free pairs at training resolution", len(label_free.pairs))
    partial = None
    if labelled is not None and config.data.partial_copies > 0:
        partial = part_validator(labelled, set(known), config)
    return Validation(label_free, labelled, wks, partial)


def part_validator(labelled: Validator, training_names: set[str], config) -> PartValidator | None:
    """PartValidator on cuts of the held-out shapes among the labelled pairs' sources (None: no cut)."""
    shapes = labelled.shapes
    sources = sorted({i for i, _ in labelled.pairs if shapes[i].name not in training_names})
    parts = validation_parts(
        labelled, sources, config.model, tuple(config.data.partial_keep), config.data.use_cache
    )
    if not parts:
        logger.warning("validation: no partial copy of a held-out shape: best.pt is chosen on whole shapes")
        return None
    logger.info(
        "validation: %d partial copies of %d held-out shapes, each against %d whole shapes (val_partial)",
        len(parts),
        len(sources),
        PART_TARGETS,
    )
    return PartValidator(labelled, parts, config.model.input in COORDINATE_INPUTS)
