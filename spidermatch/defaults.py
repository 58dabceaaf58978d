"""Default settings of a match, read from the YAML in ``conf/``: the one source of defaults.

The command line composes the same files with Hydra; the Python API (:func:`spidermatch.match`),
:class:`~spidermatch.pipeline.MatchSettings`, :class:`~spidermatch.dense.densify.DenseSettings`
and :class:`~spidermatch.model.costs.RobustLoss` take their defaults from here, so a default
changed in ``conf/`` changes everywhere. Plain YAML is read (no Hydra): the groups read here
hold no interpolations. A leaf module: it imports nothing of spidermatch.
"""

from __future__ import annotations

import functools
from importlib import resources

import yaml


@functools.cache
def group(name: str) -> dict:
    """The options of ``conf/<name>.yaml`` (e.g. ``"solver/default"``), without the comments.

    Raises
    ------
    FileNotFoundError
        The file is not part of the installed ``conf`` package.

    """
    text = resources.files("conf").joinpath(f"{name}.yaml").read_text()
    return dict(yaml.safe_load(text) or {})


def option(name: str, key: str):
    """One option of ``conf/<name>.yaml``: ``option("solver/default", "time_limit")``."""
    return group(name)[key]


def resolution(data: str, feature_name: str) -> int:
    """Faces of both decimated meshes by default, for ``data`` ("files" or "synthetic") and features.

    WKS gets the smaller resolution of the two because its ILP is harder; any feature other than
    WKS counts as learned.
    """
    kind = "wks" if feature_name == "wks" else "learned"
    return int(option(f"resolution_default/{data}_{kind}", "resolution"))


def match_option(key: str):
    """A top-level option of ``conf/match.yaml`` (``features_max_vertices``, ``partial``, ...)."""
    return option("match", key)
