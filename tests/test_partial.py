"""Partial shapes: cut copies with exact index maps, recognising a part, matching it in the partial mode."""

import json
import re

import numpy as np
import pytest
import torch
import trimesh
from conftest import composed, judged_suspect_once

import spidermatch
from spidermatch import pipeline
from spidermatch.cli.match import run_match
from spidermatch.data.synthetic import make_creature
from spidermatch.dense.densify import densify
from spidermatch.dense.settings import DenseSettings
from spidermatch.geometry.descriptors import WKSExtractor
from spidermatch.geometry.io import load_mesh, save_mesh
from spidermatch.geometry.mesh import Mesh, MeshError, make_mesh, topology
from spidermatch.geometry.partial import (
    MAX_PART_AREA_RATIO,
    MIN_PART_SHARE,
    covered_target,
    fitted_scale,
    holes_cut,
    mean_edge_length,
    overlap_kind,
    pair_kind,
    plane_cut,
    random_cut,
    rigid_fit_residual,
    view_cut,
)
from train.losses import cut_consistency_loss


@pytest.fixture(scope="module")
def creature() -> Mesh:
    return make_creature(n_verts=900, seed=3).mesh


def _is_exact_part(part, whole: Mesh) -> None:
    """The part's vertices are the whole's, and it passes the loader's validation."""
    assert np.array_equal(part.mesh.verts, whole.verts[part.to_original])
    make_mesh(part.mesh.verts, part.mesh.faces, "part")  # raises on a bow-tie, several pieces, ...
    assert np.isclose(part.kept_area, part.mesh.area / whole.area)


def test_a_plane_cut_keeps_the_asked_share_of_the_area_below_the_plane(creature):
    part = plane_cut(creature, np.array([0.0, 1.0, 0.0]), 0.5, "lower half")
    _is_exact_part(part, creature)
    assert 0.35 <= part.kept_area <= 0.55  # the clean-up keeps only the largest piece
    level = np.quantile(creature.verts[:, 1], 0.5)
    assert part.mesh.verts[:, 1].min() < level - 0.1 * np.ptp(creature.verts[:, 1])
    assert topology(part.mesh).boundaries >= 1


def test_holes_open_boundary_loops_around_their_centres(creature):
    farthest = int(np.argmax(np.linalg.norm(creature.verts - creature.verts[0], axis=1)))
    centres = np.array([0, farthest])
    part = holes_cut(creature, centres, 0.85, "two holes")
    _is_exact_part(part, creature)
    assert not np.isin(centres, part.to_original).any()
    assert topology(part.mesh).boundaries == 2 and 0.8 <= part.kept_area <= 0.9


def test_a_single_view_keeps_the_side_facing_the_camera(creature):
    part = view_cut(creature, np.array([0.0, 0.0, -1.0]), "front view")
    _is_exact_part(part, creature)
    normals = np.cross(
        *(part.mesh.verts[part.mesh.faces[:, k]] - part.mesh.verts[part.mesh.faces[:, 0]] for k in (1, 2))
    )
    assert (normals[:, 2] > 0).mean() > 0.95  # seen faces face the camera (+z)
    assert 0.2 < part.kept_area < 0.6


def test_random_cuts_stay_in_the_asked_range_and_repeat_with_their_seed(creature):
    for kind in ("plane", "holes", "view"):
        first = random_cut(creature, kind, np.random.default_rng(7), (0.3, 0.7))
        again = random_cut(creature, kind, np.random.default_rng(7), (0.3, 0.7))
        assert 0.3 <= first.kept_area <= 0.7
        assert np.array_equal(first.to_original, again.to_original)
    with pytest.raises(ValueError, match="choose from"):
        random_cut(creature, "slice", np.random.default_rng(0))


def test_a_part_is_recognised_and_other_topology_differences_refused(creature):
    part = plane_cut(creature, np.array([0.0, 1.0, 0.0]), 0.5, "part.off").mesh
    assert pair_kind(creature, creature).mode == "whole"
    kind = pair_kind(part, creature)
    assert kind.mode == "partial" and "part.off" in kind.reason and kind.area_ratio < 0.6
    assert kind.caution == ""
    holed = holes_cut(part, part.verts[[0]], 0.8, "holed.off").mesh  # a part of the part: both open
    assert "partial=both matches two incomplete shapes" in pair_kind(holed, part).caution
    with pytest.raises(MeshError, match="swap source and target"):
        pair_kind(creature, part)
    with pytest.raises(MeshError, match="partial=auto"):
        pair_kind(part, creature, partial=False)
    enlarged = Mesh(part.verts * 10.0, part.faces, "millimetres.off")
    with pytest.raises(MeshError, match="same unit"):
        pair_kind(enlarged, creature)


def test_a_large_part_of_a_larger_body_is_a_part_not_a_whole_shape(creature):
    """An 85 % scan of a body 1.2 times the target's size has more area than the target (FAUST_r's
    bodies differ that much); it is still a part, with a caution, up to MAX_PART_AREA_RATIO."""
    part = plane_cut(creature, np.array([0.0, 1.0, 0.0]), 0.85, "tall.off").mesh
    for size in (1.2, 1.35):
        larger = Mesh(part.verts * size, part.faces, "tall.off")
        kind = pair_kind(larger, creature)
        assert kind.mode == "partial" and 1.0 < kind.area_ratio < MAX_PART_AREA_RATIO
        assert "larger body in the same unit" in kind.caution
    beyond = Mesh(part.verts * 1.6, part.faces, "tall.off")  # 2.2 times the area: no body differs that much
    with pytest.raises(MeshError, match="same unit"):
        pair_kind(beyond, creature)


