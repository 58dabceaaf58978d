"""Typed settings of a training run (also the Hydra schema registered by :mod:`train.cli`).

Nothing here imports Hydra: the loop takes a :class:`TrainConfig`, the CLI builds it
from the composed configuration.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from features.diffusion_net import ModelConfig
from features.orientation import UP_AXES
from train.losses import LossConfig

# Sections a resumed run must share with its checkpoint; ``run`` (step count,
# validation and logging cadence, threads) and ``resume`` may change.
COMPATIBLE_SECTIONS = ("seed", "model", "loss", "optim", "data")
# Keys of ``data`` that may change on resume (where the files are, cache use).
RELOCATABLE_DATA_KEYS = ("root", "use_cache", "orientation_turns")
VAL_PAIR_MODES = ("all", "class")
ROTATION_MODES = ("none", "y", "all")
SCHEDULES = ("step", "cosine")


@dataclass
class DataConfig:
    """Where the shapes come from and how they are split and resampled.

    Attributes
    ----------
    root : str, optional
        A FAUST_r-style folder (``off/``, ``corres/``); None uses generated creatures.
    train, val : list of str or str, optional
        Shape names: a list, an inclusive name range ``"first..last"`` or an index
        slice ``"start:stop"`` over the sorted names. None: every k-th of the sorted
        names validates (about one in 8, at least 2 when there are 4 or more
        shapes, else 1) and the others train (see :func:`train.data.default_split`).
    val_pairs : str
        Validation pairs: ``"all"`` (every ordered pair of validation shapes; a single
        validation shape is paired with training shapes) or ``"class"`` (each
        validation shape with every other shape of its class, both directions; the
        class is the name without trailing digits, e.g. ``cat3`` -> ``cat``).
    label_free_pairs : int
        At most this many of the validation pairs give the label-free figure (the
        unsupervised loss at training resolution).
    augment_rotation : str
        Random rotation of ``xyz`` network inputs at each training step: ``"none"``,
        ``"y"`` (about the y axis, for upright shapes) or ``"all"`` (uniform over SO(3)).
        WKS inputs are invariant and ignore it.
    target_faces : int, optional
        Decimate training shapes to about this many faces (None: full resolution).
    synthetic_shapes, synthetic_verts : int
        Size of the generated dataset when ``root`` is None.
    val_points : int, optional
        Reference points per validation pair (evenly spaced rows of the ground
        truth; None uses all).
    use_cache : bool
        Use the on-disk operator cache.
    repair : bool
        A shape of ``root`` that fails the checks only as a raw scan does (debris, bow-ties,
        stray vertices, slivers, fins) is trained on as its largest clean piece, as
        ``spidermatch-match repair=true`` matches it; false refuses it (every such shape is
        named before the data preparation).
    orientation_turns : int
        For networks that read coordinates (``xyz``, ``wks_xyz``): validation and inference
        present each shape in this many turns about the vertical axis and keep the one whose
        unsupervised loss against the first training shape is lowest (no labels; see
        :mod:`features.orientation`). 0 turns the search off; WKS inputs ignore it.
    up_axis : str
        The axis the training shapes stand along (``"y"`` for FAUST_r, ``"z"`` for
        TOSCA_animals): the orientation search turns about it. Stored in the checkpoint with
        the search's reference.
    partial_copies : int
        Partial copies made of every training shape (plane cuts, holes and single views in
        turn; :func:`spidermatch.geometry.partial.random_cut`), for the cut-consistency term of the
        loss (``loss.w_partial``). 0: none.
    partial_keep : list of two floats
        Range of the area fraction a partial copy keeps.
    partial_placed : float
        Share of the steps at which a partial copy is shown where it lies on its whole (its
        centre moved by its offset from the whole's centre, plus ``partial_jitter``) instead
        of centred on itself, as the inference's placement search (``features.orientation``)
        shows a part. 0: always centred. At 0.5 the FAUST_r partial recipe did no better on
        parts than at 0 (docs/partial.md, "Features that survive cuts").
    partial_jitter : float
        Half-width of the uniform random shift added to a placed copy's offset, per axis, in
        the whole's unit of length (sqrt of its area); about half the inference grid's step.
    """

    root: str | None = None
    train: Any = None
    val: Any = None
    val_pairs: str = "all"
    label_free_pairs: int = 20
    augment_rotation: str = "none"
    target_faces: int | None = 4000
    synthetic_shapes: int = 6
    synthetic_verts: int = 2000
    val_points: int | None = 500
    use_cache: bool = True
    repair: bool = False
    orientation_turns: int = 0
    up_axis: str = "y"
    partial_copies: int = 0
    partial_keep: Any = (0.3, 0.7)
    partial_placed: float = 0.0
    partial_jitter: float = 0.075

    def __post_init__(self) -> None:
        if self.orientation_turns < 0:
            raise ValueError(f"data.orientation_turns must be >= 0, got {self.orientation_turns}")
        if self.up_axis not in UP_AXES:
            raise ValueError(f"data.up_axis must be one of {UP_AXES}, got {self.up_axis!r}")
        if self.partial_copies < 0:
            raise ValueError(f"data.partial_copies must be >= 0, got {self.partial_copies}")
        keep = list(self.partial_keep)
        if len(keep) != 2 or not 0.0 < keep[0] <= keep[1] < 1.0:
            raise ValueError(f"data.partial_keep must be [low, high] with 0 < low <= high < 1, got {keep}")
        self.partial_keep = [float(keep[0]), float(keep[1])]
        if not 0.0 <= self.partial_placed <= 1.0:
            raise ValueError(f"data.partial_placed must be a share in [0, 1], got {self.partial_placed}")
        if self.partial_jitter < 0:
            raise ValueError(f"data.partial_jitter must be >= 0, got {self.partial_jitter}")
        if self.val_pairs not in VAL_PAIR_MODES:
            raise ValueError(f"data.val_pairs must be one of {VAL_PAIR_MODES}, got {self.val_pairs!r}")
        if self.augment_rotation not in ROTATION_MODES:
            raise ValueError(
                f"data.augment_rotation must be one of {ROTATION_MODES}, got {self.augment_rotation!r}"
            )
        if self.label_free_pairs < 1:
            raise ValueError(f"data.label_free_pairs must be positive, got {self.label_free_pairs}")


@dataclass
class OptimConfig:
    """Adam with a step learning-rate schedule and gradient-norm clipping.

    Attributes
    ----------
    lr : float
    weight_decay : float
    schedule : str
        ``"step"``: multiply the learning rate by ``decay_gamma`` every ``decay_every``
        steps; ``"cosine"``: cosine annealing from ``lr`` to ``lr_min`` over ``run.n_steps``.
    decay_every : int
    decay_gamma : float
    lr_min : float
        Final learning rate of the cosine schedule.
    grad_clip : float
        Maximum gradient norm (0 disables clipping).
    ema_decay : float
        Keep an exponential moving average of the weights with this decay per step
        (0 disables it). Validation, ``best.pt`` and inference use the average;
        early steps use the smaller decay ``(1 + step) / (10 + step)``.
    """

    lr: float = 1e-3
    weight_decay: float = 0.0
    schedule: str = "step"
    decay_every: int = 2500
    decay_gamma: float = 0.5
    lr_min: float = 1e-4
    grad_clip: float = 1.0
    ema_decay: float = 0.999


@dataclass
class RunConfig:
    """Length and cadence of a run; may change when resuming.

    Attributes
    ----------
    n_steps : int
        Total optimisation steps (one shape pair per step).
    val_every : int
        Validate (and write ``last.pt``, ``best.pt``) every this many steps.
    checkpoint_every : int
        Also write ``last.pt`` every this many steps.
    log_every : int
        Append the loss terms to ``losses.csv`` every this many steps.
    progress : bool
        Show a tqdm progress bar.
    threads : int, optional
        ``torch.set_num_threads`` (None leaves torch's default).
    time_limit_min : float, optional
        Stop training (after validating and checkpointing) once this many minutes
        have passed since the run started, data preparation included; None: no limit.
    """

    n_steps: int = 300
    val_every: int = 100
    checkpoint_every: int = 100
    log_every: int = 1
    progress: bool = True
    threads: int | None = None
    time_limit_min: float | None = None


@dataclass
class TrainConfig:
    """A whole training run."""

    seed: int = 0
    model: ModelConfig = field(default_factory=ModelConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    data: DataConfig = field(default_factory=DataConfig)
    run: RunConfig = field(default_factory=RunConfig)
    resume: str | None = None

    def __post_init__(self) -> None:
        if self.loss.n_fmap > self.model.n_eig:
            raise ValueError(
                f"loss.n_fmap = {self.loss.n_fmap} exceeds the model's n_eig = {self.model.n_eig} eigenpairs"
            )
        if not 0.0 <= self.optim.ema_decay < 1.0:
            raise ValueError(f"optim.ema_decay must be in [0, 1), got {self.optim.ema_decay}")
        if self.optim.schedule not in SCHEDULES:
            raise ValueError(f"optim.schedule must be one of {SCHEDULES}, got {self.optim.schedule!r}")
        if self.loss.w_partial > 0 and self.data.partial_copies == 0:
            raise ValueError("loss.w_partial > 0 needs partial copies of the shapes: set data.partial_copies")
        for key in ("n_steps", "val_every", "checkpoint_every", "log_every"):
            if getattr(self.run, key) < 1:
                raise ValueError(f"run.{key} must be positive, got {getattr(self.run, key)}")

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (lists, str, numbers) for checkpoints."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> TrainConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise TypeError."""
        sections = {
            "model": ModelConfig,
            "loss": LossConfig,
            "optim": OptimConfig,
            "data": DataConfig,
            "run": RunConfig,
        }
        kwargs = {key: sections[key](**value) if key in sections else value for key, value in values.items()}
        return cls(**kwargs)


def incompatibilities(current: dict[str, Any], stored: dict[str, Any]) -> list[str]:
    """Settings that differ between a run's config and a checkpoint's, as ``key: a != b``.

    Only :data:`COMPATIBLE_SECTIONS` are compared, without the relocatable data keys. A key
    that a checkpoint from an older version lacks counts as its default value.
    """
    differences = []
    defaults = TrainConfig().to_dict()
    for section in COMPATIBLE_SECTIONS:
        mine, theirs = current.get(section), stored.get(section)
        if isinstance(mine, dict) and isinstance(theirs, dict):
            theirs = {**{k: v for k, v in defaults[section].items() if k not in theirs}, **theirs}
            for key in sorted(set(mine) | set(theirs)):
                if section == "data" and key in RELOCATABLE_DATA_KEYS:
                    continue
                if mine.get(key, "<missing>") != theirs.get(key, "<missing>"):
                    differences.append(
                        f"{section}.{key}: {mine.get(key, '<missing>')!r} "
                        f"(now) != {theirs.get(key, '<missing>')!r} (checkpoint)"
                    )
        elif mine != theirs:
            differences.append(f"{section}: {mine!r} (now) != {theirs!r} (checkpoint)")
    return differences
