import dataclasses
import re
import shutil
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import trimesh

import spidermatch
from spidermatch import api
from spidermatch.data.datasets import SyntheticShapes
from spidermatch.dense.densify import certified_agreement
from spidermatch.eval.errors import sparse_map_errors
from spidermatch.geometry.descriptors import WKSExtractor
from spidermatch.geometry.io import load_mesh, save_mesh
from spidermatch.geometry.mesh import MeshError

README = Path(__file__).resolve().parents[1] / "README.md"
RESOLUTION = 60


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """Two synthetic creatures with different vertex counts (~700, ~900), as files and shapes."""
    folder = tmp_path_factory.mktemp("api_pair")
    small, large = (
        SyntheticShapes(n_shapes=1, n_verts=700, seed=0),
        SyntheticShapes(n_shapes=1, n_verts=900, seed=1),
    )
    x, y = small.load(small.names[0]), large.load(large.names[0])
    save_mesh(x.mesh, folder / "source.off")
    save_mesh(y.mesh, folder / "target.off")
    return types.SimpleNamespace(x=x, y=y, source=folder / "source.off", target=folder / "target.off")


@pytest.fixture(scope="module")
def from_paths(pair):
    return spidermatch.match(str(pair.source), pair.target, resolution=RESOLUTION)


def error_of(matches, source, target) -> float:
    return sparse_map_errors(
        matches[:, 0], matches[:, 1], source.mesh, source.corr, target.corr, target.mesh
    ).mean


def test_result_fields_and_direction(pair, from_paths):
    result = from_paths
    assert result.status == "optimal" and result.proven_optimal
    # HiGHS stops at its tolerance, up to rounding
    assert result.bound <= result.objective + 1e-9 and 0 <= result.gap <= 1e-4 * (1 + 1e-9)
    n_low = result.details.source.mesh.n_verts
    assert result.matches.dtype == np.int64 and result.matches.shape == (n_low, 2)
    # column 0 indexes the source (~700 vertices), column 1 the target (~900 vertices)
    assert np.unique(result.matches[:, 0]).size == len(result.matches)
    assert result.matches[:, 0].max() < pair.x.mesh.n_verts
    assert result.matches[:, 1].max() < pair.y.mesh.n_verts
    assert error_of(result.matches, pair.x, pair.y) < 0.3  # read the other way round it would be ~random
    assert result.resolution == RESOLUTION and result.features == "wks"
    assert {"features", "decimate", "solve", "check"} <= set(result.timings)
    # the dense map: a target vertex for every full-resolution source vertex, near the certified ones
    assert result.dense_map.dtype == np.int64 and result.dense_map.shape == (pair.x.mesh.n_verts,)
    assert result.p2p is result.dense_map and result.dense.vertex.shape == result.dense_map.shape
    assert result.dense_map.max() < pair.y.mesh.n_verts
    details = result.details
    low = (details.source, details.target, details.low_map)
    agreement = certified_agreement(result.dense, pair.y.mesh, *low)
    assert agreement["within_one_edge"] > 0.5


def test_reversed_pair_swaps_the_roles(pair):
    result = spidermatch.match(pair.target, pair.source, resolution=RESOLUTION)
    assert result.matches[:, 0].max() < pair.y.mesh.n_verts
    assert result.matches[:, 1].max() < pair.x.mesh.n_verts
    assert error_of(result.matches, pair.y, pair.x) < 0.3


def test_trimesh_arrays_and_precomputed_features_give_the_same_matching(pair, from_paths):
    loaded = trimesh.load(pair.source, process=False)
    arrays = (pair.y.mesh.verts, pair.y.mesh.faces)
    assert np.array_equal(
        spidermatch.match(loaded, arrays, resolution=RESOLUTION).matches, from_paths.matches
    )
    # the meshes as read back from the files (an OFF file rounds the coordinates, and decimation
    # can tell: the in-memory shapes may give another low-resolution pair)
    source, target = load_mesh(pair.source), load_mesh(pair.target)
    wks = WKSExtractor()
    features = (wks(source.centred()), wks(target.centred()))
    result = spidermatch.match(source, target, features=features, resolution=RESOLUTION)
    assert result.features == "precomputed" and result.objective == pytest.approx(
        from_paths.objective, rel=1e-6
    )
    assert np.array_equal(result.matches, from_paths.matches)


