"""The verdict's distortion figure on meshes with boundaries (parts of one surface)."""

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from spidermatch.dense.maps import DenseMap
from spidermatch.eval.quality import (
    OPEN_DENSE_DISTORTION_SUSPECT,
    OPEN_TARGET_UNJUDGED,
    assess,
    dense_figures,
    distortion,
    judge,
    with_dense_figures,
)
from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.surface import vertex_points

SPHERE = trimesh.creation.icosphere(subdivisions=4)
WHOLE_VERTS = SPHERE.vertices * [2.0, 1.0, 1.0]  # an elongated closed surface
FACE_CENTRES = WHOLE_VERTS[SPHERE.faces].mean(axis=1)


def _part(kept_faces: np.ndarray, name: str) -> Mesh:
    """The whole surface's faces ``kept_faces`` (F,) bool as a mesh of their own."""
    faces = SPHERE.faces[kept_faces]
    used = np.unique(faces)
    return Mesh(WHOLE_VERTS[used], np.searchsorted(used, faces), name)


@pytest.fixture(scope="module")
def parts():
    """Two parts of the surface: one end cut off (the source), and a slit across the middle
    that leaves a bridge (the target), so that target paths across the slit detour."""
    source = _part(FACE_CENTRES[:, 0] < 1.5, "end cut off")
    slit = (np.abs(FACE_CENTRES[:, 0]) < 0.12) & (FACE_CENTRES[:, 1] > -0.6)
    target = _part(~slit, "slit")
    right = cKDTree(target.verts).query(source.verts)[1]  # each point onto itself
    order = np.argsort(source.verts[:, 0])
    half = source.n_verts // 2
    wrong = right.copy()
    wrong[order[:half]] = right[order[::-1][:half]]  # one half laid onto the other end
    return source, target, right, wrong


def test_distances_around_a_target_s_boundaries_do_not_count_against_a_right_map(parts):
    source, target, right, wrong = parts
    # paths across the slit detour around it: compared as they are, a right map looks distorted
    assert distortion(source, target, right) > 0.1
    assert distortion(source, target, right, around_boundaries=True) == 0.0
    assert distortion(source, target, wrong, around_boundaries=True) > 0.25


def test_on_closed_meshes_the_bounded_figure_is_the_plain_one():
    whole = Mesh(WHOLE_VERTS, SPHERE.faces, "whole")
    order = np.argsort(whole.verts[:, 0])
    scrambled = np.arange(whole.n_verts)
    scrambled[order[: whole.n_verts // 2]] = order[::-1][: whole.n_verts // 2]
    plain = distortion(whole, whole, scrambled)
    assert plain > 0.2 and distortion(whole, whole, scrambled, around_boundaries=True) == plain


def _verdict(source: Mesh, target: Mesh, vertex_map: np.ndarray) -> dict:
    """The pipeline's verdict with the dense map's figures: a vertex map as both maps."""
    dense = DenseMap(vertex_map, *vertex_points(target, vertex_map), "test")
    return with_dense_figures(assess(source, target, vertex_map, 1e-4), dense_figures(source, target, dense))


def test_a_target_with_boundaries_is_judged_by_the_dense_map_around_them(parts):
    source, target, right, wrong = parts
    before = assess(source, target, right, 1e-4)  # the certified map alone: not judged there
    assert before["unjudged"] == [OPEN_TARGET_UNJUDGED]
    plausible = _verdict(source, target, right)
    assert plausible["dense_distortion_around_boundaries"] is True
    assert plausible["dense_distortion"] <= OPEN_DENSE_DISTORTION_SUSPECT
    assert plausible["verdict"] == "plausible" and plausible["unjudged"] == []
    suspect = _verdict(source, target, wrong)
    assert suspect["verdict"] == "suspect"
    assert any("even where the boundaries could explain it" in reason for reason in suspect["reasons"])


def test_few_distinct_targets_are_told_a_collapse_or_a_source_pressed_together_by_the_covered_area():
    """On parts of FAUST_r, maps with few distinct targets that still cover much of the source's area
    were mostly wrong overlaps (a piece without partner pressed together), not stay paths."""
    figures = {"mirror": 0.1, "distinct": 0.35, "gap": 1e-4, "distortion": 0.0, "distortion_judged": False}
    dense = {"dense_mirror": 0.1, "dense_distortion": 0.0, "dense_distortion_around_boundaries": True}
    pressed = judge({**figures, **dense, "dense_covered": 0.8})
    assert pressed["verdict"] == "suspect" and "pressed together" in pressed["reasons"][0]
    stay = judge({**figures, **dense, "dense_covered": 0.05})
    assert stay["verdict"] == "suspect"
    assert "the dense map covers 5% of the source's area: the matching collapses" in stay["reasons"][0]
    assert "(e.g. the trivial stay path)" in judge(figures)["reasons"][0]  # no dense map


def test_a_raw_scan_s_dense_map_is_judged_on_decimated_copies(parts, monkeypatch):
    """Meshes over DENSE_DISTORTION_MAX_VERTICES (raw scans) get their dense figure on decimated copies
    (before, none: a wrong map laid across a target with boundaries was called plausible, unjudged)."""
    from spidermatch.eval import quality

    source, target, right, wrong = parts
    monkeypatch.setattr(quality, "DENSE_DISTORTION_MAX_VERTICES", source.n_verts // 2)
    monkeypatch.setattr(quality, "DENSE_DISTORTION_COPY_FACES", source.n_faces // 3)
    low_source, low_target, low_map = quality.distortion_meshes(source, target, right)
    assert low_source.n_faces < source.n_faces / 2 and low_target.n_faces < target.n_faces / 2
    assert low_map.shape == (low_source.n_verts,) and low_map.max() < low_target.n_verts
    plausible = _verdict(source, target, right)
    assert plausible["dense_distortion"] is not None
    assert plausible["verdict"] == "plausible" and plausible["unjudged"] == []
    suspect = _verdict(source, target, wrong)
    assert suspect["verdict"] == "suspect"
    assert any("even where the boundaries could explain it" in reason for reason in suspect["reasons"])
