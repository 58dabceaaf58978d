"""``spidermatch-train``: the Hydra entry point of training (the only Hydra code of train/)."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import hydra
from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from spidermatch import shutdown
from spidermatch.data.datasets import DatasetError
from spidermatch.geometry.mesh import MeshError
from train.config import TrainConfig
from train.loop import train

logger = logging.getLogger(__name__)

CRITERION_NAMES = {  # the figure that selects best.pt, as the final line names it
    "val_error": "validation error",
    "val_partial": "validation error on partial copies",
    "val_unsup": "label-free validation loss",
}

ConfigStore.instance().store(name="train_schema", node=TrainConfig)


def to_train_config(cfg: DictConfig) -> TrainConfig:
    """The typed :class:`TrainConfig` of a composed Hydra config (``hydra`` key excluded)."""
    values = OmegaConf.to_container(cfg, resolve=True, throw_on_missing=True)
    values.pop("hydra", None)
    return TrainConfig.from_dict(values)


def worse_than_wks(result) -> str:
    """A warning for the final line when the best network matches worse than untrained WKS ('' if not)."""
    if result.criterion != "val_error" or not result.wks_error < result.best_val:
        return ""
    return (
        f"; WARNING: worse than WKS ({result.wks_error:.4f}) on the same pairs: matching with this network "
        "would be worse than without it; train longer (run.n_steps) or with more of the machine"
    )


def _report_end(message: str) -> None:
    """Why training ended early: on stderr, and in the run folder's log file (a batch job's record)."""
    print(message, file=sys.stderr)
    shutdown.log_to_files(logger, logging.ERROR, message)


@hydra.main(config_path="pkg://conf", config_name="train", version_base="1.3")
def train_main(cfg: DictConfig) -> float:
    """Train DiffusionNet features; writes ``last.pt`` and ``best.pt`` in the run folder.

    Returns the best selection figure: the validation error (mean normalised geodesic
    error) when the validation shapes have ground truth, else the label-free loss.
    """
    shutdown.quiet_file_logs()  # a log file on a full disk drops records instead of printing tracebacks
    config = to_train_config(cfg)
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    try:
        result = train(config, out_dir)
    except (ValueError, FloatingPointError) as error:  # CheckpointError, DatasetError, MeshError
        kind = type(error).__name__ if not isinstance(error, (DatasetError, MeshError)) else "data"
        _report_end(f"spidermatch-train: error ({kind}): {error}")
        raise SystemExit(2) from error
    except OSError as error:  # a checkpoint or log that cannot be written, e.g. a full disk (OutputError)
        _report_end(f"spidermatch-train: error (output): {error}; the checkpoints written before are kept")
        raise SystemExit(shutdown.EXIT_OUTPUT_ERROR) from error
    except shutdown.RunInterrupted as stop:  # during the data preparation
        _report_end(f"spidermatch-train: {stop} during the data preparation; nothing was trained")
        raise SystemExit(stop.exit_code) from None
    except KeyboardInterrupt:  # a second Ctrl-C: stop at once, without a traceback
        _report_end(f"spidermatch-train: aborted at once; the last checkpoints saved are in {out_dir}")
        raise SystemExit(130) from None
    status = f"interrupted (exit {result.exit_code})" if result.interrupted else "finished"
    figure = CRITERION_NAMES.get(result.criterion, result.criterion)
    print(
        f"{status} at step {result.step}: last {figure} {result.last_val:.4f}, "
        f"best {result.best_val:.4f}; checkpoints in {out_dir}{worse_than_wks(result)}"
    )
    if result.interrupted and HydraConfig.get().mode != RunMode.MULTIRUN:
        raise SystemExit(result.exit_code)  # a pre-empted job must not look finished
    return result.best_val


def main() -> None:
    """Console entry point of ``spidermatch-train``.

    An unknown option or a bad value (exit 2) and a run folder that cannot be written (exit 6)
    are refused with one line before Hydra starts, as for ``spidermatch-match``.
    """
    from spidermatch.cli.options import exit_on_bad_command_line, quoted_paths

    sys.argv[1:] = quoted_paths(sys.argv[1:])
    exit_on_bad_command_line("train", sys.argv[1:])
    train_main()


if __name__ == "__main__":
    main()