def test_bad_inputs_are_clear_errors(pair, tmp_path):
    with pytest.raises(MeshError, match="nope.off: no such file"):
        spidermatch.match(tmp_path / "nope.off", pair.target)
    faces = np.array([[0, 1, 2], [0, 2, 7]])
    with pytest.raises(MeshError, match=r"target mesh \(V, F\) arrays"):
        spidermatch.match(pair.source, (np.eye(3), faces))
    with pytest.raises(TypeError, match="source: expected a mesh file path"):
        spidermatch.match(42, pair.target)
    mesh = pair.y.mesh  # a Mesh built by its constructor is checked as a file is, not trusted
    island = np.array([[0, 1, 2]]) + mesh.n_verts
    two_pieces = spidermatch.Mesh(
        np.vstack([mesh.verts, mesh.verts[:3] + 10.0]), np.vstack([mesh.faces, island]), "two pieces"
    )
    with pytest.raises(MeshError, match="two pieces: the mesh has 2 connected components.*repair=true"):
        spidermatch.match(pair.source, two_pieces)
    with pytest.raises(ValueError, match="LearnedExtractor"):
        spidermatch.match(pair.source, pair.target, features="learned")
    n_x, n_y = pair.x.mesh.n_verts, pair.y.mesh.n_verts
    with pytest.raises(ValueError, match=rf"source features must have shape \({n_x}, D\)"):
        spidermatch.match(pair.source, pair.target, features=(np.ones((5, 3)), np.ones((n_y, 3))))
    varied = np.random.default_rng(0).normal(size=(n_x, 3))  # constant features (a broken network's
    with pytest.raises(ValueError, match="target features of .* are the same at every vertex"):  # zeros)
        spidermatch.match(pair.source, pair.target, features=(varied, np.zeros((n_y, 3))))


@pytest.mark.parametrize("columns", [4, 2])
def test_faces_that_are_not_triangles_are_a_clear_error(pair, columns):
    """Quads (or pairs) as a face array crashed in the weld's numbering (a numpy ValueError)."""
    mesh = pair.x.mesh
    faces = mesh.faces[:, [0, 1, 2, 0][:columns]]
    verts = np.vstack([mesh.verts, mesh.verts[:1]])  # a repeated position: the weld is tried first
    with pytest.raises(
        MeshError, match=rf"faces must be triangles with shape \(F, 3\), got \({mesh.n_faces}, {columns}\)"
    ):
        spidermatch.match((verts, faces), pair.target)


def test_half_precision_coordinates_are_read_as_the_shape_they_are(pair, from_paths):
    """float16 vertices were refused as thousands of "degenerate faces" (areas rounded to 0 in float16)."""
    x, y = pair.x.mesh, pair.y.mesh  # in hundredths of their unit: areas below float16's range
    small = spidermatch.match(
        ((x.verts / 100).astype(np.float16), x.faces),
        ((y.verts / 100).astype(np.float16), y.faces),
        resolution=RESOLUTION,
    )
    assert small.status == from_paths.status and small.matches.shape == from_paths.matches.shape


def test_dense_map_is_exposed_when_the_pipeline_has_one(from_paths):
    details = from_paths.details
    dense = np.arange(details.source.to_full.max() + 1)[::-1]
    with_dense = types.SimpleNamespace(
        solve=details.solve,
        low_map=details.low_map,
        check=details.check,
        full_pairs=details.full_pairs,
        dense=None,
    )
    with_dense.dense_map = dense
    matching = api._matching(with_dense, "wks", RESOLUTION, {})
    assert np.array_equal(matching.dense_map, dense) and matching.p2p is matching.dense_map


