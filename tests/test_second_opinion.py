"""The second opinion: a map judged suspect is matched again with a second descriptor joined to the first."""

import json
import types

import numpy as np
import pytest
from conftest import composed, judged_suspect_once

import spidermatch
from spidermatch import pipeline
from spidermatch.cli.match import run_match
from spidermatch.data.datasets import SyntheticShapes
from spidermatch.pipeline import joined_features, kept_opinion, needs_second_opinion

SMALL = ["data.n_verts=700", "resolution=60", "solver.time_limit=3600", "output.png=false"]


def opinion(verdict, status="optimal", matched=True, checked=True):
    """A stand-in for a MatchResult with what the choice reads."""
    return types.SimpleNamespace(
        low_map=np.arange(3) if matched else None,
        check=types.SimpleNamespace(ok=checked),
        quality=None if verdict is None else {"verdict": verdict, "reasons": []},
        solve=types.SimpleNamespace(status=status, objective=1.0, gap=1e-4),
        second_opinion=None,
    )


def test_joined_rows_are_unit_and_their_similarity_is_the_mean_of_the_two(rng):
    first, second = rng.normal(size=(5, 3)) * 7, rng.normal(size=(5, 4)) * 1e-3
    joined = joined_features(first, second)
    assert joined.shape == (5, 7) and np.allclose(np.linalg.norm(joined, axis=1), 1)
    unit = lambda rows: rows / np.linalg.norm(rows, axis=1, keepdims=True)  # noqa: E731
    mean = (unit(first) @ unit(first).T + unit(second) @ unit(second).T) / 2
    assert np.allclose(joined @ joined.T, mean)
    with pytest.raises(ValueError, match="4 rows for 5 vertices"):
        joined_features(first, second[:4])


@pytest.mark.parametrize(
    "second, kept",
    [
        (opinion("plausible"), "second"),
        (opinion("plausible", status="feasible"), "second"),  # plausible, not proven: still the better bet
        (opinion("suspect"), "first"),
        (opinion(None, status="no_solution", matched=False), "first"),
        (opinion("plausible", checked=False), "first"),  # a map that fails the checker is never kept
    ],
)
def test_the_second_map_is_kept_only_when_judged_plausible(second, kept):
    first = opinion("suspect")
    chosen = kept_opinion(first, second)
    assert chosen is (second if kept == "second" else first)
    assert chosen.second_opinion["kept"] == kept
    assert chosen.second_opinion["first"]["verdict"] == "suspect"
    assert needs_second_opinion(first) and not needs_second_opinion(opinion("plausible"))
    assert not needs_second_opinion(opinion("suspect", matched=False))


def test_api_asks_the_second_opinion_of_a_suspect_map_and_keeps_a_plausible_one(monkeypatch):
    shapes = SyntheticShapes(n_shapes=2, n_verts=700, seed=0)
    x, y = (shapes.load(name) for name in shapes.names)
    features = x.mesh.centred().verts, y.mesh.centred().verts
    judged_suspect_once(monkeypatch, pipeline)
    result = spidermatch.match(x.mesh, y.mesh, features=features, resolution=60, second_opinion=features)
    record = result.details.second_opinion
    assert record["first"]["verdict"] == "plausible"  # the same costs again: the same verdict
    assert record["kept"] == "second" and record["second"]["verdict"] == "plausible"
    assert result.status == "optimal" and result.dense_map is not None
    assert "second_opinion" in result.timings
    monkeypatch.undo()  # the real judgement: this plausible map is not asked about
    unasked = spidermatch.match(x.mesh, y.mesh, features=features, resolution=60, second_opinion=features)
    assert unasked.quality["verdict"] == "plausible" and unasked.details.second_opinion is None


