import csv
import json

import numpy as np
import pytest
from conftest import composed

from spidermatch.cli.batch import SUMMARY_COLUMNS, summarise, summary_row
from spidermatch.cli.match import run_match
from spidermatch.report.dense_report import read_dense_map

SMALL = ["data.n_verts=700", "resolution=60", "output.png=false"]


def config(overrides):
    return composed("match", overrides)


def test_match_writes_a_dense_map_of_every_source_vertex(tmp_path):
    assert run_match(config(SMALL), tmp_path) == 0
    result = json.loads((tmp_path / "result.json").read_text())
    low_pairs = np.loadtxt(tmp_path / "matches.csv", delimiter=",", skiprows=1, dtype=int)
    rows = list(csv.reader((tmp_path / "dense_matches.csv").open()))
    assert rows[0] == ["source_vertex", "target_vertex"]
    dense = np.array(rows[1:], dtype=int)
    n_source = dense.shape[0]
    assert np.array_equal(dense[:, 0], np.arange(n_source))
    assert low_pairs.shape[0] > 0
    stored = read_dense_map(tmp_path / "dense_map.npz")
    assert np.array_equal(stored.vertex, dense[:, 1])
    assert stored.face.shape == (n_source,) and stored.bary.shape == (n_source, 3)
    assert result["dense"]["method"] == stored.method == "deformation" and "dense" in result["timings_s"]
    for name in ("dense", "dense_vertex_map", "nearest_neighbour"):
        figures = result["dense"][name]
        assert set(figures) == {"tears", "flips", "flipped", "degenerate", "geodesic_error"}
        assert 0 <= figures["tears"] <= 1 and 0 <= figures["flips"] <= 1
        assert figures["flips"] == pytest.approx(figures["flipped"] + figures["degenerate"])
    # The deformation starts from the certified matches and stays near them.
    assert result["dense"]["certified"]["within_one_edge"] > 0.5
    coverage = result["dense"]["coverage"]
    assert 0.5 < coverage["covered_area"] <= 1 and 0 < coverage["reached_vertices"] <= 1
    assert np.load(tmp_path / "dense_geodesic_errors.npy").shape == (1000,)
    row = summary_row("a", "b", result)
    assert set(row) == set(SUMMARY_COLUMNS)
    assert row["dense_error"] == result["dense"]["dense"]["geodesic_error"]
    assert row["nn_tears"] == result["dense"]["nearest_neighbour"]["tears"]
    assert summarise([row], 1)["dense_error"]["n"] == 1


def test_pinning_methods_keep_the_certified_matches(tmp_path):
    assert run_match(config(SMALL + ["dense.method=interp_features"]), tmp_path) == 0
    low_pairs = np.loadtxt(tmp_path / "matches.csv", delimiter=",", skiprows=1, dtype=int)
    dense = np.loadtxt(tmp_path / "dense_matches.csv", delimiter=",", skiprows=1, dtype=int)
    assert np.array_equal(dense[low_pairs[:, 0], 1], low_pairs[:, 1])
    certified = json.loads((tmp_path / "result.json").read_text())["dense"]["certified"]
    assert certified == {"mean_distance": 0.0, "within_one_edge": 1.0}


def test_inverse_map_of_every_target_vertex_agrees_with_the_forward_map(tmp_path):
    assert run_match(config(SMALL + ["dense.inverse=true"]), tmp_path) == 0
    inverse = np.loadtxt(tmp_path / "dense_inverse_matches.csv", delimiter=",", skiprows=1, dtype=int)
    stored = read_dense_map(tmp_path / "dense_map.npz")
    n_target = stored.inverse.vertex.size
    assert np.array_equal(inverse[:, 0], np.arange(n_target)) and np.array_equal(
        inverse[:, 1], stored.inverse.vertex
    )
    # Forward after inverse returns a target vertex to itself, up to the gap (small where covered).
    assert np.median(stored.inverse.gap) < 0.02 and stored.inverse.bary.shape == (n_target, 3)
    assert np.mean(stored.vertex[stored.inverse.vertex] == np.arange(n_target)) > 0.2


def test_dense_map_can_be_turned_off(tmp_path):
    assert run_match(config(SMALL + ["dense.enabled=false"]), tmp_path) == 0
    result = json.loads((tmp_path / "result.json").read_text())
    assert "dense" not in result and "dense" not in result["timings_s"]
    assert not (tmp_path / "dense_matches.csv").exists() and not (tmp_path / "dense_map.npz").exists()
    assert (tmp_path / "matches.csv").is_file()
    assert summary_row("a", "b", result)["dense_error"] is None
