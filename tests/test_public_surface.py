"""The public surface stays put when the inside moves: the API, the four commands, every config key.

``tests/data/config_keys.json`` lists every option of the composed configurations; a change
to it is a change users see (their overrides and sweeps name these keys), so it must be made
on purpose: regenerate the file and say so in the commit.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
import inspect
import json
from pathlib import Path

import pytest

import spidermatch

CONFIG_KEYS = Path(__file__).with_name("data") / "config_keys.json"

COMMANDS = {
    "spidermatch-match": "spidermatch.cli.main:match_main",
    "spidermatch-eval": "spidermatch.cli.main:eval_main",
    "spidermatch-collect": "spidermatch.cli.collect:main",
    "spidermatch-train": "train.cli:main",
}

MATCH_PARAMETERS = [
    "source",
    "target",
    "features",
    "resolution",
    "time_limit",
    "mip_rel_gap",
    "strategy",
    "settings",
    "strict",
    "features_max_vertices",
    "partial",
    "repair",  # keyword-only
    "second_opinion",  # keyword-only
    "overlap_method",  # keyword-only, added last
]

MATCHING_FIELDS = [
    "matches",
    "dense_map",
    "status",
    "objective",
    "bound",
    "gap",
    "resolution",
    "features",
    "timings",
    "details",
    "source_overlap",  # added with partial="both": a new field at the end keeps positional use working
    "matched_meshes",  # added with save_pictures, at the end likewise
    "as_given",
    "target_covered",  # added for partial maps of welded or repaired targets, at the end likewise
]


def test_the_package_exports_match_and_its_result():
    for name in (
        "match",
        "Matching",
        "load_mesh",
        "Mesh",
        "MeshError",
        "MatchSettings",
        "MatchError",
        "SolverOptions",
        "DenseSettings",
    ):
        assert name in spidermatch.__all__ and getattr(spidermatch, name) is not None
    assert list(inspect.signature(spidermatch.match).parameters) == MATCH_PARAMETERS
    assert [field.name for field in dataclasses.fields(spidermatch.Matching)] == MATCHING_FIELDS


def test_the_four_commands_point_at_callables():
    installed = importlib.metadata.entry_points(group="console_scripts")
    scripts = {point.name: point.value for point in installed if point.name.startswith("spidermatch-")}
    assert scripts == COMMANDS
    for target in scripts.values():
        module, function = target.split(":")
        assert callable(getattr(importlib.import_module(module), function))


@pytest.mark.parametrize("run", sorted(json.loads(CONFIG_KEYS.read_text())))
def test_every_config_key_is_kept(run):
    import train.cli  # noqa: F401 (registers the training schema)
    from spidermatch.cli.options import compose_problem, option_names

    name, *overrides = run.split()
    cfg, problem = compose_problem(name, overrides)
    assert problem is None
    assert sorted(option_names(cfg)) == json.loads(CONFIG_KEYS.read_text())[run]
