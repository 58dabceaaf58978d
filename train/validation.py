"""Validation of a training run, with and without labels.

Two figures, both on held-out pairs (see :func:`train.data.validation_pairs`):

* ``val_error`` (needs ``corr/`` ground truth on every shape of the pairs): the mean
  geodesic error of the nearest-neighbour feature map at full resolution
  (:class:`train.data.Validator`);
* ``val_unsup`` (needs no labels): the unsupervised training objective (bijectivity,
  orthogonality and coupling, without the supervised term) of the evaluation
  network on the pairs at training resolution.

The checkpoint is selected on ``val_error`` when labels exist, else on ``val_unsup``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import torch

from features.diffusion_net import DiffusionNet
from features.fmap import FmapLossConfig, fmap_terms
from features.orientation import OrientationSearch, probe_input, searches_orientation
from train.data import TrainShape, Validator, network_outputs

logger = logging.getLogger(__name__)

TERMS = ("bij", "orth", "couple")


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


@dataclass
class Validation:
    """Both validation figures of a run.

    Attributes
    ----------
    label_free : LossValidator
    labelled : Validator, optional
        None when some shape of the validation pairs has no ground truth.
    wks_error : float
        ``val_error`` of WKS descriptors on the same pairs (nan without labels).
    """

    label_free: LossValidator
    labelled: Validator | None = None
    wks_error: float = math.nan

    @property
    def criterion(self) -> str:
        """The figure that selects ``best.pt``: ``"val_error"`` or ``"val_unsup"``."""
        return "val_error" if self.labelled is not None else "val_unsup"

    def __call__(self, network: DiffusionNet) -> dict[str, float]:
        """All figures of ``network`` (evaluated in eval mode), keyed by name."""
        figures = self.label_free(network)
        figures["val_error"] = self.labelled(network) if self.labelled is not None else math.nan
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
    from train.data import prepare_train_shape

    chosen = evenly_spaced(pairs, config.data.label_free_pairs)
    names = list(dict.fromkeys(name for pair in chosen for name in pair))
    shapes = [
        known[name] if name in known else prepare_train_shape(dataset.load(name), model, config.data)
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
    return Validation(label_free, labelled, wks)