def test_defaults_agree_with_the_command_line_config():
    from hydra import compose, initialize_config_module

    def composed(*overrides):
        with initialize_config_module(config_module="conf", version_base="1.3"):
            return compose(
                config_name="match", overrides=["source=a.off", "target=b.off", "data=files", *overrides]
            )

    assert composed().resolution == api.default_resolution("wks") == api.WKS_RESOLUTION
    assert composed("features=learned").resolution == api.default_resolution("learned")
    assert composed().solver.time_limit == api.DEFAULT_TIME_LIMIT
    assert composed().features_max_vertices == api.MAX_FEATURE_VERTICES


def test_match_settings_defaults_are_the_command_line_defaults():
    """One source of defaults: MatchSettings() is what spidermatch-match runs with learned features."""
    from hydra import compose, initialize_config_module

    from spidermatch.pipeline import MatchSettings

    with initialize_config_module(config_module="conf", version_base="1.3"):
        cfg = compose(
            config_name="match", overrides=["source=a.off", "target=b.off", "data=files", "features=learned"]
        )
    settings = MatchSettings()
    solver = dataclasses.asdict(settings.solver)
    assert {key: solver[key] for key in ("time_limit", "mip_rel_gap", "threads", "presolve", "log")} == {
        key: cfg.solver[key] for key in ("time_limit", "mip_rel_gap", "threads", "presolve", "log")
    }
    assert (settings.strategy, settings.isolate_solver) == (cfg.solver.strategy, cfg.solver.isolate)
    assert settings.resolution == cfg.resolution
    assert dataclasses.asdict(settings.dense) == {k: v for k, v in cfg.dense.items() if k != "enabled"}
    assert dataclasses.asdict(settings.loss) == {k: cfg.costs[k] for k in ("alpha", "scale", "bowl_exponent")}
    assert (settings.target_augmented, list(settings.constraints)) == (
        cfg.costs.target_augmented,
        list(cfg.costs.constraints),
    )
    curve = (settings.curve_augmented, settings.curve_seed, settings.decimation, settings.curve_matching)
    assert curve == (cfg.curve.augmented, cfg.curve.seed, cfg.curve.decimation, cfg.curve.matching)


