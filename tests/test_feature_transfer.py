"""Features of large meshes: computed on a capped copy and carried to every vertex."""

import numpy as np
import pytest
from conftest import composed

from spidermatch.data.synthetic import make_creature
from spidermatch.feature_transfer import capped_mesh, carry_features, mesh_features, pair_features
from spidermatch.geometry.descriptors import WKSExtractor
from spidermatch.geometry.remesh import decimate
from spidermatch.validate import OptionError, check_options


class SizeRecorder:
    """An extractor whose features are the (centred) coordinates, recording the sizes it saw."""

    name = "coordinates"

    def __init__(self) -> None:
        self.sizes = []

    def __call__(self, mesh):
        self.sizes.append(mesh.n_verts)
        return np.asarray(mesh.verts) + 10.0  # positive rows: unit rows stay informative


@pytest.fixture(scope="module")
def creature():
    return make_creature(3000, seed=3).mesh.centred()


def test_a_mesh_within_the_cap_is_computed_as_it_is(creature):
    recorder = SizeRecorder()
    features = mesh_features(recorder, creature, max_vertices=creature.n_verts)
    assert recorder.sizes == [creature.n_verts]
    np.testing.assert_allclose(features, creature.verts + 10.0)
    assert capped_mesh(creature, None) is None and capped_mesh(creature, 0) is None


def test_a_larger_mesh_is_computed_on_a_copy_within_the_cap_and_carried_to_every_vertex(creature):
    recorder = SizeRecorder()
    cap = creature.n_verts // 3
    features = mesh_features(recorder, creature, max_vertices=cap)
    assert len(recorder.sizes) == 1 and recorder.sizes[0] <= cap + 10
    assert features.shape == (creature.n_verts, 3)
    np.testing.assert_allclose(np.linalg.norm(features, axis=1), 1.0)
    exact = (creature.verts + 10.0) / np.linalg.norm(creature.verts + 10.0, axis=1, keepdims=True)
    # the carried field is the full one up to a fraction of the copy's edge length
    angle = np.arccos(np.clip(np.sum(features * exact, axis=1), -1, 1))
    assert np.percentile(angle, 95) < 2e-3


def test_carrying_keeps_a_surviving_vertex_row_and_bounds_memory_blockwise(creature, monkeypatch):
    import spidermatch.feature_transfer as transfer

    low = decimate(creature, creature.n_faces // 4)
    rng = np.random.default_rng(0)
    rows = rng.normal(size=(low.mesh.n_verts, 8))
    whole = carry_features(rows, low.mesh, creature)
    monkeypatch.setattr(transfer, "CARRY_BLOCK", 97)  # many blocks: the same result
    np.testing.assert_allclose(carry_features(rows, low.mesh, creature), whole)
    same = np.linalg.norm(creature.verts[low.to_full] - low.mesh.verts, axis=1) < 1e-12
    assert same.any()
    kept = rows[same] / np.linalg.norm(rows[same], axis=1, keepdims=True)
    np.testing.assert_allclose(whole[low.to_full[same]], kept, atol=1e-9)


def test_pair_features_pass_both_capped_meshes_to_an_adaptive_extractor(creature):
    seen = []

    class Adaptive:
        name = "adaptive"

        def __call__(self, mesh):  # pragma: no cover - pair_features must be used
            raise AssertionError("the pair method must be called")

        def pair_features(self, mesh_x, mesh_y):
            seen.append((mesh_x.n_verts, mesh_y.n_verts, mesh_x.name))
            return mesh_x.verts + 10.0, mesh_y.verts + 10.0

    small = make_creature(800, seed=4).mesh
    feat_x, feat_y = pair_features(Adaptive(), creature, small, max_vertices=1000)
    assert seen[0][0] <= 1010 and seen[0][1] == small.n_verts
    assert seen[0][2] == creature.name  # messages name the user's mesh, not the copy
    assert feat_x.shape == (creature.n_verts, 3) and feat_y.shape == (small.n_verts, 3)


def test_wks_of_a_capped_mesh_is_close_to_the_full_one():
    mesh = make_creature(4000, seed=5).mesh
    full = WKSExtractor(n_descr=32, n_eig=40, use_cache=False)(mesh.centred())
    capped = mesh_features(WKSExtractor(n_descr=32, n_eig=40, use_cache=False), mesh, max_vertices=2000)
    cosine = np.sum(full * capped, axis=1)
    assert np.median(cosine) > 0.99


@pytest.mark.parametrize("value", [100, 2.5, -1, "many"])
def test_a_bad_cap_is_named(value):
    cfg = composed("match", [f"features_max_vertices={value}"])
    with pytest.raises(OptionError, match="features_max_vertices="):
        check_options(cfg)


def test_the_api_matches_with_capped_features_and_names_a_bad_cap():
    from spidermatch import api

    source, target = make_creature(1500, seed=1).mesh, make_creature(1500, seed=2).mesh
    matching = api.match(source, target, resolution=60, features_max_vertices=600)
    assert matching.status == "optimal" and matching.dense_map.shape == (source.n_verts,)
    with pytest.raises(OptionError, match="^bad option: features_max_vertices=10:"):
        api.match(source, target, resolution=60, features_max_vertices=10)


def test_a_run_on_meshes_above_the_cap_says_so_in_result_json(tmp_path):
    from tests.test_bad_inputs import creature as bad_input_creature
    from tests.test_bad_inputs import files_pair, result_of, run_files

    pair = files_pair(tmp_path, bad_input_creature(0, 900), bad_input_creature(1, 900))
    code, folder = run_files(tmp_path, pair, "features_max_vertices=600")
    report = result_of(folder)
    assert code == 0 and report["status"] == "optimal"
    capped = report["feature_inputs"]["computed_on_vertices"]
    assert sorted(capped) == sorted([str(tmp_path / "source.off"), str(tmp_path / "target.off")])
    assert all(500 <= count <= 610 for count in capped.values())
