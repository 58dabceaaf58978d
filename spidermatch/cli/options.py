"""Command-line checks before Hydra starts: unknown option names and an unusable run folder.

Hydra reports a misspelt option (``resolutoin=5``) with exit code 1 and fails with a
traceback when it cannot create the run folder; spidermatch promises exit code 2 for bad
input and 6 for an output that cannot be written, with a message naming the option or path.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

from spidermatch.shutdown import EXIT_BAD_INPUT, EXIT_OUTPUT_ERROR


def compose_problem(config_name: str, overrides: list[str]):
    """Compose the configuration with ``overrides``; return (config or None, problem or None)."""
    from hydra import compose, initialize_config_module
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        with initialize_config_module(config_module="conf", version_base="1.3"):
            return compose(config_name=config_name, overrides=overrides, return_hydra_config=True), None
    except (HydraException, OmegaConfBaseException) as error:
        lines = [line for line in str(error).splitlines() if line.strip()]
        return None, " ".join(lines[:3]) if lines else type(error).__name__


def unwritable_folder(folder: str | os.PathLike) -> str | None:
    """Why a run folder cannot be created or written (None if it can), without creating it.

    The nearest existing folder on its path is asked, then tried: a scratch folder is made
    in it and removed, because permissions alone do not tell (root may write anywhere by
    its permissions, yet not into ``/proc`` or a read-only mount).
    """
    path = Path(folder).absolute()
    for parent in (path, *path.parents):
        if parent.exists():
            if not parent.is_dir():
                return f"{parent} is not a folder"
            if not os.access(parent, os.W_OK | os.X_OK):
                return f"{parent} is not writable"
            return _creation_problem(parent)
    return None


def _creation_problem(folder: Path) -> str | None:
    """Why no folder can be made in the existing ``folder`` (None if one can)."""
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".spidermatch-probe-", dir=folder))
    except OSError as error:
        return f"no folder can be made in {folder} ({error.strerror or error})"
    return None


def _run_folder(cfg) -> str | None:
    from hydra.core.utils import setup_globals
    from omegaconf import OmegaConf

    setup_globals()  # the ${now:...} resolver of the default run folder
    try:
        return str(OmegaConf.select(cfg, "hydra.run.dir", throw_on_resolution_failure=True))
    except Exception:  # a folder pattern only Hydra's own run can resolve: Hydra checks it
        return None


def option_names(cfg) -> list[str]:
    """Every option of a composed configuration as a dotted name (``solver.time_limit``), Hydra's apart."""
    from omegaconf import DictConfig, OmegaConf

    names = []

    def walk(node, prefix: str) -> None:
        for key in node.keys() if isinstance(node, DictConfig) else ():
            name = f"{prefix}{key}"
            if name == "hydra":
                continue
            names.append(name)
            child = OmegaConf.select(node, str(key), throw_on_resolution_failure=False)
            walk(child, f"{name}.")

    walk(cfg, "")
    return names


def _key(override: str) -> str:
    return override.split("=", 1)[0].lstrip("+~")


def config_groups() -> set[str]:
    """Names of the configuration's groups (``features``, ``solver``, ...): the folders of ``conf``."""
    from importlib.resources import files

    folders = files("conf").iterdir()
    return {entry.name for entry in folders if entry.is_dir() and not entry.name.startswith("_")}


def unknown_option_problem(config_name: str, overrides: list[str]) -> str | None:
    """An override that names no option of the configuration, with the nearest real name.

    Covers both ``resolutoin=250`` (Hydra's own hint, "use +resolutoin=250", would add a key
    that nothing reads and run with the default) and ``+resolutoin=250``. ``hydra.*`` keys
    are Hydra's and left to it.
    """
    import difflib

    plain = [item for item in overrides if "=" in item and not item.startswith(("+", "~"))]
    groups = [item for item in plain if _key(item).split("/")[0] in config_groups()]  # also train/loss=
    cfg, _ = compose_problem(config_name, groups)
    if cfg is None:  # a value Hydra cannot take: the full composition names it (a guess here could be
        return None  # wrong: without the chosen groups, their options would look unknown)
    names = option_names(cfg)
    for item in overrides:
        key = _key(item)
        hydras = key.startswith("hydra") or "/" in key  # Hydra's own keys and config-group paths
        if "=" not in item or hydras or key in names or item.startswith(("~", "++")):
            continue
        close = difflib.get_close_matches(key, names, n=1, cutoff=0.6)
        hint = f" (did you mean {close[0]}?)" if close else ""
        return f"unknown option {key!r}{hint}: nothing reads it, so it is refused rather than ignored"
    return None


