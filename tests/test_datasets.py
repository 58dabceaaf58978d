import numpy as np
import pytest

from spidermatch.data.datasets import DatasetError, ShapeFolder, SyntheticShapes, open_dataset, write_dataset
from spidermatch.data.synthetic import creature_pair_ground_truth, make_creature
from spidermatch.eval.errors import cumulative_curve, dense_map_errors, sparse_map_errors
from spidermatch.geometry.io import save_mesh, write_vts
from spidermatch.geometry.mesh import Mesh, MeshError
from spidermatch.geometry.remesh import decimate, nearest_vertices, surface_nearest_vertices


def test_synthetic_shapes_are_seeded_and_meshed_independently():
    a, a_again, b = make_creature(2000, 0), make_creature(2000, 0), make_creature(2000, 1)
    np.testing.assert_array_equal(a.mesh.verts, a_again.mesh.verts)
    assert a.mesh.n_verts != b.mesh.n_verts or not np.array_equal(a.mesh.faces, b.mesh.faces)
    # ground truth: corresponding points lie at the same place of the rest shape's parameter sphere
    gt = creature_pair_ground_truth(a, b)
    assert np.mean(np.linalg.norm(a.params - b.params[gt], axis=1)) < 0.05


def test_synthetic_ground_truth_is_consistent_between_shapes():
    shapes = SyntheticShapes(n_shapes=3, n_verts=1500)
    x, y = shapes.load("creature_000"), shapes.load("creature_001")
    assert x.corr.shape == y.corr.shape == (1000,)
    # the true map composed with itself is (nearly) the identity at the reference points
    evaluation = dense_map_errors(np.arange(x.mesh.n_verts), x.corr, x.corr, x.mesh)
    assert evaluation.mean == 0.0
    assert len(shapes.pairs()) == 6


def test_write_and_read_folder_round_trip(tmp_path):
    shapes = SyntheticShapes(n_shapes=2, n_verts=600)
    write_dataset(shapes, tmp_path)
    folder = open_dataset(tmp_path)
    assert isinstance(folder, ShapeFolder) and folder.names == shapes.names
    loaded, original = folder.load("creature_001"), shapes.load("creature_001")
    np.testing.assert_allclose(loaded.mesh.verts, original.mesh.verts, atol=1e-6)
    np.testing.assert_array_equal(loaded.corr, original.corr)
    pairs_file = tmp_path / "pairs.txt"
    pairs_file.write_text("# pairs\ncreature_000 creature_001\ncreature_001,creature_000\n")
    assert folder.pairs(pairs_file) == [("creature_000", "creature_001"), ("creature_001", "creature_000")]
    pairs_file.write_text("creature_000.off creature_001.OFF\n")  # file names as a user lists them
    assert folder.pairs(pairs_file) == [("creature_000", "creature_001")]
    pairs_file.write_text("creature_000 nobody\n")
    with pytest.raises(DatasetError, match="pairs.txt:1: unknown shape 'nobody'"):
        folder.pairs(pairs_file)
    pairs_file.write_text("creature_000 nobody.off\n")
    with pytest.raises(DatasetError, match="pairs.txt:1: unknown shape 'nobody.off'"):
        folder.pairs(pairs_file)
    flat = ShapeFolder(tmp_path / "off")  # the meshes may also lie in the folder itself
    assert flat.names == shapes.names and flat.load("creature_000").corr is None
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="empty: no mesh files"):
        ShapeFolder(tmp_path / "empty")
    with pytest.raises(DatasetError, match="nowhere: no such folder"):
        ShapeFolder(tmp_path / "nowhere")
    save_mesh(shapes.load("creature_000").mesh, tmp_path / "off" / "creature_000.ply")
    with pytest.raises(DatasetError, match=r"creature_000\.(off|ply): two meshes are called"):
        ShapeFolder(tmp_path)


