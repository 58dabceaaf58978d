"""Typed settings of a training run (also the Hydra schema registered by :mod:`train.cli`).

Nothing here imports Hydra: the loop takes a :class:`TrainConfig`, the CLI builds it
from the composed configuration.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from features.diffusion_net import ModelConfig
from train.losses import LossConfig

# Sections a resumed run must share with its checkpoint; ``run`` (step count,
# validation and logging cadence, threads) and ``resume`` may change.
COMPATIBLE_SECTIONS = ("seed", "model", "loss", "optim", "data")
# Keys of ``data`` that may change on resume (where the files are, cache use).
RELOCATABLE_DATA_KEYS = ("root", "use_cache")


@dataclass
class DataConfig:
    """Where the shapes come from and how they are split and resampled.

    Attributes
    ----------
    root : str, optional
        A FAUST_r-style folder (``off/``, ``corres/``); None uses generated creatures.
    train, val : list of str or str, optional
        Shape names: a list, an inclusive name range ``"first..last"`` or an index
        slice ``"start:stop"`` over the sorted names. None: the last
        ``max(2, round(n / 8))`` names validate and the others train.
    target_faces : int, optional
        Decimate training shapes to about this many faces (None: full resolution).
    synthetic_shapes, synthetic_verts : int
        Size of the generated dataset when ``root`` is None.
    val_points : int, optional
        Reference points per validation pair (evenly spaced rows of the ground
        truth; None uses all).
    use_cache : bool
        Use the on-disk operator cache.
    """

    root: str | None = None
    train: Any = None
    val: Any = None
    target_faces: int | None = 4000
    synthetic_shapes: int = 6
    synthetic_verts: int = 2000
    val_points: int | None = 500
    use_cache: bool = True


@dataclass
class OptimConfig:
    """Adam with a step learning-rate schedule and gradient-norm clipping.

    Attributes
    ----------
    lr : float
    weight_decay : float
    decay_every : int
        Multiply the learning rate by ``decay_gamma`` every this many steps.
    decay_gamma : float
    grad_clip : float
        Maximum gradient norm (0 disables clipping).
    ema_decay : float
        Keep an exponential moving average of the weights with this decay per step
        (0 disables it). Validation, ``best.pt`` and inference use the average;
        early steps use the smaller decay ``(1 + step) / (10 + step)``.
    """

    lr: float = 1e-3
    weight_decay: float = 0.0
    decay_every: int = 2500
    decay_gamma: float = 0.5
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
        for key in ("n_steps", "val_every", "checkpoint_every"):
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

    Only :data:`COMPATIBLE_SECTIONS` are compared, without the relocatable data keys.
    """
    differences = []
    for section in COMPATIBLE_SECTIONS:
        mine, theirs = current.get(section), stored.get(section)
        if isinstance(mine, dict) and isinstance(theirs, dict):
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