PATH_KEYS = frozenset(
    {"source", "target", "source_corr", "target_corr", "checkpoint", "features.checkpoint", "second_opinion",
     "pairs_file", "dataset", "data.root", "resume", "name", "hydra.run.dir", "hydra.sweep.dir"}
)  # fmt: skip
"""Options whose values are file or folder names: quoted for Hydra when they need it."""


def quoted_paths(argv: list[str]) -> list[str]:
    """``argv`` with every path option's value quoted where Hydra's grammar would misread it.

    Hydra's override grammar refuses letters outside ASCII, parentheses, ``=``, ``~`` and
    apostrophes in an unquoted value and reads a comma as a sweep, all common in file names
    (``scan (1).off``, ``Körper.ply``, ``x,y.off``). A value that Hydra would not read back exactly
    as given is put in single quotes (an apostrophe in it escaped); a value already quoted is
    left alone, and so is every argument of a ``-m`` sweep (whose commas list values) and a value
    Hydra reads as null, a number or a list (``target=[a,b]``, refused later as not one path).
    """
    if "-m" in argv or "--multirun" in argv:  # a sweep may list paths with commas: left to the user
        return list(argv)
    return [_quoted_path(argument) for argument in argv]


def _quoted_path(argument: str) -> str:
    key, separator, value = argument.partition("=")
    if not separator or key.lstrip("+~") not in PATH_KEYS or value[:1] in ("'", '"') or not value:
        return argument
    read = _hydra_value(argument)
    if read == value or (read is not _UNREADABLE and not isinstance(read, str) and not _is_sweep(read)):
        return argument  # read as given, or meant as null, a number or a list: Hydra's to read
    quoted = f"{key}='" + value.replace("'", "\\'") + "'"
    return quoted if _hydra_value(quoted) == value else argument


_UNREADABLE = object()


def _is_sweep(value) -> bool:
    """Whether Hydra read a value as a sweep (``a,b``): a comma in a file name, outside ``-m`` runs."""
    from hydra.core.override_parser.types import Sweep

    return isinstance(value, Sweep)


def _hydra_value(argument: str):
    """The value Hydra's override parser reads from ``argument`` (``_UNREADABLE`` if it cannot parse it)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    try:
        return OverridesParser.create().parse_override(argument).value()
    except Exception:  # any parse failure: the caller quotes or leaves the argument to Hydra's message
        return _UNREADABLE


MAX_FOLDER_SUFFIX = 1000


def claimed_run_folder(config_name: str, argv: list[str], folder: str | None = None) -> list[str]:
    """``argv`` with ``hydra.run.dir`` set to a fresh folder made for this run, when none was given.

    The default run folder is named by the second the run started, so two runs started in the
    same second (a script launching matches in parallel) chose the same folder and one was
    refused. The folder is made here (an atomic ``mkdir``); when it exists, ``_2``, ``_3``, ...
    are tried. Sweeps, runs with Hydra flags and a folder that cannot be made are left as they
    are (Hydra, or the lock, reports them). ``folder``: the default folder as resolved already
    (what :func:`exit_on_bad_command_line` returns); else the configuration is composed for it.
    """
    if any(arg.startswith("-") for arg in argv) or any(_key(arg) == "hydra.run.dir" for arg in argv):
        return list(argv)
    if folder is None:
        cfg, problem = compose_problem(config_name, list(argv))
        folder = None if problem else _run_folder(cfg)
    if not folder:
        return list(argv)
    for number in range(1, MAX_FOLDER_SUFFIX + 1):
        candidate = Path(folder if number == 1 else f"{folder}_{number}")
        try:
            candidate.parent.mkdir(parents=True, exist_ok=True)
            candidate.mkdir()
        except FileExistsError:
            continue
        except OSError:
            return list(argv)
        return [*argv, *quoted_paths([f"hydra.run.dir={candidate}"])]
    return list(argv)


def exit_on_bad_command_line(config_name: str, argv: list[str]) -> str | None:
    """Exit 2 for an unknown option or value syntax, 6 for an unusable run folder (single runs).

    Runs with Hydra flags (``-m``, ``--help``, ``--cfg``, ...) are left to Hydra. Returns the
    run folder checked (None when not resolved).
    """
    if any(arg.startswith("-") for arg in argv):
        return None
    problem = unknown_option_problem(config_name, list(argv))
    cfg = None
    if problem is None:
        cfg, problem = compose_problem(config_name, list(argv))
    if problem:
        print(f"spidermatch-{config_name}: bad option: {problem}", file=sys.stderr)
        sys.exit(EXIT_BAD_INPUT)
    folder = _run_folder(cfg)
    reason = unwritable_folder(folder) if folder else None
    if reason:
        print(f"spidermatch-{config_name}: cannot write the run folder {folder}: {reason}", file=sys.stderr)
        sys.exit(EXIT_OUTPUT_ERROR)
    return folder