def test_identity_map_has_zero_error_and_curve_is_cumulative(rng):
    mesh = make_creature(1000, 2).mesh
    corr = rng.choice(mesh.n_verts, 200, replace=False)
    assert dense_map_errors(np.arange(mesh.n_verts), corr, corr, mesh).mean == 0.0
    shuffled = rng.permutation(mesh.n_verts)
    evaluation = dense_map_errors(shuffled, corr, corr, mesh)
    assert evaluation.mean > 0.1
    thresholds, curve = evaluation.curve()
    assert curve[0] >= 0 and curve[-1] <= 1 and np.all(np.diff(curve) >= 0)
    np.testing.assert_allclose(
        cumulative_curve(np.array([0.0, 0.1, 0.3]), np.array([0.0, 0.1, 0.25])), [1 / 3, 2 / 3, 2 / 3]
    )


def test_sparse_map_uses_nearest_reference_point():
    mesh = make_creature(1000, 3).mesh
    low = decimate(mesh, 200)
    corr = np.arange(mesh.n_verts)
    evaluation = sparse_map_errors(low.to_full, low.to_full, mesh, corr, corr, mesh)
    assert evaluation.mean == 0.0 and evaluation.n_approximated == 0
    partial = corr[::2]
    evaluation = sparse_map_errors(low.to_full, low.to_full, mesh, partial, partial, mesh)
    assert evaluation.mean < 0.05


def test_decimation_hits_face_count_and_maps_to_nearest_vertex():
    mesh = make_creature(2000, 4).mesh  # no two parts touch: the vertex on its own part is the nearest
    for faces in (100, 500):
        low = decimate(mesh, faces)
        assert low.mesh.n_faces == faces
        assert low.to_full.shape == (low.mesh.n_verts,)
        distance = np.linalg.norm(mesh.verts[low.to_full] - low.mesh.verts, axis=1)
        all_distances = np.linalg.norm(low.mesh.verts[:, None] - mesh.verts[None], axis=2)
        np.testing.assert_allclose(distance, all_distances.min(axis=1))
    same = decimate(mesh, 10**6)
    assert same.mesh is mesh and np.array_equal(same.to_full, np.arange(mesh.n_verts))