def test_api_second_opinion_that_fails_leaves_the_first_map(monkeypatch):
    shapes = SyntheticShapes(n_shapes=2, n_verts=700, seed=0)
    x, y = (shapes.load(name) for name in shapes.names)
    features = x.mesh.centred().verts, y.mesh.centred().verts
    judged_suspect_once(monkeypatch, pipeline)
    wrong = features[0][:10], features[1]  # ten rows for the whole source
    result = spidermatch.match(x.mesh, y.mesh, features=features, resolution=60, second_opinion=wrong)
    assert result.status == "optimal" and result.matches is not None
    assert result.details.second_opinion["kept"] == "first"
    assert "10 rows" in result.details.second_opinion["error"]


def test_cli_second_opinion_rewrites_the_outputs_with_the_kept_map(tmp_path, tiny_checkpoint, monkeypatch):
    import spidermatch.cli.match as cli_match

    learned = ["features=learned", f"checkpoint={tiny_checkpoint}"]
    assert run_match(composed("match", SMALL + learned), tmp_path / "alone") == 0

    def other_features(cfg, inputs):  # a second descriptor that disagrees: another map
        rng = np.random.default_rng(0)
        return rng.normal(size=(inputs.source.n_verts, 8)), rng.normal(size=(inputs.target.n_verts, 8))

    def judged_plausible(first, second):  # whatever its real verdict, the second map is kept
        second.quality = {**(second.quality or {}), "verdict": "plausible", "reasons": []}
        return real_kept_opinion(first, second)

    judged_suspect_once(monkeypatch, cli_match)
    monkeypatch.setattr(cli_match, "second_opinion_features", other_features)
    real_kept_opinion = pipeline.kept_opinion
    monkeypatch.setattr(pipeline, "kept_opinion", judged_plausible)
    asked = learned + [f"second_opinion={tiny_checkpoint}"]
    assert run_match(composed("match", SMALL + asked), tmp_path / "asked") == 0
    result = json.loads((tmp_path / "asked" / "result.json").read_text())
    record = result["second_opinion"]
    assert record["kept"] == "second" and record["time_s"] > 0
    assert result["objective"] == pytest.approx(record["second"]["objective"])  # the report is the second's
    assert record["first"]["objective"] != pytest.approx(record["second"]["objective"])
    assert result["status"] == "optimal" and result["check"]["ok"]
    files = [(tmp_path / run / "matches.csv").read_text() for run in ("alone", "asked")]
    assert files[0] != files[1]  # matches.csv is the second map's
    dense = [np.load(tmp_path / run / "dense_map.npz")["vertex"] for run in ("alone", "asked")]
    assert not np.array_equal(*dense)  # and so is the dense map


def test_cli_second_opinion_that_fails_leaves_the_first_map(tmp_path, tiny_checkpoint, monkeypatch):
    import spidermatch.cli.match as cli_match

    def broken(cfg, inputs):
        raise RuntimeError("the second network is broken")

    judged_suspect_once(monkeypatch, cli_match)
    monkeypatch.setattr(cli_match, "second_opinion_features", broken)
    learned = ["features=learned", f"checkpoint={tiny_checkpoint}", f"second_opinion={tiny_checkpoint}"]
    assert run_match(composed("match", SMALL + learned), tmp_path) == 0
    result = json.loads((tmp_path / "result.json").read_text())
    assert result["second_opinion"] == {"kept": "first", "error": "the second network is broken"}
    assert result["status"] == "optimal" and (tmp_path / "matches.csv").exists()


@pytest.mark.parametrize(
    "overrides, problem",
    [
        (["features=wks", "second_opinion=net.pt"], "second_opinion=net.pt: needs features=learned"),
        (
            ["features=learned", "checkpoint=net.pt", "second_opinion=missing.pt"],
            "second_opinion=missing.pt: no such file",
        ),
    ],
)
def test_a_second_opinion_that_cannot_be_asked_is_refused_before_any_work(tmp_path, overrides, problem):
    assert run_match(composed("match", SMALL + overrides), tmp_path) == 2
    assert problem in json.loads((tmp_path / "result.json").read_text())["error"]
