"""Which software made a result: recorded in ``result.json`` and in training checkpoints.

A certified matching is only reproducible with the code and the solver that made it: a later
version may match the same pair differently (a fix in the mesh clean-up, another HiGHS), so
every result says which versions made it, and ``spidermatch-eval`` does not reuse a pair's
result made by another version of spidermatch (:func:`spidermatch.cli.resume.rerun_reason`).

From a git checkout the version carries the commit, ``0.1.0+g1a2b3c4``, and ``.dirty`` when
the package's files differ from it; from an installed wheel it is the release alone.
"""

from __future__ import annotations

import functools
import logging
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import spidermatch

logger = logging.getLogger(__name__)

PACKAGES = ("numpy", "scipy", "highspy", "trimesh", "potpourri3d")
"""Distributions whose versions decide a match (torch is added when it is loaded)."""

CODE_FOLDERS = ("spidermatch", "features", "train", "conf")
"""The project's folders whose changes make a checkout ``.dirty``."""

GIT_TIMEOUT_S = 5.0


@functools.lru_cache(maxsize=1)
def spidermatch_version() -> str:
    """``__version__``, with ``+g<commit>`` (and ``.dirty``) when run from a git checkout."""
    commit = _checkout_commit(Path(spidermatch.__file__).resolve().parent.parent)
    return spidermatch.__version__ if commit is None else f"{spidermatch.__version__}+{commit}"


def _checkout_commit(root: Path) -> str | None:
    """``g<short commit>[.dirty]`` of the git checkout at ``root``, or None (no checkout, no git)."""
    if not (root / ".git").exists():
        return None
    head = _git(root, "rev-parse", "--short=10", "HEAD")
    if head is None:
        return None
    status = _git(root, "status", "--porcelain", "--", *CODE_FOLDERS)
    return f"g{head}" + (".dirty" if status else "")


def _git(root: Path, *arguments: str) -> str | None:
    """The stripped output of ``git -C root arguments``, or None when git fails or is missing."""
    try:
        done = subprocess.run(
            ["git", "-C", str(root), *arguments],
            capture_output=True,
            text=True,
            timeout=GIT_TIMEOUT_S,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def _distribution_version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def _highs_version() -> str | None:
    """The HiGHS library's own version (highspy's wheel version can differ from it)."""
    try:
        from highspy import _core

        return f"{_core.HIGHS_VERSION_MAJOR}.{_core.HIGHS_VERSION_MINOR}.{_core.HIGHS_VERSION_PATCH}"
    except (ImportError, AttributeError):
        return None


def software_versions() -> dict[str, str]:
    """Versions of spidermatch, Python, HiGHS and the packages that decide a match, JSON-ready.

    ``torch`` appears only when it is already loaded (learned features): the library does not
    import it.
    """
    versions = {"spidermatch": spidermatch_version(), "python": platform.python_version()}
    highs = _highs_version()
    if highs is not None:
        versions["highs"] = highs
    for name in PACKAGES + (("torch",) if "torch" in sys.modules else ()):
        found = _distribution_version(name)
        if found is not None:
            versions[name] = found
    return versions