def test_a_vertex_near_a_touching_part_is_mapped_to_its_own_part():
    from tests.test_metrics import hairpin_strip

    strip, index = hairpin_strip(radius=0.01)  # two arms 0.02 apart in space, about 2 apart along the strip
    rows = index.shape[0]
    first_arm, second_arm = index[: rows // 3].ravel(), index[-rows // 3 :].ravel()
    births = first_arm[::7]
    points = strip.verts[births] + np.array([0.003, 0.014, 0.0])  # nearer the second arm than the first
    assert np.isin(nearest_vertices(strip.verts, points), second_arm).all()
    reach = np.full(len(points), 0.05)
    chosen = surface_nearest_vertices(strip, points, births, reach)
    assert np.isin(chosen, first_arm).all()
    on_first_arm = strip.verts[first_arm]
    nearest_on_first = np.linalg.norm(points[:, None] - on_first_arm[None], axis=2).min(axis=1)
    np.testing.assert_allclose(np.linalg.norm(strip.verts[chosen] - points, axis=1), nearest_on_first)


def test_a_dataset_folder_welds_an_stl_soup_and_tells_its_ground_truth_on_the_welded_mesh(tmp_path):
    import trimesh

    creature = make_creature(n_verts=500, seed=2).mesh
    (tmp_path / "off").mkdir()
    (tmp_path / "corres").mkdir()
    trimesh.Trimesh(creature.verts, creature.faces, process=False).export(tmp_path / "off" / "scan.stl")
    corners = creature.faces.reshape(-1)
    truth = np.arange(0, creature.n_verts, 9)
    first_corner = np.full(creature.n_verts, -1)
    first_corner[corners[::-1]] = np.arange(corners.size)[::-1]
    np.savetxt(tmp_path / "corres" / "scan.vts", first_corner[truth] + 1, fmt="%d")  # the file's corners
    shape = ShapeFolder(tmp_path).load("scan")
    assert shape.weld is not None and shape.mesh.n_verts == creature.n_verts
    np.testing.assert_array_equal(shape.mesh.verts[shape.corr], creature.verts[truth].astype(np.float32))


def _raw_scan_folder(tmp_path):
    """A folder of three shapes: one clean, one with floating debris, one with stray vertices (with truth)."""
    import trimesh

    creature = make_creature(n_verts=500, seed=2).mesh
    debris = trimesh.creation.icosphere(subdivisions=1, radius=0.05)
    with_debris = (
        np.vstack([debris.vertices + creature.verts.max(axis=0) + 0.5, creature.verts]),  # debris first
        np.vstack([debris.faces, creature.faces + len(debris.vertices)]),
    )
    stray = (np.vstack([creature.verts, creature.verts[:3] + 0.01]), creature.faces)
    truth = np.arange(0, creature.n_verts, 9)
    for name, (verts, faces), shift in (
        ("a_clean", (creature.verts, creature.faces), 0),
        ("b_debris", with_debris, len(debris.vertices)),
        ("c_stray", stray, 0),
    ):
        save_mesh(Mesh(verts, faces), tmp_path / "off" / f"{name}.off")
        write_vts(truth + shift, tmp_path / "corres" / f"{name}.vts")
    return creature, truth


def test_a_folder_of_raw_scans_names_every_bad_shape_with_what_the_repair_would_use(tmp_path):
    _raw_scan_folder(tmp_path)
    folder = ShapeFolder(tmp_path, repair_option="data.repair=true")
    problems = folder.unusable(folder.names)
    assert len(problems) == 2 and "b_debris.off" in problems[0] and "c_stray.off" in problems[1]
    assert all("data.repair=true would use its largest clean piece" in problem for problem in problems)
    with pytest.raises(MeshError, match="2 connected components"):
        ShapeFolder(tmp_path).load("b_debris")  # no option named where none can be set


def test_a_repaired_shape_keeps_its_ground_truth_on_the_piece(tmp_path, caplog):
    creature, truth = _raw_scan_folder(tmp_path)
    folder = ShapeFolder(tmp_path, repair=True, repair_option="data.repair=true")
    assert folder.unusable(folder.names) == []
    folder.load("b_debris")  # checked, then loaded: its repair is told once
    told = [record.message for record in caplog.records if "data.repair=true uses" in record.message]
    assert len(told) == 2 and "b_debris.off" in told[0] and "c_stray.off" in told[1]
    for name in folder.names:
        shape = folder.load(name)
        assert shape.mesh.n_verts == creature.n_verts
        np.testing.assert_allclose(shape.mesh.verts[shape.corr], creature.verts[truth], atol=1e-8)


def test_training_refuses_a_folder_naming_all_its_bad_shapes_before_preparing_any(tmp_path):
    from train.loop import refuse_unusable_shapes

    _raw_scan_folder(tmp_path)
    folder = open_dataset(tmp_path, repair_option="data.repair=true")
    listing = r"2 of 3 shapes cannot be used:\n  .*b_debris.off.*\n  .*c_stray.off"
    with pytest.raises(DatasetError, match=listing):
        refuse_unusable_shapes(folder, folder.names)
    refuse_unusable_shapes(open_dataset(tmp_path, repair=True), folder.names)  # all usable


def test_a_reference_point_the_repair_left_out_moves_to_the_nearest_vertex_kept():
    from spidermatch.data.datasets import kept_reference_vertices

    creature = make_creature(n_verts=500, seed=2).mesh
    stray = Mesh(np.vstack([creature.verts, creature.verts[7] + 1e-3]), creature.faces, "stray.off")
    kept = np.arange(creature.n_verts)  # the repair's piece leaves the stray vertex out
    moved = kept_reference_vertices(stray, kept, np.array([3, creature.n_verts, 11]))
    np.testing.assert_array_equal(moved, [3, 7, 11])