def test_a_part_in_another_unit_than_its_whole_is_refused_with_the_likely_factor(creature):
    part = plane_cut(creature, np.array([0.0, 1.0, 0.0]), 0.5, "part_m.off").mesh
    in_millimetres = Mesh(creature.verts * 1000.0, creature.faces, "whole_mm.off")
    metres_in_millimetres = r"scaled by 1000 \(millimetres and metres\)"
    with pytest.raises(MeshError, match=r"only 5.*e-07 of its area.*" + metres_in_millimetres):
        pair_kind(part, in_millimetres)
    part_mm = Mesh(part.verts * 1000.0, part.faces, "part_mm.off")
    with pytest.raises(MeshError, match=r"same unit \(the source scaled by 0.001 \(millimetres and metres\)"):
        pair_kind(part_mm, creature)
    with pytest.raises(
        MeshError, match=r"partial=both: part_m.off has 5.*e-07 times the area.*" + metres_in_millimetres
    ):
        overlap_kind(part, in_millimetres)
    tiny = plane_cut(creature, np.array([0.0, 1.0, 0.0]), 0.008, "tiny.off").mesh  # a true part, too small
    assert tiny.area / creature.area < MIN_PART_SHARE
    with pytest.raises(MeshError, match="too small to be matched"):
        pair_kind(tiny, creature)


def test_the_identity_of_a_part_covers_what_was_kept():
    sphere = trimesh.creation.icosphere(subdivisions=4)
    whole = Mesh(sphere.vertices, sphere.faces, "sphere")
    for part in (
        plane_cut(whole, np.array([1.0, 0.2, 0.0]), 0.5, "half"),
        holes_cut(whole, np.array([0, 100]), 0.6, "holed"),
    ):
        faces, bary = _at_vertices(whole, part.to_original)
        covered = covered_target(whole, faces, bary, mean_edge_length(part.mesh))
        kept = np.zeros(whole.n_verts, dtype=bool)
        kept[part.to_original] = True
        assert covered[kept].all()
        assert (covered & ~kept).sum() <= 0.01 * kept.sum()  # not the ring one edge outside


