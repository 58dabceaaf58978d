"""The training loop: pair sampling, optimisation, validation, checkpoints and exact resume.

A checkpoint is a ``torch.save`` dictionary (readable with ``weights_only=True``)::

    format, version        framing, checked by features.learned.read_checkpoint
    config                 TrainConfig.to_dict()
    step                   optimisation steps completed
    model                  DiffusionNet state_dict (the weights being optimised)
    ema                    moving average of ``model`` (None when optim.ema_decay is 0);
                           validation, ``best.pt`` selection and inference use it
    optimizer, scheduler   their state_dicts
    rng                    torch global RNG state and the pair sampler's state
    metrics                best validation error, validation history, last loss
    software               versions of spidermatch, torch and the rest that trained it

Resuming restores all of it, so the next losses equal those of an uninterrupted run.
"""

from __future__ import annotations

import contextlib
import copy
import logging
import math
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from tqdm.auto import tqdm

from features.diffusion_net import DiffusionNet
from features.learned import CHECKPOINT_FORMAT, CHECKPOINT_VERSION, CheckpointError, read_checkpoint
from features.orientation import (
    moved_coordinates,
    reference_payload,
    rotated_coordinates,
    searches_orientation,
    turn_about_vertical,
)
from spidermatch import shutdown
from spidermatch.data.datasets import DatasetError, ShapeFolder
from spidermatch.versions import software_versions
from train.config import TrainConfig, incompatibilities
from train.data import (
    PartialInput,
    TrainShape,
    check_fmap_room,
    open_shapes,
    prepare_shapes,
    prepare_train_shape,
    split_names,
    validation_pairs,
)
from train.losses import cut_consistency_loss, pair_loss
from train.report import LossLog, write_figure, write_validation_csv
from train.validation import Validation, prepare_validation

logger = logging.getLogger(__name__)


@dataclass
class TrainingState:
    """Everything that changes during training (and is saved in a checkpoint)."""

    network: DiffusionNet
    optimiser: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler
    generator: torch.Generator
    average: dict[str, torch.Tensor] | None = None
    step: int = 0
    best_val: float = math.inf
    history: list[dict[str, float]] = field(default_factory=list)
    last_loss: float = math.nan
    last_terms: dict[str, float] = field(default_factory=dict)
    orientation: dict[str, Any] | None = None


@dataclass
class TrainResult:
    """Outcome of :func:`run_training`.

    Attributes
    ----------
    step : int
        Steps completed in total (including those before a resume).
    losses : list of float
        Loss of each step run by this call, in order.
    best_val, last_val : float
        Best and most recent value of the selection figure (nan if never validated).
    interrupted : bool
        The run stopped early on SIGINT or SIGTERM (``last.pt`` holds its state).
    criterion : str
        The selection figure: ``"val_error"`` (labelled) or ``"val_unsup"`` (label-free).
    stop_signal : int
        The signal that stopped the run (0 if none).
    wks_error : float
        The validation error of WKS descriptors on the same pairs (nan without labels).
    """

    step: int
    losses: list[float]
    best_val: float
    last_val: float
    interrupted: bool = False
    criterion: str = "val_error"
    stop_signal: int = 0
    wks_error: float = math.nan

    @property
    def exit_code(self) -> int:
        """0 for a finished run; 128 + the signal for an interrupted one (130 Ctrl-C, 143 SIGTERM)."""
        return 128 + self.stop_signal if self.interrupted else 0


def new_state(config: TrainConfig) -> TrainingState:
    """Seeded network, Adam, step schedule and pair sampler."""
    torch.manual_seed(config.seed)
    network = DiffusionNet.from_config(config.model)
    optim = config.optim
    optimiser = torch.optim.Adam(network.parameters(), lr=optim.lr, weight_decay=optim.weight_decay)
    if optim.schedule == "cosine":
        scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, config.run.n_steps, optim.lr_min)
    else:
        scheduler = torch.optim.lr_scheduler.StepLR(optimiser, optim.decay_every, optim.decay_gamma)
    generator = torch.Generator().manual_seed(config.seed)
    average = weight_copy(network.state_dict()) if optim.ema_decay > 0 else None
    return TrainingState(network, optimiser, scheduler, generator, average)


