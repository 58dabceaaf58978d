"""Hydra entry points ``spidermatch-match`` and ``spidermatch-eval``: run folder, lock, ``.hydra/``.

Outputs in the Hydra run directory: ``matches.csv``, ``result.json`` and
``correspondence.png`` (:mod:`spidermatch.cli.match`, :mod:`spidermatch.cli.evaluate`).
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

from spidermatch import shutdown
from spidermatch.cli.evaluate import run_eval
from spidermatch.cli.match import run_match
from spidermatch.cli.outputs import refuse_foreign_folder
from spidermatch.cli.sweep import record_job_code
from spidermatch.shutdown import write_atomic

logger = logging.getLogger("spidermatch.match")


EXIT_BAD_INPUT = shutdown.EXIT_BAD_INPUT


def configure_logging(level: str) -> None:
    """The log level of spidermatch's and the features' loggers.

    A log record that the run folder's log file cannot take (a full disk) is dropped quietly:
    the console still shows it, and the run's own error says what failed, instead of a
    traceback of the logging module for every record.
    """
    shutdown.quiet_file_logs()
    logging.getLogger("spidermatch").setLevel(level)
    logging.getLogger("features").setLevel(level)


def _save_run_config(cfg, hydra_cfg, output_dir: Path) -> None:
    """``.hydra/config.yaml``, ``hydra.yaml`` and ``overrides.yaml``, written once the folder is held.

    The configs set ``hydra.output_subdir: null`` so that Hydra does not write them itself
    before the run folder is locked (a second run into the folder would overwrite them).
    """
    from omegaconf import OmegaConf

    folder = output_dir / ".hydra"
    try:
        folder.mkdir(exist_ok=True)
    except OSError as error:
        raise shutdown.OutputError(f"{folder}: cannot be created ({error.strerror or error})") from error
    for name, content in (
        ("config.yaml", cfg),
        ("hydra.yaml", OmegaConf.create({"hydra": hydra_cfg})),
        ("overrides.yaml", OmegaConf.create(list(hydra_cfg.overrides.task))),
    ):
        write_atomic(folder / name, OmegaConf.to_yaml(content))


def _held_run(run, cfg, hydra_cfg, output_dir: Path, check_folder=None) -> int:
    """``run(cfg, output_dir)`` with the folder locked and the configuration saved; the exit code.

    ``check_folder(output_dir)``, if given, may refuse the folder (an OutputError) before
    anything is written into it.
    """
    try:
        if check_folder is not None:
            check_folder(output_dir)
        with shutdown.folder_lock(output_dir):
            _save_run_config(cfg, hydra_cfg, output_dir)
            return run(cfg, output_dir)
    except shutdown.FolderInUse as error:
        shutdown.detach_file_logs(output_dir, remove_empty=False)  # its log is the live run's
        logger.error("%s", error)
        return EXIT_BAD_INPUT
    except shutdown.OutputError as error:
        if not (output_dir / shutdown.LOCK_NAME).exists():  # refused before holding it
            shutdown.detach_file_logs(output_dir, remove_empty=True)
        logger.error("%s; nothing was run", error)
        return shutdown.EXIT_OUTPUT_ERROR


def _hydra_app(run, config_name: str, check_folder=None):
    import hydra
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    @hydra.main(config_path="pkg://conf", config_name=config_name, version_base="1.3")
    def app(cfg) -> None:
        configure_logging(cfg.log_level)
        hydra_cfg = HydraConfig.get()
        output_dir = Path(hydra_cfg.runtime.output_dir)
        code = _held_run(run, cfg, hydra_cfg, output_dir, check_folder)
        if hydra_cfg.mode == RunMode.MULTIRUN:
            record_job_code(output_dir, code)  # the sweep's end reports it (spidermatch.cli.sweep)
        if shutdown.native_work_abandoned():
            # a solve left running after a signal: end now (all files are written)
            logging.shutdown()
            sys.stderr.flush()
            os._exit(code)
        if code and hydra_cfg.mode != RunMode.MULTIRUN:
            sys.exit(code)

    return app


def file_run_overrides(overrides: list[str]) -> list[str]:
    """Command-line overrides with ``data=files`` added when ``source=`` is given without ``data=``.

    The data group decides the default resolution and is saved in ``.hydra/``, so a file
    run must select it before Hydra composes the config (the defaults list cannot look at
    ``source``).
    """
    keys = {item.split("=", 1)[0].lstrip("+~") for item in overrides if "=" in item}
    if "source" in keys and "data" not in keys:
        return [*overrides, "data=files"]
    return list(overrides)


def match_main() -> None:
    """Console entry point of ``spidermatch-match``."""
    from spidermatch.cli.options import claimed_run_folder, exit_on_bad_command_line, quoted_paths

    sys.argv[1:] = file_run_overrides(quoted_paths(sys.argv[1:]))
    folder = exit_on_bad_command_line("match", sys.argv[1:])
    sys.argv[1:] = claimed_run_folder("match", sys.argv[1:], folder)  # two runs in one second: two folders
    _hydra_app(run_match, "match", refuse_foreign_folder)()
    _exit_after_sweep()


def eval_main() -> None:
    """Console entry point of ``spidermatch-eval``."""
    from spidermatch.cli.options import exit_on_bad_command_line, quoted_paths

    sys.argv[1:] = quoted_paths(sys.argv[1:])
    exit_on_bad_command_line("eval", sys.argv[1:])
    _hydra_app(run_eval, "eval")()
    _exit_after_sweep()


def _exit_after_sweep() -> None:
    """Exit with the first failed job's code after a sweep (Hydra itself exits 0 whatever they returned)."""
    from spidermatch.cli import sweep

    if sweep.sweep_code:
        sys.exit(sweep.sweep_code)


if __name__ == "__main__":
    match_main()
