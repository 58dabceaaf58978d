"""Training and validation shapes: dataset split, resampling, precomputed network inputs.

Every operator is computed (or read from the operator cache) once, before the
training loop; the loop only indexes the prepared tensors.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree
from tqdm.auto import tqdm

from features.diffusion_net import DiffusionNet, ModelConfig, ShapeInput, prepare_shape
from features.wks import normalise_rows
from spidermatch.datasets import Shape, ShapeFolder, SyntheticShapes, open_dataset
from spidermatch.geodesics import GeodesicDistances
from spidermatch.mesh import Mesh
from spidermatch.remesh import decimate
from train.config import DataConfig

logger = logging.getLogger(__name__)

SYNTHETIC_SEED = 0


@dataclass(frozen=True, eq=False)
class TrainShape:
    """A training shape at training resolution (V_low vertices).

    Attributes
    ----------
    name : str
    input : ShapeInput
        Features (V_low, C_in) and operators.
    corr : torch.Tensor, shape (N,), int64, or None
        Training-resolution vertex nearest to each reference point.
    """

    name: str
    input: ShapeInput
    corr: torch.Tensor | None


@dataclass(frozen=True, eq=False)
class ValShape:
    """A validation shape at full resolution (V vertices).

    Attributes
    ----------
    name : str
    mesh : Mesh
    input : ShapeInput
    corr : np.ndarray, shape (N,)
        Vertex of each reference point.
    """

    name: str
    mesh: Mesh
    input: ShapeInput
    corr: np.ndarray


def open_shapes(config: DataConfig) -> ShapeFolder | SyntheticShapes:
    """The dataset named by ``config.root`` (generated creatures when it is None)."""
    return open_dataset(
        config.root, n_shapes=config.synthetic_shapes, n_verts=config.synthetic_verts, seed=SYNTHETIC_SEED
    )


def select_names(names: Sequence[str], spec: str | Sequence[str], what: str) -> list[str]:
    """Names chosen by ``spec``: a list, ``"first..last"`` (inclusive) or ``"start:stop"``.

    Ranges and slices refer to the sorted ``names``. Raises ValueError naming ``what``
    (e.g. ``"data.train"``) for unknown names or an empty selection.
    """
    ordered = sorted(names)
    if isinstance(spec, str) and ".." in spec:
        first, last = (part.strip() for part in spec.split("..", 1))
        for name in (first, last):
            if name not in ordered:
                raise ValueError(f"{what} = {spec!r}: no shape named {name!r}")
        chosen = ordered[ordered.index(first) : ordered.index(last) + 1]
    elif isinstance(spec, str) and ":" in spec:
        try:
            bounds = [int(part) if part.strip() else None for part in spec.split(":")]
        except ValueError as error:
            raise ValueError(f"{what} = {spec!r}: expected 'start:stop' integers") from error
        if len(bounds) != 2:
            raise ValueError(f"{what} = {spec!r}: expected 'start:stop'")
        chosen = ordered[slice(*bounds)]
    else:
        chosen = [spec] if isinstance(spec, str) else [str(name) for name in spec]
        unknown = [name for name in chosen if name not in ordered]
        if unknown:
            raise ValueError(f"{what}: unknown shape {unknown[0]!r} ({len(ordered)} shapes available)")
    if not chosen:
        raise ValueError(f"{what} = {spec!r} selects no shapes")
    return chosen


def split_names(names: Sequence[str], config: DataConfig) -> tuple[list[str], list[str]]:
    """Training and validation names; unset parts default to a split by sorted order."""
    ordered = sorted(names)
    n_val = max(2, round(len(ordered) / 8))
    train = (
        select_names(ordered, config.train, "data.train") if config.train is not None else ordered[:-n_val]
    )
    val = select_names(ordered, config.val, "data.val") if config.val is not None else ordered[-n_val:]
    if len(train) < 2:
        raise ValueError(f"training needs at least 2 shapes, got {len(train)} ({train})")
    if len(val) < 2:
        raise ValueError(f"validation needs at least 2 shapes, got {len(val)} ({val})")
    overlap = sorted(set(train) & set(val))
    if overlap:
        logger.warning("%d shapes are both trained and validated on (e.g. %s)", len(overlap), overlap[0])
    return train, val


def prepare_train_shape(shape: Shape, model: ModelConfig, config: DataConfig) -> TrainShape:
    """Decimate (if ``config.target_faces``) and precompute the network input of one shape."""
    mesh, corr = shape.mesh, None
    if config.target_faces is not None and mesh.n_faces > config.target_faces:
        low = decimate(mesh, config.target_faces).mesh
        if shape.corr is not None:
            _, nearest = cKDTree(low.verts).query(mesh.verts[shape.corr])
            corr = torch.from_numpy(np.asarray(nearest, dtype=np.int64))
        mesh = low
    elif shape.corr is not None:
        corr = torch.from_numpy(np.asarray(shape.corr, dtype=np.int64))
    return TrainShape(shape.name, prepare_shape(mesh, model, use_cache=config.use_cache), corr)


def prepare_val_shape(shape: Shape, model: ModelConfig, config: DataConfig) -> ValShape:
    """Full-resolution network input of one validation shape (it needs ground truth)."""
    if shape.corr is None:
        raise ValueError(f"validation shape {shape.name} has no ground truth (.vts file)")
    return ValShape(
        shape.name,
        shape.mesh,
        prepare_shape(shape.mesh, model, config.use_cache),
        np.asarray(shape.corr, dtype=np.int64),
    )


def prepare_shapes(
    dataset, names: list[str], prepare, model: ModelConfig, config: DataConfig, desc: str, progress: bool
) -> list:
    """Apply ``prepare(shape, model, config)`` to every named shape, with a progress bar."""
    return [
        prepare(dataset.load(name), model, config)
        for name in tqdm(names, desc=desc, disable=not progress, leave=False)
    ]


class Validator:
    """Mean geodesic error of the nearest-neighbour feature map on validation pairs.

    Every ordered pair of validation shapes is evaluated at full resolution on the
    same evenly spaced subset of reference points (all of them by default). The
    geodesic distances from each shape's reference vertices are computed once, on
    the first call, and kept as float32 tables (K x V per shape).

    Parameters
    ----------
    shapes : list of ValShape
    val_points : int, optional
        Reference points per pair (None: all).
    progress : bool
        Show a progress bar while the distance tables are computed.
    """

    def __init__(self, shapes: list[ValShape], val_points: int | None = None, progress: bool = False) -> None:
        n_refs = min(len(shape.corr) for shape in shapes)
        if any(len(shape.corr) != n_refs for shape in shapes):
            raise ValueError("validation shapes have ground truth of different lengths")
        count = n_refs if val_points is None else min(val_points, n_refs)
        self.rows = np.unique(np.linspace(0, n_refs - 1, count).round().astype(np.int64))
        self.shapes = shapes
        self.pairs = list(itertools.permutations(range(len(shapes)), 2))
        self._tables: list[np.ndarray] | None = None
        self.progress = progress

    def distance_tables(self) -> list[np.ndarray]:
        """Per shape, normalised geodesic distances from its reference vertices, (K, V) float32."""
        if self._tables is None:
            tables = []
            bar = tqdm(self.shapes, desc="validation geodesics", leave=False, disable=not self.progress)
            for shape in bar:
                fields = GeodesicDistances(shape.mesh).from_vertices(shape.corr[self.rows])
                tables.append((fields / np.sqrt(shape.mesh.area)).astype(np.float32))
            self._tables = tables
            logger.info(
                "validation: geodesic tables for %d shapes x %d reference points", len(tables), self.rows.size
            )
        return self._tables

    def features(self, network: DiffusionNet) -> list[np.ndarray]:
        """L2-normalised descriptors of every validation shape, each (V, C_out)."""
        was_training = network.training
        network.eval()
        with torch.no_grad():
            out = [
                normalise_rows(network(s.input.features, s.input.ops).double().numpy()) for s in self.shapes
            ]
        network.train(was_training)
        return out

    def pair_errors(self, feats: list[np.ndarray], i: int, j: int) -> np.ndarray:
        """Errors of the nearest-neighbour map from shape i to shape j, one per reference point (K,)."""
        source_refs = self.shapes[i].corr[self.rows]
        predicted = np.argmax(feats[i][source_refs] @ feats[j].T, axis=1)
        table = self.distance_tables()[j]
        return table[np.arange(self.rows.size), predicted].astype(np.float64)

    def __call__(self, network: DiffusionNet) -> float:
        """Mean over pairs of the pair's mean normalised geodesic error."""
        feats = self.features(network)
        return float(np.mean([self.pair_errors(feats, i, j).mean() for i, j in self.pairs]))