def test_import_spidermatch_loads_neither_torch_nor_features():
    code = (
        "import sys, spidermatch; from spidermatch import match; "
        "import spidermatch.api, spidermatch.pipeline, spidermatch.geometry.descriptors; "
        "import spidermatch.cli.main; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'features', 'train')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def readme_python_blocks() -> list[str]:
    text = README.read_text()
    section = text[text.index("## Python API") :]
    section = section[: section.index("\n## ", 1)]
    return re.findall(r"```python\n(.*?)```", section, flags=re.S)


def test_readme_python_example_runs(pair, tiny_checkpoint, tmp_path, monkeypatch):
    blocks = readme_python_blocks()
    assert len(blocks) >= 2 and "spidermatch.match(" in blocks[0]
    for name in ("source.off", "target.off"):
        shutil.copy(getattr(pair, name.split(".")[0]), tmp_path / name)
    shutil.copy(tiny_checkpoint, tmp_path / "best.pt")
    monkeypatch.chdir(tmp_path)
    # the README's defaults are for FAUST-sized meshes; these small ones are matched at RESOLUTION faces
    monkeypatch.setattr(api, "WKS_RESOLUTION", RESOLUTION)
    monkeypatch.setattr(api, "LEARNED_RESOLUTION", RESOLUTION)
    for block in blocks:
        namespace: dict = {}
        exec(compile(block, str(README), "exec"), namespace)
        assert namespace["result"].matches.shape[1] == 2


def test_settings_defaults_and_precedence():
    from spidermatch.pipeline import MatchSettings

    wks = api._settings(None, "wks", None, None, None, None)
    assert (wks.resolution, wks.solver.time_limit) == (api.WKS_RESOLUTION, api.DEFAULT_TIME_LIMIT)
    assert api._settings(None, "learned", None, None, None, None).resolution == api.LEARNED_RESOLUTION
    given = api._settings(MatchSettings(resolution=77), "wks", None, None, None, "plain")
    assert (given.resolution, given.strategy) == (77, "plain")
    assert given.solver.time_limit == api.DEFAULT_TIME_LIMIT
    assert wks.strategy == "rcfix"  # "auto": WKS's weak LP keeps rcfix
    assert api._settings(None, "learned", None, None, None, None).strategy == "colgen"
    assert api._settings(None, "learned", None, None, None, "auto").strategy == "colgen"
    assert api._settings(None, "wks", None, None, None, "colgen").strategy == "colgen"
    overridden = api._settings(MatchSettings(resolution=77), "wks", 90, 12.0, 1e-3, None)
    solver = overridden.solver
    assert (overridden.resolution, solver.time_limit, solver.mip_rel_gap) == (90, 12.0, 1e-3)


def test_colgen_strategy_gives_rcfix_objective_through_the_api(pair, from_paths):
    lazy = spidermatch.match(str(pair.source), pair.target, resolution=RESOLUTION, strategy="colgen")
    assert lazy.status == "optimal" and lazy.proven_optimal
    assert lazy.objective == pytest.approx(from_paths.objective, rel=2e-4)  # both within the 1e-4 gap
    assert lazy.bound <= from_paths.objective * (1 + 1e-4) + 1e-12


def test_save_pictures_draws_the_dense_map_with_its_errors(pair, from_paths, tmp_path):
    from spidermatch.eval.errors import dense_map_errors

    written = from_paths.save_pictures(tmp_path / "pictures", pair.x.corr, pair.y.corr)
    names = {path.name for path in written}
    assert names == {"correspondence.png", "spider_curve.png", "texture.png", "error.png", "viewer.html"}
    assert all(path.stat().st_size > 1000 for path in written)
    # the viewer's error layer is the dense map's error against the ground truth
    expected = dense_map_errors(from_paths.dense_map, pair.x.corr, pair.y.corr, pair.y.mesh).mean
    assert f"mean {expected:.4f}" in (tmp_path / "pictures" / "viewer.html").read_text()
    with pytest.raises(ValueError, match="both"):
        from_paths.save_pictures(tmp_path / "other", source_corr=pair.x.corr)


def test_save_pictures_refuses_ground_truth_of_meshes_changed_before_matching(pair, tmp_path):
    mesh = pair.x.mesh
    soup = (mesh.verts[mesh.faces].reshape(-1, 3), np.arange(3 * mesh.n_faces).reshape(-1, 3))
    welded = spidermatch.match(soup, pair.target, resolution=RESOLUTION)
    assert not welded.as_given and welded.matched_meshes[0].n_verts == mesh.n_verts
    with pytest.raises(ValueError, match="welded, repaired or cut"):
        welded.save_pictures(tmp_path, pair.x.corr, pair.y.corr)
    assert {path.name for path in welded.save_pictures(tmp_path, viewer=False)} >= {"correspondence.png"}


def test_a_trimesh_scene_is_matched_as_its_mesh_and_a_point_cloud_is_refused(pair, from_paths):
    """``trimesh.load`` gives a Scene for GLB files and OBJ files with materials."""
    source = trimesh.load(pair.source, process=False)
    scene = trimesh.Scene(source)
    result = spidermatch.match(scene, pair.target, resolution=RESOLUTION)
    assert np.array_equal(result.matches, from_paths.matches)
    with pytest.raises(MeshError, match=f"a point cloud of {len(source.vertices)} points"):
        spidermatch.match(trimesh.PointCloud(source.vertices), pair.target)
