"""A part matched in several presentations to the network: the cheapest consistent matching is kept."""

import numpy as np
import pytest

import spidermatch
from spidermatch import pipeline
from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.descriptors import WKSExtractor
from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.partial import mean_edge_length, plane_cut


@pytest.fixture(scope="module")
def creature() -> Mesh:
    return make_creature(n_verts=900, seed=3).mesh


class _PresentingExtractor:
    """Features of a part in two presentations: a wrong one (scrambled rows) first, then the right one."""

    def __init__(self, whole: Mesh, part):
        self.whole_features = WKSExtractor()(whole)
        self.right = self.whole_features[part.to_original]
        self.wrong = self.right[np.random.default_rng(0).permutation(len(self.right))]
        self.asked = []

    def __call__(self, mesh):
        return self.whole_features

    def part_features(self, part, whole):
        return self.wrong, self.whole_features

    def part_feature_options(self, part, whole, count):
        self.asked.append(count)
        return [("scrambled", self.wrong), ("as cut", self.right)][:count], self.whole_features


def test_the_cheapest_presentation_is_kept_and_every_one_is_reported(creature):
    part = plane_cut(creature, np.array([0.0, 1.0, 0.3]), 0.6, "part")
    extractor = _PresentingExtractor(creature, part)
    settings = spidermatch.MatchSettings(resolution=300, part_presentations=2)
    # the scrambled presentation is hard to certify: it ends at its share of the 30 s
    result = spidermatch.match(part.mesh, creature, features=extractor, settings=settings, time_limit=30)
    assert extractor.asked == [2]
    details = result.details
    assert details.presentation == 1 and result.status == "optimal"
    rows = details.presentations
    assert [row["presentation"] for row in rows] == ["scrambled", "as cut"]
    assert [row["chosen"] for row in rows] == [False, True]
    assert rows[1]["objective"] < rows[0]["objective"]
    assert "other_presentations" in details.timings
    dense_error = np.linalg.norm(creature.verts[result.dense_map] - part.mesh.verts, axis=1)
    assert np.mean(dense_error) < 0.5 * mean_edge_length(creature)  # the right presentation's map


def test_one_presentation_asks_for_the_best_one_only(creature):
    part = plane_cut(creature, np.array([0.0, 1.0, 0.3]), 0.6, "part")
    extractor = _PresentingExtractor(creature, part)
    settings = spidermatch.MatchSettings(resolution=300, part_presentations=1, dense=None)
    result = spidermatch.match(
        part.mesh, creature, features=extractor, settings=settings, strict=False, time_limit=5
    )
    assert extractor.asked == [] and result.details.presentations == []  # part_features, once


def test_the_presentations_share_the_solver_budget(creature, monkeypatch):
    """Each presentation gets an equal share of the time the earlier ones left (not the whole limit)."""
    part = plane_cut(creature, np.array([0.0, 1.0, 0.3]), 0.6, "part")
    features = WKSExtractor()(creature)
    limits, real_match = [], pipeline.match

    def recording_match(source, target, feat_x, feat_y, settings):
        limits.append(settings.solver.time_limit)
        assert settings.dense is None  # only the winner gets a dense map
        result = real_match(source, target, feat_x, feat_y, settings)
        result.timings["solve"] = 6.0  # as if each solve took 6 s
        return result

    monkeypatch.setattr(pipeline, "match", recording_match)
    options = [(f"option {k}", features[part.to_original]) for k in range(3)]
    settings = spidermatch.MatchSettings(resolution=200, partial=True)
    settings = pipeline.dataclasses.replace(
        settings, solver=pipeline.dataclasses.replace(settings.solver, time_limit=30.0)
    )
    result = pipeline.match_presentations(part.mesh, creature, options, features, settings)
    assert limits == pytest.approx([10.0, 12.0, 18.0])  # 30/3, (30-6)/2, 30-12
    assert result.presentation == 0 and result.dense is not None  # equal objectives: the first


def test_the_command_line_reports_each_presentation_and_keeps_the_cheapest(tmp_path, creature, monkeypatch):
    from conftest import composed, result_of

    from spidermatch.cli import inputs as cli_inputs
    from spidermatch.cli.match import run_match
    from spidermatch.geometry.io import save_mesh

    part = plane_cut(creature, np.array([0.0, 1.0, 0.3]), 0.6, "part")
    extractor = _PresentingExtractor(creature, part)
    monkeypatch.setattr(cli_inputs, "make_extractor", lambda cfg: extractor)
    save_mesh(part.mesh, tmp_path / "part.off")
    save_mesh(creature, tmp_path / "whole.off")
    overrides = [f"source={tmp_path / 'part.off'}", f"target={tmp_path / 'whole.off'}", "resolution=300"]
    overrides += ["part_presentations=2", "solver.time_limit=30", "output.png=false"]
    assert run_match(composed("match", overrides), tmp_path / "run") == 0
    result = result_of(tmp_path / "run")
    assert [row["chosen"] for row in result["presentations"]] == [False, True]
    assert result["status"] == "optimal" and "other_presentations" in result["timings_s"]
    dense = np.loadtxt(tmp_path / "run" / "dense_matches.csv", delimiter=",", skiprows=1, dtype=np.int64)
    dense_error = np.linalg.norm(creature.verts[dense[:, 1]] - part.mesh.verts, axis=1)
    assert np.mean(dense_error) < 0.5 * mean_edge_length(creature)  # the right presentation's dense map


@pytest.mark.parametrize("value", ["0", "1.5", "many"])
def test_a_bad_number_of_presentations_is_refused_naming_the_option(value):
    from conftest import composed

    from spidermatch.validate import OptionError, check_options

    with pytest.raises(OptionError, match=f"part_presentations='?{value}'?: must be a whole number"):
        check_options(composed("match", [f"part_presentations={value}"]))
    with pytest.raises(OptionError, match="part_presentations"):
        pipeline.check_settings(spidermatch.MatchSettings(part_presentations=0))


def test_another_presentation_is_kept_only_when_it_undercuts_the_first_by_the_margin():
    from types import SimpleNamespace

    def solved(objective):
        return SimpleNamespace(low_map=np.zeros(3), check=None, solve=SimpleNamespace(objective=objective))

    unsolved = SimpleNamespace(low_map=None, check=None, solve=SimpleNamespace(objective=float("inf")))
    just_below = 10.0 * (1.0 - pipeline.PRESENTATION_MARGIN) * 1.01
    assert pipeline._cheapest([solved(10.0), solved(just_below)]) == 0  # within the margin: the search's
    assert pipeline._cheapest([solved(10.0), solved(just_below * 0.97), solved(9.5)]) == 1
    assert pipeline._cheapest([unsolved, solved(12.0), solved(11.0)]) == 2  # the first has no matching
    assert pipeline._cheapest([unsolved, unsolved]) == 0
