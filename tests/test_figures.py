from types import SimpleNamespace

import numpy as np
import pytest

from spidermatch.cli.inputs import MatchInputs
from spidermatch.cli.outputs import write_pngs
from spidermatch.data.synthetic import creature_pair_ground_truth, make_creature
from spidermatch.geometry.remesh import decimate
from spidermatch.report.figures import status_line


@pytest.fixture(scope="module")
def pair():
    source, target = make_creature(600, seed=0), make_creature(600, seed=1)
    truth = creature_pair_ground_truth(source, target)
    references = np.arange(0, source.mesh.n_verts, 4)
    inputs = MatchInputs(
        source.mesh, target.mesh, references, truth[references], 60, "/data/a.off -> /data/b.off"
    )
    low = decimate(source.mesh, 60)
    return inputs, low, truth


def fake_result(low, pairs, dense_map=None, covered=None):
    """What write_pngs reads of a MatchResult: low-res source, curve, full-res pairs, dense map
    and the target region it covers (a partial source's)."""
    curve = SimpleNamespace(vertices=np.arange(low.mesh.n_verts))
    dense = None if dense_map is None else SimpleNamespace(covered=covered)
    return SimpleNamespace(source=low, curve=curve, full_pairs=pairs, dense_map=dense_map, dense=dense)


def test_pictures_use_the_dense_map_when_the_result_has_one(tmp_path, pair):
    inputs, low, truth = pair
    report = {"status": "optimal", "gap": 0.0, "resolution": 60, "features": "wks"}
    pairs = np.stack([low.to_full, truth[low.to_full]], axis=1)
    write_pngs(tmp_path, fake_result(low, pairs, dense_map=truth), inputs, report)
    names = {path.name for path in tmp_path.iterdir()}
    assert names == {"correspondence.png", "spider_curve.png", "texture.png", "error.png", "viewer.html"}
    # the exact dense map has zero error at every reference point
    assert "mean 0.0000" in (tmp_path / "viewer.html").read_text()


def test_pictures_fall_back_to_the_pairs_and_can_skip_the_viewer(tmp_path, pair):
    inputs, low, truth = pair
    pairs = np.stack([low.to_full, truth[low.to_full]], axis=1)
    write_pngs(tmp_path, fake_result(low, pairs), inputs, {"status": "feasible", "gap": 0.02}, viewer=False)
    assert {path.name for path in tmp_path.iterdir()} == {
        "correspondence.png",
        "spider_curve.png",
        "error.png",
    }


def test_status_line_always_has_status_and_gap():
    assert status_line({"status": "optimal", "gap": 1e-4, "resolution": 250, "features": "wks"}) == (
        "optimal, gap 1.0e-04 | 250 faces, wks features"
    )
    assert status_line({"status": "no_solution", "gap": None}) == "no_solution, gap unknown"


def test_given_errors_are_drawn_without_recomputing_them(tmp_path, pair):
    inputs, low, truth = pair
    pairs = np.stack([low.to_full, truth[low.to_full]], axis=1)
    given = (pairs[:, 0], np.full(len(pairs), 0.123))
    write_pngs(tmp_path, fake_result(low, pairs), inputs, {"status": "optimal", "gap": 0.0}, True, given)
    assert "mean 0.1230" in (tmp_path / "viewer.html").read_text()
