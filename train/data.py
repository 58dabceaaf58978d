"""Training and validation shapes: dataset split, resampling, precomputed network inputs.

Every operator is computed (or read from the operator cache) once, before the
training loop; the loop only indexes the prepared tensors.
"""

from __future__ import annotations

import itertools
import logging
import zlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree
from tqdm.auto import tqdm

from features.diffusion_net import DiffusionNet, ModelConfig, ShapeInput, prepare_shape
from features.orientation import Orientation, OrientationSearch, oriented_outputs
from features.wks import normalise_rows
from spidermatch.data.datasets import DatasetError, Shape, ShapeFolder, SyntheticShapes, open_dataset
from spidermatch.geometry.geodesics import GeodesicDistances
from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.partial import CUT_KINDS, PartialShape, random_cut
from spidermatch.geometry.remesh import decimate
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
    mesh : Mesh, optional
        The mesh at training resolution (V_low vertices).
    partials : tuple of PartialInput
        Partial copies of the mesh (``data.partial_copies``), for the cut-consistency loss.
    """

    name: str
    input: ShapeInput
    corr: torch.Tensor | None
    mesh: Mesh | None = None
    partials: tuple = ()


@dataclass(frozen=True, eq=False)
class PartialInput:
    """A partial copy of a training shape, measured in the whole shape's unit of length.

    Attributes
    ----------
    input : ShapeInput
        Features (V_p, C_in) and operators of the part.
    to_whole : torch.Tensor, shape (V_p,), int64
        Vertex of the training-resolution shape each vertex of the part is.
    kind : str
        How it was cut (:data:`spidermatch.geometry.partial.CUT_KINDS`).
    offset : torch.Tensor, shape (3,)
        Where the part's centre lies relative to the whole's, in the whole's unit of length:
        added to the part's (self-centred) coordinates, it shows the part at its place.
    """

    input: ShapeInput
    to_whole: torch.Tensor
    kind: str
    offset: torch.Tensor


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
        config.root,
        config.repair,
        "data.repair=true",
        n_shapes=config.synthetic_shapes,
        n_verts=config.synthetic_verts,
        seed=SYNTHETIC_SEED,
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


def default_split(names: Sequence[str]) -> tuple[list[str], list[str]]:
    """Deterministic split of a folder without a split file: every k-th shape validates.

    About one shape in 8 validates, spread evenly over the sorted names (so folders whose
    names group classes, like ``cat0..cat10, dog0..``, validate on several classes); at
    least 2 when there are 4 or more shapes (so validation has held-out pairs), else 1.
    With only 2 shapes both train, and the validation shape is also trained on.

    Raises
    ------
    ValueError
        Fewer than 2 shapes.
    """
    ordered = sorted(names)
    n = len(ordered)
    if n < 2:
        raise ValueError(f"training needs at least 2 shapes, found {n} ({', '.join(ordered) or 'none'})")
    n_val = max(1, min(2, n - 2), round(n / 8))
    spacing = n / n_val
    val = [ordered[min(n - 1, int((i + 0.5) * spacing))] for i in range(n_val)]
    train = [name for name in ordered if name not in val]
    if len(train) < 2:
        logger.warning("only %d shapes: %s is trained on too (no held-out shape)", n, val[0])
        train = ordered
    return train, val


def split_names(names: Sequence[str], config: DataConfig) -> tuple[list[str], list[str]]:
    """Training and validation names; unset parts default to :func:`default_split`."""
    auto_train, auto_val = default_split(names)
    val = select_names(names, config.val, "data.val") if config.val is not None else auto_val
    if config.train is not None:
        train = select_names(names, config.train, "data.train")
    elif config.val is not None:
        train = [name for name in sorted(names) if name not in val]
    else:
        train = auto_train
    if len(train) < 2:
        raise ValueError(f"training needs at least 2 shapes, got {len(train)} ({train})")
    overlap = sorted(set(train) & set(val))
    if overlap:
        logger.warning("%d shapes are both trained and validated on (e.g. %s)", len(overlap), overlap[0])
    return train, val


def shape_class(name: str) -> str:
    """The class of a shape: its name without trailing digits (``cat10`` -> ``cat``)."""
    return name.rstrip("0123456789") or name


def validation_pairs(
    val: Sequence[str], train: Sequence[str], mode: str = "all", max_partners: int = 4
) -> list[tuple[str, str]]:
    """Ordered (source, target) name pairs that validate.

    Parameters
    ----------
    val, train : sequence of str
        Validation and training names.
    mode : str
        ``"all"``: every ordered pair of distinct validation shapes; with a single
        validation shape, it and up to ``max_partners`` training shapes, both directions.
        ``"class"``: each validation shape with every other shape of its class
        (:func:`shape_class`) among validation and training names, both directions.
    max_partners : int

    Returns
    -------
    list of (str, str)
        Without duplicates, in a deterministic order.
    """
    val = list(dict.fromkeys(val))
    if mode == "class":
        everyone = list(dict.fromkeys([*val, *train]))
        partners = {v: [w for w in everyone if w != v and shape_class(w) == shape_class(v)] for v in val}
    elif len(val) >= 2:
        partners = {v: [w for w in val if w != v] for v in val}
    else:
        partners = {v: [w for w in train if w != v][:max_partners] for v in val}
    pairs = []
    for v, others in partners.items():
        for w in others:
            pairs.extend([(v, w), (w, v)])
    pairs = list(dict.fromkeys(pairs))
    if not pairs:
        raise ValueError(f"no validation pairs: {val} have no partner shape (data.val_pairs={mode})")
    return pairs


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
    partials = partial_inputs(mesh, shape.name, model, config)
    whole = prepare_shape(mesh, model, use_cache=config.use_cache)
    return TrainShape(shape.name, whole, corr, mesh, partials)


def check_fmap_room(prepared: TrainShape, n_fmap: int, dataset) -> TrainShape:
    """``prepared`` if its operators hold the ``n_fmap`` eigenpairs the functional-map loss takes.

    Raises
    ------
    DatasetError
        Naming the shape's file: the loss would otherwise fail at whichever later step first
        draws the shape (a training shape) or at the first validation (a held-out one).
    """
    eigenpairs = prepared.input.ops.k
    if eigenpairs < n_fmap:
        where = dataset.mesh_path(prepared.name) if hasattr(dataset, "mesh_path") else prepared.name
        raise DatasetError(
            f"{where}: {prepared.mesh.n_verts} vertices (at training resolution) give {eigenpairs} "
            f"eigenpairs, fewer than the functional-map loss takes (loss.n_fmap = {n_fmap}): remove the "
            "shape from the folder"
        )
    return prepared


def partial_inputs(mesh: Mesh, name: str, model: ModelConfig, config: DataConfig) -> tuple[PartialInput, ...]:
    """``config.partial_copies`` random cuts of ``mesh`` (kinds in turn), seeded by the shape's name.

    Each part is measured in the whole's unit of length (``scale_area``), as the partial
    mode presents a partial scan in its target's unit. A kind that keeps no part within
    ``config.partial_keep`` (e.g. a single view of a thin shape) is skipped, with a warning.
    """
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    parts = []
    for k in range(config.partial_copies):
        kind = CUT_KINDS[k % len(CUT_KINDS)]
        try:
            part, shape, offset = cut_input(
                mesh, kind, rng, tuple(config.partial_keep), f"{name}#{kind}{k}", model, config.use_cache
            )
        except ValueError as error:
            logger.warning("partial copy %d of %s skipped: %s", k, name, error)
            continue
        offset = torch.from_numpy(offset).to(shape.features.dtype)
        parts.append(PartialInput(shape, torch.from_numpy(part.to_original), kind, offset))
    return tuple(parts)


def cut_input(
    mesh: Mesh,
    kind: str,
    rng: np.random.Generator,
    keep: tuple[float, float],
    name: str,
    model: ModelConfig,
    use_cache: bool,
) -> tuple[PartialShape, ShapeInput, np.ndarray]:
    """A random cut of ``mesh``, its network input in the whole's unit, and its place on the whole.

    Returns
    -------
    part : PartialShape
    shape : ShapeInput
        Features (V_p, C_in) and operators of the part, centred on itself, measured in
        sqrt(``mesh.area``).
    offset : np.ndarray, shape (3,)
        :func:`place_of_part` of the part.

    Raises
    ------
    ValueError
        No cut of ``kind`` keeps an area fraction in ``keep`` (:func:`random_cut`).
    """
    part = random_cut(mesh, kind, rng, keep, name)
    shape = prepare_shape(part.mesh, model, use_cache=use_cache, scale_area=mesh.area)
    return part, shape, place_of_part(part.mesh.verts, mesh.verts, mesh.area)


def place_of_part(part_verts: np.ndarray, whole_verts: np.ndarray, whole_area: float) -> np.ndarray:
    """Offset (3,) of a part's vertex mean from its whole's, divided by sqrt(``whole_area``).

    Network inputs centre coordinates on the vertex mean (:func:`features.diffusion_net.input_features`),
    so this is what moves a part's input to where the part lies in its whole's input.
    """
    return (part_verts.mean(axis=0) - whole_verts.mean(axis=0)) / np.sqrt(whole_area)


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


def network_outputs(
    network: DiffusionNet,
    shapes: Sequence,
    orientation: OrientationSearch | None,
    probes: list[ShapeInput] | None = None,
) -> list[torch.Tensor]:
    """The network's output (V, C_out) on every shape's ``input``, without gradients.

    With an orientation search, each shape is presented in the turn the search chooses
    (on ``probes``, the shapes at training resolution, when given).
    """
    found = oriented_outputs(network, [shape.input for shape in shapes], orientation, probes)
    return [feats for _, feats in found]


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
    pairs : list of (int, int), optional
        Ordered pairs of indices into ``shapes`` (default: every ordered pair).
    orientation : OrientationSearch, optional
        Present every shape in the turn the search chooses (None: as it is).
    probes : list of ShapeInput, optional
        The shapes at training resolution, on which the search chooses the turns.
    """

    def __init__(
        self,
        shapes: list[ValShape],
        val_points: int | None = None,
        progress: bool = False,
        pairs: list[tuple[int, int]] | None = None,
        orientation: OrientationSearch | None = None,
        probes: list[ShapeInput] | None = None,
    ) -> None:
        n_refs = min(len(shape.corr) for shape in shapes)
        if any(len(shape.corr) != n_refs for shape in shapes):
            counts = ", ".join(f"{shape.name}: {len(shape.corr)}" for shape in shapes)
            raise ValueError(f"validation shapes have ground truth of different lengths ({counts})")
        count = n_refs if val_points is None else min(val_points, n_refs)
        self.rows = np.unique(np.linspace(0, n_refs - 1, count).round().astype(np.int64))
        self.shapes = shapes
        self.pairs = list(itertools.permutations(range(len(shapes)), 2)) if pairs is None else list(pairs)
        self._tables: list[np.ndarray] | None = None
        self.progress = progress
        self.orientation, self.probes = orientation, probes

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
        return self.oriented_features(network)[1]

    def oriented_features(self, network: DiffusionNet) -> tuple[list[Orientation], list[np.ndarray]]:
        """How every validation shape was presented, and its L2-normalised descriptors (V, C_out)."""
        was_training = network.training
        network.eval()
        found = oriented_outputs(
            network, [shape.input for shape in self.shapes], self.orientation, self.probes
        )
        network.train(was_training)
        return [chosen for chosen, _ in found], [normalise_rows(feats.double().numpy()) for _, feats in found]

    def pair_errors(self, feats: list[np.ndarray], i: int, j: int) -> np.ndarray:
        """Errors of the nearest-neighbour map from shape i to shape j, one per reference point (K,)."""
        source_refs = self.shapes[i].corr[self.rows]
        predicted = np.argmax(feats[i][source_refs] @ feats[j].T, axis=1)
        table = self.distance_tables()[j]
        return table[np.arange(self.rows.size), predicted].astype(np.float64)

    def __call__(self, network: DiffusionNet) -> float:
        """Mean over pairs of the pair's mean normalised geodesic error."""
        return self.error_of(self.features(network))

    def error_of(self, feats: list[np.ndarray]) -> float:
        """Mean pair error of given L2-normalised descriptors, one (V, C) array per shape."""
        return float(np.mean([self.pair_errors(feats, i, j).mean() for i, j in self.pairs]))

    def wks_error(self, use_cache: bool = True) -> float:
        """The same figure for WKS descriptors (``features=wks`` of spidermatch-match)."""
        from features.extractor import WKSExtractor

        extractor = WKSExtractor(use_cache=use_cache)
        return self.error_of([extractor(shape.mesh) for shape in self.shapes])