def _at_vertices(mesh: Mesh, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each of ``vertices`` as a point on ``mesh``: a face around it, all the weight on it."""
    face_of = np.zeros(mesh.n_verts, dtype=np.int64)
    corner_of = np.zeros(mesh.n_verts, dtype=np.int64)
    for corner in range(3):
        face_of[mesh.faces[:, corner]] = np.arange(mesh.n_faces)
        corner_of[mesh.faces[:, corner]] = corner
    bary = np.zeros((len(vertices), 3))
    bary[np.arange(len(vertices)), corner_of[vertices]] = 1.0
    return face_of[vertices], bary


def test_an_image_inside_faces_covers_their_corners():
    """Image points in the middle of faces reach into the stars of all their corners, though each
    corner is more than half an edge away: the corners are covered as the part's own rim is."""
    sphere = trimesh.creation.icosphere(subdivisions=4)
    whole = Mesh(sphere.vertices, sphere.faces, "sphere")
    faces = np.flatnonzero(whole.verts[whole.faces].mean(axis=1)[:, 0] > 0.5)
    bary = np.full((faces.size, 3), 1.0 / 3.0)
    covered = covered_target(whole, faces, bary, 0.0, closing_rings=0)
    corners = np.zeros(whole.n_verts, dtype=bool)
    corners[whole.faces[faces]] = True
    assert np.array_equal(covered, corners)
    on_edges = np.array([[0.5, 0.5, 0.0]] * faces.size)  # on the edge opposite each third corner
    covered = covered_target(whole, faces, on_edges, 0.0, closing_rings=0)
    assert not covered[whole.faces[faces, 2]].all() and covered[whole.faces[faces, :2]].all()


def test_the_rigid_fit_residual_tells_a_moved_copy_from_scrambled_partners(creature):
    points = creature.verts
    angle = 2.0
    turn = np.array(
        [[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]]
    )
    moved = points @ turn.T + np.array([3.0, -1.0, 0.5])
    spread = np.linalg.norm(points - points.mean(axis=0), axis=1).mean()
    assert rigid_fit_residual(points, moved) < 1e-9 * spread
    wrong = moved.copy()
    wrong[::4] = moved[np.random.default_rng(0).permutation(points.shape[0])[::4]]
    assert rigid_fit_residual(points, wrong) < 1e-9 * spread  # a quarter wrong does not decide it
    mirrored = moved * np.array([-1.0, 1.0, 1.0])  # a reflection is no rigid motion
    assert rigid_fit_residual(points, mirrored) > 0.05 * spread
    scrambled = moved[np.random.default_rng(1).permutation(points.shape[0])]
    assert rigid_fit_residual(points, scrambled) > 0.5 * spread


def test_the_fitted_scale_reads_a_size_through_wrong_partners_and_a_turn(creature):
    points = creature.verts
    angle = 1.0
    turn = np.array(
        [[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]]
    )
    for size in (0.8, 1.0, 1.25):
        partners = size * points @ turn.T + np.array([1.0, 2.0, -3.0])
        partners[::4] = partners[np.random.default_rng(0).permutation(points.shape[0])[::4]]
        assert fitted_scale(points, partners) == pytest.approx(size, rel=1e-9)


def test_cut_consistency_prefers_features_that_find_each_vertex_of_the_part():
    generator = torch.Generator().manual_seed(0)
    whole = torch.nn.functional.normalize(torch.randn(50, 8, generator=generator), dim=1)
    to_whole = torch.arange(10, 40)
    agreeing = cut_consistency_loss(whole[to_whole], whole, to_whole, 0.07)
    shuffled = cut_consistency_loss(whole[to_whole.flip(0)], whole, to_whole, 0.07)
    assert agreeing < 0.5 < shuffled
    points = torch.tensor([0, 3])
    assert torch.isclose(
        cut_consistency_loss(whole[to_whole], whole, to_whole, 0.07, points),
        cut_consistency_loss(whole[to_whole[points]], whole, to_whole[points], 0.07),
    )


def test_the_partial_mode_recovers_the_identity_on_the_kept_part(creature, monkeypatch):
    """A cut copy against its whole, with the whole's own features restricted to the part.

    The dense stage deforms the part with the part's fit weight, not the whole shapes' one.
    """
    part = plane_cut(creature, np.array([0.0, 1.0, 0.3]), 0.6, "part")
    feat_whole = WKSExtractor()(creature)
    fit_weights = []

    def densify_recorded(*args, **kwargs):
        fit_weights.append(args[7].fit_weight)
        return densify(*args, **kwargs)

    monkeypatch.setattr(pipeline, "densify", densify_recorded)
    result = spidermatch.match(
        part.mesh,
        creature,
        features=(feat_whole[part.to_original], feat_whole),
        resolution=300,
        time_limit=600,
    )
    assert result.details.pair.mode == "partial" and result.status == "optimal"
    assert fit_weights == [DenseSettings().part_fit_weight] != [DenseSettings().fit_weight]
    sparse_source, sparse_target = result.matches.T
    sparse_error = np.linalg.norm(creature.verts[sparse_target] - part.mesh.verts[sparse_source], axis=1)
    dense_error = np.linalg.norm(creature.verts[result.dense_map] - part.mesh.verts, axis=1)
    assert np.mean(sparse_error) < 0.5 * mean_edge_length(result.details.target.mesh)
    assert np.mean(dense_error) < 0.5 * mean_edge_length(creature)
    covered = result.target_covered
    assert np.array_equal(covered, result.dense.covered)  # the target as given was matched
    kept = np.zeros(creature.n_verts, dtype=bool)
    kept[part.to_original] = True
    assert (covered & kept).sum() / (covered | kept).sum() > 0.85


def test_the_covered_target_names_the_vertices_of_a_target_given_as_a_soup(creature):
    """A target whose faces each have their own corners (an STL file) is matched welded; the
    covered region is told per corner, each corner as its vertex."""
    part = plane_cut(creature, np.array([0.0, 1.0, 0.3]), 0.6, "part")
    corners = creature.faces.reshape(-1)
    soup = Mesh(creature.verts[corners], np.arange(corners.size).reshape(-1, 3), "soup.stl")
    feat_whole = WKSExtractor()(creature)
    result = spidermatch.match(
        part.mesh, soup, features=(feat_whole[part.to_original], feat_whole[corners]), resolution=200
    )
    assert result.details.pair.mode == "partial" and result.target_covered.shape == (soup.n_verts,)
    assert result.dense.covered.shape == (creature.n_verts,)  # the welded target's, as matched
    covered = np.zeros(creature.n_verts, dtype=bool)
    covered[corners] = result.target_covered
    assert np.array_equal(covered[corners], result.target_covered)  # one value per vertex
    kept = np.zeros(creature.n_verts, dtype=bool)
    kept[part.to_original] = True
    assert (covered & kept).sum() / (covered | kept).sum() > 0.85


def _matched_files(tmp_path, source: Mesh, target: Mesh, *overrides: str):
    """Run ``spidermatch-match`` on the two meshes (saved as source.off, target.off) without pictures."""
    save_mesh(source, tmp_path / "source.off")
    save_mesh(target, tmp_path / "target.off")
    files = [f"source={tmp_path / 'source.off'}", f"target={tmp_path / 'target.off'}"]
    cfg = composed("match", [*files, "output.png=false", *overrides])
    out = tmp_path / "run"
    assert run_match(cfg, out) == 0
    return out


def test_a_source_with_a_hole_is_matched_without_options(tmp_path, creature, caplog):
    holed = holes_cut(creature, np.array([10]), 0.85, "holed")
    caplog.set_level("WARNING", logger="spidermatch.api")
    out = _matched_files(tmp_path, holed.mesh, creature, "resolution=150", "solver.time_limit=600")
    assert "WKS is unfit for parts" in caplog.text  # the default features, said before the solve
    result = json.loads((out / "result.json").read_text())
    assert result["pair"]["mode"] == "partial" and "1 boundary loop" in result["pair"]["reason"]
    assert result["status"] in ("optimal", "feasible")
    assert 0.5 < result["overlap"]["target_covered_area"] <= 1.0
    with np.load(out / "dense_map.npz") as dense:
        assert dense["target_covered"].shape == (load_mesh(tmp_path / "target.off").n_verts,)


def _smooth_position_code(verts: np.ndarray, dims: int = 64, seed: int = 0) -> np.ndarray:
    """Descriptors (V, dims) whose cosine similarity falls off smoothly with 3-D distance."""
    rng = np.random.default_rng(seed)
    scale = np.sqrt(np.ptp(verts, axis=0).prod() ** (2 / 3))
    frequencies = rng.normal(size=(3, dims)) * 6.0 / scale
    return np.cos(verts @ frequencies + rng.uniform(0, 2 * np.pi, dims))


def _band_cuts(creature):
    """Two cuts of ``creature`` from opposite sides, sharing a band: (lower, upper) PartialShapes."""
    normal = np.array([0.0, 1.0, 0.3])
    return plane_cut(creature, normal, 0.65, "lower"), plane_cut(creature, -normal, 0.65, "upper")


def _band_parts_matched(
    creature, overlap_method: str, resolution: int = 300, time_limit: float = 600, **options
):
    """The two cuts of :func:`_band_cuts` matched with ``partial="both"`` (and ``options``).

    Returns the two parts, the matching and the true source overlap (V_lower,) bool.
    """
    lower, upper = _band_cuts(creature)
    code = _smooth_position_code(creature.verts)
    result = spidermatch.match(
        lower.mesh,
        upper.mesh,
        features=(code[lower.to_original], code[upper.to_original]),
        resolution=resolution,
        time_limit=time_limit,
        partial="both",
        overlap_method=overlap_method,
        **options,
    )
    in_upper = np.zeros(creature.n_verts, dtype=bool)
    in_upper[upper.to_original] = True
    return lower, upper, result, in_upper[lower.to_original]


def test_two_overlapping_parts_are_matched_on_their_overlap_only(creature):
    """Two cuts of one shape from opposite sides share a band: only it is matched, by the identity."""
    lower, upper, result, truth = _band_parts_matched(creature, "features")
    assert result.details.pair.mode == "overlap" and result.status == "optimal"
    found = result.source_overlap
    areas = lower.mesh.vertex_areas
    assert areas[found & truth].sum() / areas[found | truth].sum() > 0.65  # the whole part scores 0.51
    assert np.all((result.dense_map >= 0) == found)
    assert np.all(found[result.matches[:, 0]])
    both = found & truth  # a vertex without partner has no right image
    images = upper.mesh.verts[result.dense_map[both]]
    dense_error = np.linalg.norm(images - lower.mesh.verts[both], axis=1)
    assert np.mean(dense_error) < 0.5 * mean_edge_length(creature)
    # judged on the target with a boundary, by the dense map (docs/partial.md, "Telling a wrong partial map")
    quality = result.quality
    assert quality["dense_distortion_around_boundaries"] and quality["dense_covered"] > 0.5
    assert quality["verdict"] == "plausible" and quality["unjudged"] == [], quality


def _overlap_searches_spied(monkeypatch, fail_second: bool = False) -> list:
    """Each overlap search of ``spidermatch.api`` recorded as (V_X, D) of the source features it got;
    with ``fail_second``, the second search finds nothing."""
    from spidermatch import api

    widths, real_search = [], api.source_overlap_piece

    def spied(source, target, feat_x, *args):
        widths.append(np.shape(feat_x))
        if fail_second and len(widths) == 2:
            raise MeshError(f"{source.name}: no overlap with the target found")
        return real_search(source, target, feat_x, *args)

    monkeypatch.setattr(api, "source_overlap_piece", spied)
    return widths


def test_a_second_opinion_of_two_parts_finds_the_overlap_again_with_both_features(creature, monkeypatch):
    """partial="both": the second opinion searches the overlap again with the joined features (of the
    whole source, not the first piece) and matches it; the kept map and its overlap are its own."""
    lower, upper = _band_cuts(creature)
    other = _smooth_position_code(creature.verts, dims=48, seed=1)
    second = other[lower.to_original], other[upper.to_original]
    widths = _overlap_searches_spied(monkeypatch)
    judged_suspect_once(monkeypatch, pipeline)
    _, _, result, truth = _band_parts_matched(creature, "features", resolution=200, second_opinion=second)
    assert widths == [(lower.mesh.n_verts, 64), (lower.mesh.n_verts, 64 + 48)]
    record = result.details.second_opinion
    assert record["kept"] == "second" and record["second"]["verdict"] == "plausible", record
    found = result.source_overlap
    assert np.all((result.dense_map >= 0) == found)  # the files tell the kept map's piece
    areas = lower.mesh.vertex_areas
    assert areas[found & truth].sum() / areas[found | truth].sum() > 0.65
    both = found & truth
    dense_error = np.linalg.norm(upper.mesh.verts[result.dense_map[both]] - lower.mesh.verts[both], axis=1)
    assert np.mean(dense_error) < 0.5 * mean_edge_length(creature)


def test_a_second_opinion_of_two_parts_that_finds_no_overlap_leaves_the_first_map(creature, monkeypatch):
    lower, upper = _band_cuts(creature)
    other = _smooth_position_code(creature.verts, dims=48, seed=1)
    widths = _overlap_searches_spied(monkeypatch, fail_second=True)
    judged_suspect_once(monkeypatch, pipeline)
    second = other[lower.to_original], other[upper.to_original]
    _, _, result, _ = _band_parts_matched(creature, "features", resolution=200, second_opinion=second)
    assert len(widths) == 2 and result.status == "optimal" and result.dense_map is not None
    record = result.details.second_opinion
    assert record["kept"] == "first" and "no overlap with the target found" in record["error"]
    assert np.all((result.dense_map >= 0) == result.source_overlap)


def test_the_command_line_second_opinion_of_two_parts_writes_the_second_overlap(
    tmp_path, creature, tiny_checkpoint, monkeypatch
):
    """``partial=both`` with ``second_opinion``: the overlap is searched again with the joined features,
    and every file (result.json's overlap, dense_map.npz, dense_matches.csv) tells the kept map's piece."""
    import spidermatch.cli.match as cli_match

    def code_of(verts, seed):  # the descriptors of each file vertex, read at its place on the creature
        code = _smooth_position_code(creature.verts, dims=64 - 16 * seed, seed=seed)
        return code[np.argmin(((verts[:, None] - creature.verts[None]) ** 2).sum(2), axis=1)]

    def first_features(cfg, inputs):
        return code_of(inputs.source.verts, 0), code_of(inputs.target.verts, 0), "learned", {}

    def second_features(cfg, inputs):
        return code_of(inputs.source.verts, 1), code_of(inputs.target.verts, 1)

    lower, upper = _band_cuts(creature)
    monkeypatch.setattr(cli_match, "compute_features", first_features)
    monkeypatch.setattr(cli_match, "second_opinion_features", second_features)
    widths = _overlap_searches_spied(monkeypatch)
    judged_suspect_once(monkeypatch, cli_match)
    learned = ["features=learned", f"checkpoint={tiny_checkpoint}", f"second_opinion={tiny_checkpoint}"]
    out = _matched_files(tmp_path, lower.mesh, upper.mesh, "partial=both", "resolution=200", *learned)
    assert widths == [(lower.mesh.n_verts, 64), (lower.mesh.n_verts, 64 + 48)]
    result = json.loads((out / "result.json").read_text())
    assert result["second_opinion"]["kept"] == "second" and result["status"] == "optimal", result
    assert result["objective"] == pytest.approx(result["second_opinion"]["second"]["objective"])
    n_piece = result["overlap"]["source_overlap_vertices"]
    assert result["overlap"]["found_by"] == {"method": "features"}
    assert "target_covered_area" in result["overlap"]
    with np.load(out / "dense_map.npz") as dense:
        ids = dense["source_vertex"]
        assert ids.shape == (n_piece,) and ids.max() < lower.mesh.n_verts
    rows = np.loadtxt(out / "dense_matches.csv", delimiter=",", skiprows=1, dtype=np.int64)
    assert np.array_equal(np.flatnonzero(rows[:, 1] >= 0), np.sort(ids))
    truth = np.isin(lower.to_original, upper.to_original)
    both = truth & (rows[:, 1] >= 0)
    dense_error = np.linalg.norm(upper.mesh.verts[rows[both, 1]] - lower.mesh.verts[both], axis=1)
    assert both.sum() > 0.5 * truth.sum() and np.mean(dense_error) < mean_edge_length(creature)


def test_the_overlap_matched_with_a_void_vertex_is_closer_to_the_truth_than_the_estimate(creature):
    """The certified matching of all of one part decides its overlap: the band both cuts share."""
    lower, upper, result, truth = _band_parts_matched(creature, "matched")
    found_by = result.details.overlap_found
    assert found_by["method"] == "matched" and found_by["status"] == "optimal", found_by
    assert 0.3 < found_by["void_share"] < 0.7
    assert result.status == "optimal"
    found, areas = result.source_overlap, lower.mesh.vertex_areas
    assert areas[found & truth].sum() / areas[found | truth].sum() > 0.8  # 0.68 by the descriptors' estimate
    assert areas[found & truth].sum() / areas[found].sum() > 0.9  # little matched without a partner
    both = found & truth
    dense_error = np.linalg.norm(upper.mesh.verts[result.dense_map[both]] - lower.mesh.verts[both], axis=1)
    assert np.mean(dense_error) < 0.5 * mean_edge_length(creature)


class _ReferenceExtractor:
    """A network stand-in with a whole reference shape (``creature``): the descriptors of a vertex are
    those of the creature vertex it was cut from, each part told by its vertex count."""

    def __init__(self, creature, parts):
        self.reference_mesh = creature
        self.code = _smooth_position_code(creature.verts)
        self.origin = {part.mesh.n_verts: part.to_original for part in parts}
        self.origin[creature.n_verts] = np.arange(creature.n_verts)
        self.calls = []

    def _for(self, mesh):
        return self.code[self.origin[mesh.n_verts]]

    def __call__(self, mesh):
        return self._for(mesh)

    def parts_features(self, x, y):
        return self._for(x), self._for(y)

    def part_features(self, part, whole):
        self.calls.append((part.n_verts, whole.n_verts))
        return self._for(part), self._for(whole)


def test_the_overlap_read_on_a_reference_shape_is_the_band_both_parts_share(creature):
    """Each part read as a part of the whole reference: the source vertices whose partner the target
    reaches too are the band, closer to the truth than the descriptors' estimate (IoU 0.68 here)."""
    lower, upper = _band_cuts(creature)
    assert len({lower.mesh.n_verts, upper.mesh.n_verts, creature.n_verts}) == 3
    extractor = _ReferenceExtractor(creature, (lower, upper))
    result = spidermatch.match(
        lower.mesh, upper.mesh, features=extractor, resolution=300, partial="both", overlap_method="reference"
    )
    assert sorted(extractor.calls) == sorted(
        [(lower.mesh.n_verts, creature.n_verts), (upper.mesh.n_verts, creature.n_verts)]
    )
    found_by = result.details.overlap_found
    assert found_by["method"] == "reference" and found_by["target_overlap"] == "reference"
    assert result.status == "optimal"
    in_upper = np.zeros(creature.n_verts, dtype=bool)
    in_upper[upper.to_original] = True
    truth, found, areas = in_upper[lower.to_original], result.source_overlap, lower.mesh.vertex_areas
    assert areas[found & truth].sum() / areas[found | truth].sum() > 0.85
    assert areas[found & truth].sum() / areas[found].sum() > 0.9  # little matched without a partner
    both = found & truth
    dense_error = np.linalg.norm(upper.mesh.verts[result.dense_map[both]] - lower.mesh.verts[both], axis=1)
    assert np.mean(dense_error) < 0.5 * mean_edge_length(creature)
    in_lower = np.zeros(creature.n_verts, dtype=bool)
    in_lower[lower.to_original] = True
    truth, covered, areas = in_lower[upper.to_original], result.target_covered, upper.mesh.vertex_areas
    assert areas[covered & truth].sum() / areas[covered | truth].sum() > 0.85  # the target's, read alike
    assert 0.0 < found_by["map_covered_area"] <= 1.0


def test_parts_that_reach_disjoint_regions_of_the_reference_share_no_overlap(creature):
    from spidermatch.geometry.overlap import ReferenceImages, overlap_part, reference_overlap

    normal = np.array([0.0, 1.0, 0.3])
    lower, upper = plane_cut(creature, normal, 0.4, "lower"), plane_cut(creature, -normal, 0.4, "upper")
    images = ReferenceImages(creature, lower.to_original, upper.to_original)
    region = reference_overlap(lower.mesh, images, float(np.sqrt(lower.mesh.area)))
    assert lower.mesh.vertex_areas[region].sum() < 0.05 * lower.mesh.area
    with pytest.raises(MeshError, match="has a partner on the reference shape where the target lies"):
        overlap_part(lower.mesh, region, "has a partner on the reference shape where the target lies")
    both = reference_overlap(lower.mesh, ReferenceImages(creature, lower.to_original, lower.to_original), 1.0)
    assert both.all()  # a part against itself overlaps everywhere


def test_the_reference_overlap_without_a_reference_shape_falls_back_to_the_estimate(creature):
    """Precomputed descriptors (or WKS) have no reference shape: the descriptors' estimate is used, said."""
    _, _, result, _ = _band_parts_matched(creature, "reference")
    assert result.details.overlap_found == {"method": "features", "fallback_from": "reference"}
    assert result.status == "optimal"


def test_the_command_line_reads_the_overlap_on_the_checkpoint_reference(tmp_path, creature):
    """``partial_overlap=reference`` with a network whose checkpoint stores a reference shape: both
    parts are read on it (each placed as a part), and result.json says how the overlap was found."""
    from test_orientation import _checkpoint_with_reference

    lower, upper = _band_cuts(creature)
    _checkpoint_with_reference(tmp_path / "net.pt", creature)
    out = _matched_files(
        tmp_path,
        lower.mesh,
        upper.mesh,
        "partial=both",
        "partial_overlap=reference",
        "features=learned",
        f"checkpoint={tmp_path / 'net.pt'}",
        "resolution=100",
        "solver.time_limit=40",  # an untrained network: the way the overlap was found is the point
    )
    result = json.loads((out / "result.json").read_text())
    found_by = result["overlap"]["found_by"]
    assert found_by["method"] == "reference" and found_by["target_overlap"] == "reference"
    assert 0 < result["overlap"]["source_overlap_vertices"] <= lower.mesh.n_verts
    covered = np.load(out / "dense_map.npz")["target_covered"]
    assert covered.shape == (upper.mesh.n_verts,)
    shared = upper.mesh.vertex_areas[covered].sum() / upper.mesh.area
    assert result["overlap"]["target_covered_area"] == pytest.approx(shared, abs=1e-4)


def test_an_unknown_overlap_method_is_refused_by_name(tmp_path, creature):
    with pytest.raises(ValueError, match="overlap_method='cycle'"):
        spidermatch.match(creature, creature, partial="both", overlap_method="cycle")
    save_mesh(creature, tmp_path / "a.off")
    files = [f"source={tmp_path / 'a.off'}", f"target={tmp_path / 'a.off'}"]
    cfg = composed("match", [*files, "partial=both", "partial_overlap=cycle", "output.png=false"])
    assert run_match(cfg, tmp_path / "run") == 2
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert "partial_overlap='cycle'" in result["error"] and "features, matched" in result["error"]


def test_partial_both_accepts_only_its_three_names(creature):
    with pytest.raises(ValueError, match="'auto', 'off' or 'both'"):
        spidermatch.match(creature, creature, partial="overlap")


def test_the_command_line_matches_two_parts_and_writes_the_source_own_indices(tmp_path, creature):
    lower, upper = _band_cuts(creature)
    out = _matched_files(
        tmp_path,
        lower.mesh,
        upper.mesh,
        "partial=both",
        "resolution=100",
        "dense.inverse=true",
        "solver.time_limit=40",  # WKS on two parts is hard to certify; the files are the point here
    )
    result = json.loads((out / "result.json").read_text())
    assert result["pair"]["mode"] == "overlap" and result["status"] in ("optimal", "feasible")
    n_piece = result["overlap"]["source_overlap_vertices"]
    assert 0 < n_piece < lower.mesh.n_verts and 0 < result["overlap"]["source_overlap_area"] < 1
    assert result["overlap"]["found_by"] == {"method": "features"}
    assert "target_covered_area" in result["overlap"]
    with np.load(out / "dense_map.npz") as dense:
        ids = dense["source_vertex"]
        assert ids.shape == (n_piece,) == dense["vertex"].shape
        assert np.unique(ids).size == n_piece and ids.max() < lower.mesh.n_verts
        assert np.all(np.isin(dense["inverse_vertex"], ids))  # onto the piece, in source indices
        faces = lower.mesh.faces[dense["inverse_face"]]
        assert np.all(np.isin(faces, ids))
    rows = np.loadtxt(out / "dense_matches.csv", delimiter=",", skiprows=1, dtype=np.int64)
    # a row per source vertex, in order, so that reading by position is right; -1 outside the piece
    assert np.array_equal(rows[:, 0], np.arange(lower.mesh.n_verts))
    assert np.array_equal(np.flatnonzero(rows[:, 1] >= 0), np.sort(ids))
    with np.load(out / "dense_map.npz") as dense:
        assert np.array_equal(rows[dense["source_vertex"], 1], dense["vertex"])
    matches = np.loadtxt(out / "matches.csv", delimiter=",", skiprows=1, dtype=np.int64)
    assert np.all(np.isin(matches[:, 0], ids))


class _RecordingExtractor:
    """Features that say which of an extractor's methods the API called (the methods differ in units)."""

    def __init__(self, creature):
        self.calls = []
        self.code = _smooth_position_code(creature.verts)
        self.creature = creature

    def _for(self, mesh):
        nearest = np.argmin(((mesh.verts[:, None] - self.creature.centred().verts[None]) ** 2).sum(2), axis=1)
        return self.code[nearest]

    def __call__(self, mesh):
        self.calls.append("single")
        return self._for(mesh)

    def pair_features(self, x, y):
        self.calls.append("pair_features")
        return self._for(x), self._for(y)

    def part_features(self, part, whole):
        self.calls.append("part_features")
        return self._for(part), self._for(whole)

    def parts_features(self, x, y):
        self.calls.append("parts_features")
        return self._for(x), self._for(y)


@pytest.mark.parametrize(
    ("partial", "expected"), [("auto", "part_features"), ("off", "pair_features"), ("both", "parts_features")]
)
def test_each_partial_mode_asks_the_extractor_for_its_own_features(creature, partial, expected):
    part = plane_cut(creature, np.array([0.0, 1.0, 0.3]), 0.6, "part")
    extractor = _RecordingExtractor(creature)
    settings = spidermatch.MatchSettings(dense=None)
    spidermatch.match(
        part.mesh,
        creature,
        features=extractor,
        resolution=150,
        partial=partial,
        strict=False,
        settings=settings,
    )
    assert extractor.calls == [expected]


def test_an_overlap_of_almost_nothing_is_refused_with_the_source_named(creature):
    from spidermatch.geometry.overlap import overlap_part

    region = np.zeros(creature.n_verts, dtype=bool)
    region[creature.faces[0]] = True  # one triangle: far below the least overlap
    with pytest.raises(MeshError, match=re.escape(f"{creature.name}: no overlap with the target found")):
        overlap_part(creature, region)
    assert overlap_part(creature, np.ones(creature.n_verts, dtype=bool)).kept_area == pytest.approx(1.0)


def test_two_cut_parts_matched_as_wholes_by_default_are_warned_about(creature):
    """Upper and lower halves: one cut loop each, so the default reads them as two whole shapes;
    the reading is kept but said (the cut loops named, partial=both offered), not put down to holes."""
    normal = np.array([0.0, 1.0, 0.0])
    lower = plane_cut(creature, normal, 0.6, "lower.off").mesh
    upper = plane_cut(creature, -normal, 0.6, "upper.off").mesh
    kind = pair_kind(upper, lower)
    assert kind.mode == "whole"
    assert "small holes" not in kind.reason and "cut" in kind.reason
    assert "partial=both" in kind.caution and "upper.off" in kind.caution and "lower.off" in kind.caution
    assert pair_kind(creature, creature).caution == ""  # two closed shapes: nothing to say


def test_wks_on_a_part_is_warned_about_and_named_when_no_matching_is_found(creature, caplog):
    """WKS of a part is not its whole's: said before the solve and in the error of a failed run."""
    from spidermatch.api import WKS_ON_PARTS_HINT
    from spidermatch.model.product_graph import ProductGraph
    from spidermatch.pipeline import MatchResult, NoSolutionError
    from spidermatch.solve.types import SolveResult

    holed = holes_cut(creature, np.array([10]), 0.85, "holed").mesh
    caplog.set_level("WARNING", logger="spidermatch.api")
    spidermatch.match(holed, creature, features="wks", resolution=100, time_limit=30, strict=False)
    assert "WKS is unfit for parts" in caplog.text and "faust_r_unsup_partial" in caplog.text
    caplog.clear()
    spidermatch.match(creature, creature, features="wks", resolution=100, time_limit=30, strict=False)
    assert "WKS is unfit for parts" not in caplog.text  # two whole shapes: WKS is fine

    empty = np.zeros(0, dtype=np.int64)
    graph = ProductGraph(3, 4, np.zeros((0, 2), dtype=np.int64), empty, empty, empty.astype(np.int8))
    stopped = SolveResult("no_solution", None, np.inf, 0.0, np.nan, 60.0, 0, 0, 0, "Time limit reached")
    failed = MatchResult(None, None, None, graph, stopped)
    with pytest.raises(NoSolutionError) as told:
        failed.raise_for_status(WKS_ON_PARTS_HINT)
    assert str(told.value).endswith(WKS_ON_PARTS_HINT) and "raise solver.time_limit" in str(told.value)
    with pytest.raises(NoSolutionError) as plain:
        failed.raise_for_status()
    assert "WKS" not in str(plain.value)


def test_the_overlap_solve_and_the_piece_solve_share_one_time_limit(creature, monkeypatch):
    """partial='both' with the overlap matched: two solves, one ``time_limit`` between them."""
    from spidermatch import overlap_solve

    limits, real_overlap, real_match = {}, overlap_solve.matched_overlap, pipeline.match

    def overlap_recorded(source, target, feat_x, feat_y, settings, *args, **kwargs):
        limits["overlap"] = settings.solver.time_limit
        found = real_overlap(source, target, feat_x, feat_y, settings, *args, **kwargs)
        limits["overlap_solve_s"] = found.summary()["solve_s"]
        return found

    def match_recorded(source, target, feat_x, feat_y, settings, **kwargs):
        limits["piece"] = settings.solver.time_limit
        return real_match(source, target, feat_x, feat_y, settings, **kwargs)

    monkeypatch.setattr(overlap_solve, "matched_overlap", overlap_recorded)
    monkeypatch.setattr(pipeline, "match", match_recorded)
    _, _, result, _ = _band_parts_matched(creature, "matched", resolution=100, time_limit=300)
    assert result.details.overlap_found["method"] == "matched"
    assert limits["overlap"] == 300 * pipeline.OVERLAP_SOLVE_SHARE
    assert limits["piece"] == pytest.approx(300 - limits["overlap_solve_s"]) and limits["piece"] < 300


def test_the_command_line_gives_the_piece_what_the_overlap_solve_left(tmp_path, creature, monkeypatch):
    import spidermatch.cli.inputs as cli_inputs
    import spidermatch.cli.match as cli_match

    given, real_overlap_inputs, real_match = [], cli_inputs.overlap_inputs, cli_match.match

    def overlap_took_12_5_s(inputs, feat_x, feat_y, report, method, settings, reference):
        cut = real_overlap_inputs(inputs, feat_x, feat_y, report, method, settings, reference)
        report["overlap"]["found_by"]["solve_s"] = 12.5  # as a matched overlap's record says
        return cut

    def match_recorded(source, target, feat_x, feat_y, settings, **kwargs):
        given.append(settings.solver.time_limit)
        return real_match(source, target, feat_x, feat_y, settings, **kwargs)

    monkeypatch.setattr(cli_inputs, "overlap_inputs", overlap_took_12_5_s)
    monkeypatch.setattr(cli_match, "match", match_recorded)
    lower, upper = _band_cuts(creature)
    # a limit well above the piece's need, so that a busy machine still finds its map in what is left
    _matched_files(
        tmp_path, lower.mesh, upper.mesh, "partial=both", "resolution=100", "solver.time_limit=120"
    )
    assert given == [pytest.approx(107.5)]


def test_later_solves_get_what_the_earlier_left_of_the_limit_and_no_limit_stays_none():
    settings = pipeline.MatchSettings(solver=pipeline.SolverOptions(time_limit=100.0))
    assert pipeline.solver_time_left(settings, 30.0).solver.time_limit == 70.0
    assert pipeline.solver_time_left(settings, 130.0).solver.time_limit == 0.0  # never negative
    assert pipeline.overlap_solve_settings(settings).solver.time_limit == 100.0 * pipeline.OVERLAP_SOLVE_SHARE
    unlimited = pipeline.MatchSettings(solver=pipeline.SolverOptions(time_limit=float("inf")))
    assert pipeline.solver_time_left(unlimited, 1e6).solver.time_limit == float("inf")
    assert pipeline.overlap_solve_settings(unlimited).solver.time_limit == float("inf")