def weight_copy(weights: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Detached copies of the tensors of a state_dict."""
    return {name: tensor.detach().clone() for name, tensor in weights.items()}


def update_average(state: TrainingState, decay: float) -> None:
    """Move the weight average towards the current weights (after step ``state.step``).

    The first steps use the smaller decay ``(1 + step) / (10 + step)`` so that the
    average forgets its random initial weights quickly.
    """
    if state.average is None:
        return
    weight = min(decay, (1.0 + state.step) / (10.0 + state.step))
    with torch.no_grad():
        for name, current in state.network.state_dict().items():
            averaged = state.average[name]
            if averaged.is_floating_point():
                averaged.mul_(weight).add_(current.detach(), alpha=1.0 - weight)
            else:
                averaged.copy_(current)


def evaluation_network(state: TrainingState) -> DiffusionNet:
    """The network that validation and inference use: the weight average if kept."""
    if state.average is None:
        return state.network
    network = copy.deepcopy(state.network)
    network.load_state_dict(state.average)
    return network


def checkpoint_dict(state: TrainingState, config: TrainConfig) -> dict[str, Any]:
    """The checkpoint of ``state`` (see the module docstring)."""
    return {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "config": config.to_dict(),
        "step": state.step,
        "model": state.network.state_dict(),
        "ema": state.average,
        "optimizer": state.optimiser.state_dict(),
        "scheduler": state.scheduler.state_dict(),
        "rng": {"torch": torch.get_rng_state(), "pairs": state.generator.get_state()},
        "metrics": {"best_val": state.best_val, "history": list(state.history), "last_loss": state.last_loss},
        "orientation": state.orientation,
        "software": software_versions(),
    }


TORCH_WRITE_FAILURES = ("inline_container", "PytorchStreamWriter", "unexpected pos")
"""Marks of torch's archive writer failing to write (it raises a RuntimeError, e.g. on a full disk)."""


def save_checkpoint(path: str | os.PathLike, state: TrainingState, config: TrainConfig) -> Path:
    """Write the checkpoint atomically (temporary file, then rename).

    Raises
    ------
    spidermatch.shutdown.OutputError
        It cannot be written (e.g. a full disk, which torch reports as a RuntimeError from
        its archive writer); the file at ``path`` is left as it was and no partial file stays.
    """
    path = Path(path)
    partial = path.with_name(path.name + ".partial")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save(checkpoint_dict(state, config), partial)
        os.replace(partial, path)
    except (OSError, RuntimeError) as error:
        with contextlib.suppress(OSError):
            partial.unlink()
        if isinstance(error, RuntimeError) and not any(mark in str(error) for mark in TORCH_WRITE_FAILURES):
            raise  # not the archive writer's: a bug, shown as it is
        reason = (
            error.strerror if isinstance(error, OSError) and error.strerror else str(error).splitlines()[0]
        )
        free = _free_bytes(path.parent)
        room = "" if free is None else f"; {free / 2**20:.1f} MiB free there"
        raise shutdown.OutputError(f"{path}: the checkpoint cannot be written ({reason}{room})") from error
    return path


def _free_bytes(folder: Path) -> int | None:
    try:
        return shutil.disk_usage(folder).free
    except OSError:
        return None


def compatible_checkpoint(path: str | os.PathLike, config: TrainConfig) -> dict[str, Any]:
    """Read a checkpoint and check that ``config`` may resume it (CheckpointError if not)."""
    checkpoint = read_checkpoint(path)
    differences = incompatibilities(config.to_dict(), checkpoint["config"])
    if differences:
        raise CheckpointError(f"{path}: checkpoint from an incompatible config: " + "; ".join(differences))
    if int(checkpoint["step"]) >= config.run.n_steps:  # nothing to train: no checkpoint would be written
        raise CheckpointError(
            f"{path}: the checkpoint is already at step {int(checkpoint['step'])}, and run.n_steps = "
            f"{config.run.n_steps} leaves nothing to train: give a larger run.n_steps"
        )
    return checkpoint


def load_checkpoint_into(path: str | os.PathLike, state: TrainingState, config: TrainConfig) -> None:
    """Restore ``state`` from a checkpoint written with a compatible config.

    Raises
    ------
    CheckpointError
        Missing, corrupt or incompatible checkpoint (the message lists the differences).
    """
    checkpoint = compatible_checkpoint(path, config)
    try:
        state.network.load_state_dict(checkpoint["model"])
        state.optimiser.load_state_dict(checkpoint["optimizer"])
        state.scheduler.load_state_dict(checkpoint["scheduler"])
        if state.average is not None:
            state.average = weight_copy(checkpoint["ema"])
            if state.average.keys() != state.network.state_dict().keys():
                raise KeyError("the weight average does not have the model's tensors")
        torch.set_rng_state(checkpoint["rng"]["torch"])
        state.generator.set_state(checkpoint["rng"]["pairs"])
        metrics = checkpoint["metrics"]
        state.best_val = float(metrics["best_val"])
        state.history = list(metrics["history"])
        state.last_loss = float(metrics["last_loss"])
    except (AttributeError, KeyError, RuntimeError, TypeError, ValueError) as error:
        raise CheckpointError(
            f"{path}: checkpoint is incomplete or does not fit the model ({error})"
        ) from error
    state.step = int(checkpoint["step"])


def sample_pair(generator: torch.Generator, n: int) -> tuple[int, int]:
    """Two distinct indices in ``range(n)``, uniformly, from ``generator``."""
    first = int(torch.randint(n, (1,), generator=generator))
    second = int(torch.randint(n - 1, (1,), generator=generator))
    return first, second + (second >= first)


def random_rotation(mode: str, generator: torch.Generator) -> torch.Tensor:
    """A random rotation (3, 3): about the y axis (``"y"``) or uniform over SO(3) (``"all"``)."""
    if mode == "y":
        return turn_about_vertical(2 * math.pi * float(torch.rand(1, generator=generator)))
    w, x, y, z = torch.randn(4, generator=generator).tolist()
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / norm, x / norm, y / norm, z / norm
    return torch.tensor(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def network_input(shape: TrainShape, config: TrainConfig, generator: torch.Generator) -> torch.Tensor:
    """Input features of a training shape, randomly rotated if ``data.augment_rotation`` asks.

    Only coordinates rotate (the whole input for ``xyz``, its last 3 columns for ``wks_xyz``).
    """
    features = shape.input.features
    if config.data.augment_rotation == "none" or config.model.input == "wks":
        return features
    return rotated_coordinates(features, random_rotation(config.data.augment_rotation, generator))


def train_step(state: TrainingState, shapes: list[TrainShape], config: TrainConfig) -> float:
    """One Adam step on a random pair; returns the loss before the step.

    The loss terms of the step are left in ``state.last_terms``.
    """
    state.network.train()
    i, j = sample_pair(state.generator, len(shapes))
    x, y = shapes[i], shapes[j]
    feat_x = state.network(network_input(x, config, state.generator), x.input.ops)
    feat_y = state.network(network_input(y, config, state.generator), y.input.ops)
    corr = (x.corr, y.corr) if x.corr is not None and y.corr is not None else None
    loss, terms = pair_loss(feat_x, feat_y, x.input.ops, y.input.ops, config.loss, corr)
    if config.loss.w_partial > 0 and x.partials:
        partial = partial_term(state, x, feat_x, config)
        loss = loss + config.loss.w_partial * partial
        terms["partial"] = partial.item()
    if not torch.isfinite(loss):
        raise FloatingPointError(f"step {state.step + 1}: loss is {float(loss)} on pair ({x.name}, {y.name})")
    state.optimiser.zero_grad(set_to_none=True)
    loss.backward()
    if config.optim.grad_clip > 0:
        torch.nn.utils.clip_grad_norm_(state.network.parameters(), config.optim.grad_clip)
    state.optimiser.step()
    state.scheduler.step()
    state.step += 1
    update_average(state, config.optim.ema_decay)
    state.last_loss = loss.item()
    state.last_terms = {"loss": state.last_loss, **terms}
    return state.last_loss


def partial_term(state: TrainingState, shape: TrainShape, feat_whole: torch.Tensor, config: TrainConfig):
    """Cut-consistency loss of a random partial copy of ``shape`` against its features ``feat_whole``.

    The copy's coordinates are not rotated: with ``data.augment_rotation`` the whole's
    are, and the term then also asks for features that do not depend on the rotation.
    """
    choice = int(torch.randint(len(shape.partials), (1,), generator=state.generator))
    part = shape.partials[choice]
    feat_part = state.network(partial_copy_input(part, config, state.generator), part.input.ops)
    n_part = part.to_whole.shape[0]
    points = None
    if n_part > config.loss.partial_points:
        points = torch.randperm(n_part, generator=state.generator)[: config.loss.partial_points]
    return cut_consistency_loss(feat_part, feat_whole, part.to_whole, config.loss.temperature, points)


def partial_copy_input(part: PartialInput, config: TrainConfig, generator: torch.Generator) -> torch.Tensor:
    """Input features (V_p, C_in) of a partial copy: centred on itself, or at its place on the whole.

    With probability ``data.partial_placed`` (and coordinates among the inputs), the copy's
    coordinates are moved by its offset on the whole plus a uniform shift of at most
    ``data.partial_jitter`` per axis, as the inference's placement search presents a part.
    """
    features = part.input.features
    if config.model.input == "wks" or config.data.partial_placed <= 0:
        return features
    if float(torch.rand((), generator=generator)) >= config.data.partial_placed:
        return features
    jitter = (2 * torch.rand(3, generator=generator) - 1) * config.data.partial_jitter
    return moved_coordinates(features, part.offset + jitter)


def validate(
    state: TrainingState, validation: Validation | None, config: TrainConfig, out_dir: Path
) -> float:
    """Validate, record, and write ``last.pt`` (and ``best.pt`` on improvement).

    Returns the selection figure (``validation.criterion``; nan without validation).
    """
    figures = validation(evaluation_network(state)) if validation is not None else {}
    criterion = validation.criterion if validation is not None else "val_error"
    value = figures.get(criterion, math.nan)
    improved = value < state.best_val
    if improved:
        state.best_val = value
    state.history.append({"step": state.step, **figures, "loss": state.last_loss})
    save_checkpoint(out_dir / "last.pt", state, config)
    if improved:
        save_checkpoint(out_dir / "best.pt", state, config)
    write_validation_csv(state.history, out_dir)
    write_figure(out_dir)
    logger.info(
        "step %d: %s %.4f (best %.4f); %s",
        state.step,
        criterion,
        value,
        state.best_val,
        ", ".join(f"{key} {val:.4f}" for key, val in figures.items() if key != criterion),
    )
    return value


def run_training(
    config: TrainConfig,
    out_dir: str | os.PathLike,
    shapes: list[TrainShape],
    validation: Validation | None,
    started: float | None = None,
) -> TrainResult:
    """Train on prepared shapes, validating and checkpointing into ``out_dir``.

    Stops after ``config.run.n_steps`` steps, at the wall-clock limit
    ``config.run.time_limit_min`` (validating and checkpointing there), or after
    the current step on Ctrl-C (writing ``last.pt``).

    Parameters
    ----------
    config : TrainConfig
        ``config.resume`` names a checkpoint to continue from (or None).
    out_dir : str or PathLike
        Receives ``last.pt``, ``best.pt``, ``losses.csv``, ``validation.csv`` and ``.png``.
    shapes : list of TrainShape
        At least two training shapes.
    validation : Validation, optional
        None skips the figures (they are nan) but still checkpoints.
    started : float, optional
        ``time.monotonic()`` at which the time limit starts counting (default: now).
    """
    if len(shapes) < 2:
        raise ValueError(f"training needs at least 2 shapes, got {len(shapes)}")
    out_dir, run = Path(out_dir), config.run
    state = new_state(config)
    state.orientation = orientation_reference(shapes[0], config)
    if config.resume is not None:
        load_checkpoint_into(config.resume, state, config)
        _carry_best(Path(config.resume), out_dir)
        logger.info("resumed from %s at step %d", config.resume, state.step)
        if validation is not None:
            _rebase_best(state, validation.criterion)
        _warn_if_cosine_restarts(state.scheduler, run.n_steps)
    started = time.monotonic() if started is None else started
    deadline = math.inf if run.time_limit_min is None else started + 60 * run.time_limit_min
    losses, last_val = [], math.nan
    log = LossLog(out_dir / "losses.csv", state.step)
    run_started = time.monotonic()
    bar = tqdm(
        total=run.n_steps,
        initial=min(state.step, run.n_steps),
        desc="train",
        unit="step",
        disable=not run.progress,
        dynamic_ncols=True,
    )
    with bar, shutdown.graceful_stops("stopping after this step and saving last.pt (Ctrl-C again to abort)"):
        while state.step < run.n_steps and not shutdown.stop_requested():
            losses.append(train_step(state, shapes, config))
            if state.step % run.log_every == 0:
                lr = state.optimiser.param_groups[0]["lr"]
                log.append(state.step, state.last_terms, lr, time.monotonic() - run_started)
            bar.update(1)
            bar.set_postfix(progress_fields(state.last_terms, last_val, validation), refresh=False)
            out_of_time = time.monotonic() > deadline
            if state.step % run.val_every == 0 or state.step == run.n_steps or out_of_time:
                last_val = validate(state, validation, config, out_dir)
            elif state.step % run.checkpoint_every == 0:
                save_checkpoint(out_dir / "last.pt", state, config)
            if out_of_time:
                logger.warning("time limit of %s min reached at step %d", run.time_limit_min, state.step)
                break
        stop_signal = shutdown.received_signal() if shutdown.stop_requested() else 0
    if stop_signal:
        save_checkpoint(out_dir / "last.pt", state, config)
        logger.warning("stopped at step %d; continue with resume=%s", state.step, out_dir / "last.pt")
    criterion = validation.criterion if validation is not None else "val_error"
    wks = validation.wks_error if validation is not None else math.nan
    return TrainResult(
        state.step, losses, state.best_val, last_val, bool(stop_signal), criterion, stop_signal, wks
    )


def orientation_reference(shape: TrainShape, config: TrainConfig) -> dict[str, Any] | None:
    """The orientation search's checkpoint entry (the first training shape), or None when off."""
    if shape.mesh is None or not searches_orientation(config.model, config.data.orientation_turns):
        return None
    return reference_payload(shape.mesh, config.data.orientation_turns, config.data.up_axis)


def progress_fields(
    terms: dict[str, float], last_val: float, validation: Validation | None
) -> dict[str, str]:
    """The progress bar's postfix: each loss term of the last step and the last validation figure."""
    fields = {key: f"{value:.3g}" for key, value in terms.items()}
    criterion = validation.criterion if validation is not None else "val"
    name = {"val_error": "val_err"}.get(criterion, criterion)
    fields[name] = f"{last_val:.4f}"
    return fields


def _warn_if_cosine_restarts(scheduler, n_steps: int) -> None:
    """Say that a resumed cosine schedule keeps the length it was made with, if ``n_steps`` differs.

    The scheduler's state (its period included) comes from the checkpoint, so a run extended past
    its planned end does not stretch the cosine: the learning rate rises again towards ``lr``
    (a warm restart), which is what extending a finished run measured (docs/partial.md).
    """
    planned = getattr(scheduler, "T_max", None)
    if planned is not None and planned != n_steps:
        logger.warning(
            "run.n_steps=%d, but the resumed cosine schedule was made for %d steps and keeps that "
            "period: past step %d the learning rate rises again (a warm restart)",
            n_steps,
            planned,
            planned,
        )


def _carry_best(resumed: Path, out_dir: Path) -> None:
    """Copy the resumed run's ``best.pt`` into a new output folder, if there is one."""
    best = resumed.parent / "best.pt"
    if best.is_file() and best.resolve() != (out_dir / "best.pt").resolve():
        out_dir.mkdir(parents=True, exist_ok=True)
        with shutdown.atomic_path(out_dir / "best.pt") as tmp:  # OutputError naming it if it cannot be
            shutil.copyfile(best, tmp)


def _rebase_best(state: TrainingState, criterion: str) -> None:
    """Make the resumed best figure the best ``criterion`` of the history.

    A run written before its selection figure existed (``val_partial``) stored the best of
    another figure; compared with that, the new figure would never (or always) improve.
    """
    values = [
        float(entry[criterion]) for entry in state.history if math.isfinite(entry.get(criterion, math.nan))
    ]
    best = min(values, default=math.inf)
    if best != state.best_val:
        logger.info(
            "resumed run: best %s so far %.4f (the checkpoint's best figure was %.4f)",
            criterion,
            best,
            state.best_val,
        )
        state.best_val = best


UNUSABLE_LISTED = 10
"""Unusable shapes named one by one in the refusal; the rest are counted."""


def refuse_unusable_shapes(dataset, names: list[str]) -> None:
    """DatasetError naming every shape of ``names`` that cannot be loaded, before any is prepared.

    A folder of a user's scans may hold several bad files; naming them one run at a time
    (a run stops at the first) would cost a preparation each.
    """
    if not isinstance(dataset, ShapeFolder):
        return
    problems = dataset.unusable(sorted(names))
    if not problems:
        return
    listed = "\n  ".join(problems[:UNUSABLE_LISTED])
    more = f"\n  ... and {len(problems) - UNUSABLE_LISTED} more" if len(problems) > UNUSABLE_LISTED else ""
    raise DatasetError(
        f"{dataset.root}: {len(problems)} of {len(names)} shapes cannot be used:\n  {listed}{more}"
    )


def prepare_data(config: TrainConfig) -> tuple[list[TrainShape], Validation]:
    """Open the dataset, split it, and precompute all training and validation inputs."""
    dataset = open_shapes(config.data)
    try:
        train_names, val_names = split_names(dataset.names, config.data)
    except ValueError as error:
        raise DatasetError(f"{config.data.root or 'synthetic shapes'}: {error}") from error
    refuse_unusable_shapes(dataset, [*train_names, *val_names])
    logger.info(
        "%d training shapes (%s..%s), %d validation shapes (%s)",
        len(train_names),
        train_names[0],
        train_names[-1],
        len(val_names),
        ", ".join(val_names) if len(val_names) <= 6 else f"{val_names[0]}..{val_names[-1]}",
    )

    def prepare_checked(shape, model, data):  # a shape too small for the loss: refused before step 1
        return check_fmap_room(prepare_train_shape(shape, model, data), config.loss.n_fmap, dataset)

    shapes = prepare_shapes(
        dataset,
        train_names,
        prepare_checked,
        config.model,
        config.data,
        "prepare training shapes",
        config.run.progress,
    )
    pairs = validation_pairs(val_names, train_names, config.data.val_pairs)
    return shapes, prepare_validation(dataset, pairs, shapes, config)


def train(config: TrainConfig, out_dir: str | os.PathLike) -> TrainResult:
    """Prepare the data named by ``config.data`` and run :func:`run_training`.

    The time limit ``config.run.time_limit_min`` includes the data preparation.
    """
    started = time.monotonic()
    if config.run.threads is not None:
        torch.set_num_threads(config.run.threads)
    if config.resume is not None:
        compatible_checkpoint(config.resume, config)  # fail before the (slow) data preparation
    with shutdown.signals_handled():  # SIGINT/SIGTERM here: RunInterrupted (nothing trained yet)
        shapes, validation = prepare_data(config)
    return run_training(config, out_dir, shapes, validation, started)
