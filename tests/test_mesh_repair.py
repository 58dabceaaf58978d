"""repair=true: a raw scan's largest clean piece is matched; every output names the file's own vertices."""

import numpy as np
import pytest
from conftest import composed, result_of

import spidermatch
from spidermatch.api import mesh_of
from spidermatch.cli.match import run_match
from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.descriptors import WKSExtractor
from spidermatch.geometry.io import save_mesh
from spidermatch.geometry.mesh import Mesh, MeshError, make_mesh
from spidermatch.geometry.partial import mean_edge_length
from spidermatch.geometry.repair import largest_clean_piece


@pytest.fixture(scope="module")
def creature() -> Mesh:
    return make_creature(n_verts=700, seed=5).mesh


def raw_scan(whole: Mesh, fin: bool = False) -> tuple[Mesh, np.ndarray]:
    """``whole`` as a raw scan: a lone triangle touching vertex 0 (a bow-tie), a two-triangle island,
    a stray vertex and a degenerate face (and, with ``fin``, a third face on one edge).

    Returns the raw mesh and the number of vertices of ``whole`` (they come first, in order).
    """
    n = whole.n_verts
    size = np.ptp(whole.verts, axis=0).max()
    normal_out = whole.verts[0] - whole.verts.mean(axis=0)
    normal_out /= np.linalg.norm(normal_out)
    side = np.cross(normal_out, [0.0, 0.0, 1.0]) + 1e-3
    side /= np.linalg.norm(side)
    # larger than the body's own faces at vertex 0: the body's fan must stay all the same
    lone = [whole.verts[0] + 0.3 * size * normal_out, whole.verts[0] + 0.3 * size * (normal_out + side)]
    corners = np.array([[0.5, 0, 0], [0.6, 0, 0], [0.5, 0.1, 0], [0.6, 0.1, 0.05]])
    island = whole.verts.max(axis=0) + size * corners
    stray = whole.verts.max(axis=0) + size
    verts = np.vstack([whole.verts, lone, island, stray])
    faces = [
        *whole.faces,
        [0, n, n + 1],  # the bow-tie at vertex 0
        [n + 2, n + 3, n + 4],  # the island
        [n + 3, n + 5, n + 4],
        [1, 1, 2],  # degenerate (a repeated vertex)
    ]
    if fin:
        a, b = whole.faces[0][:2]
        faces.append([a, b, n + 6])  # a third face on the edge (a, b)
    return Mesh(verts, np.asarray(faces), "raw_scan.off"), n


def test_the_largest_clean_piece_of_a_raw_scan_is_its_body_and_passes_the_checks(creature):
    raw, n = raw_scan(creature)
    with pytest.raises(MeshError, match="degenerate"):  # the loader names the first problem
        make_mesh(raw.verts, raw.faces, raw.name)
    repaired = largest_clean_piece(raw)
    piece = repaired.piece
    make_mesh(piece.mesh.verts, piece.mesh.faces, "piece")  # raises if anything is left
    assert np.array_equal(piece.to_original, np.arange(n))  # the body, every vertex, in order
    assert np.array_equal(piece.mesh.verts, raw.verts[:n])
    assert np.array_equal(np.sort(raw.faces[repaired.face_ids], axis=1), np.sort(piece.mesh.faces, axis=1))
    assert piece.mesh.n_faces == creature.n_faces  # the body's fan at the bow-tie is kept, the lone one not
    assert "degenerate 1" in repaired.summary and "vertices left out: 7" in repaired.summary
    assert repaired.n_original == raw.n_verts
    assert 0.9 < piece.kept_area < 1.0


def test_a_fin_on_an_edge_is_dropped_with_the_faces_on_that_edge(creature):
    raw, n = raw_scan(creature, fin=True)
    repaired = largest_clean_piece(raw)
    assert "on non-manifold edges 3" in repaired.summary
    assert repaired.piece.mesh.n_faces == creature.n_faces - 2  # a hole where the edge was
    make_mesh(repaired.piece.mesh.verts, repaired.piece.mesh.faces, "piece")


def test_duplicate_faces_are_named_and_only_the_copies_dropped(creature):
    copies = creature.faces[[5, 50, 500]][:, ::-1]  # the same faces again, one of them turned round
    raw = Mesh(creature.verts, np.vstack([creature.faces, copies]), "doubled.off")
    with pytest.raises(MeshError, match=r"doubled.off: 3 duplicate faces .*face \d+ repeats face 5"):
        make_mesh(raw.verts, raw.faces, raw.name)
    with pytest.raises(MeshError) as refused:  # as matching refuses it: what repair=true keeps, said once
        mesh_of(raw, "source", repair=False)
    assert str(refused.value).count("repair=true") == 1 and "duplicates of other faces 3" in str(
        refused.value
    )
    repaired = largest_clean_piece(raw)
    assert "duplicates of other faces 3" in repaired.summary and "non-manifold" not in repaired.summary
    assert repaired.piece.mesh.n_faces == creature.n_faces and repaired.piece.kept_area == pytest.approx(1.0)


def test_a_repair_that_keeps_too_little_is_refused_with_the_file_named(creature):
    shifted = [creature.verts + k * 10 * np.ptp(creature.verts) for k in range(3)]
    faces = np.vstack([creature.faces + k * creature.n_verts for k in range(3)])
    three_bodies = Mesh(np.vstack(shifted), faces, "three_bodies.off")
    with pytest.raises(MeshError, match=r"three_bodies.off: its largest clean piece would be .*too little"):
        largest_clean_piece(three_bodies)


def test_the_api_refuses_a_raw_scan_with_what_repair_would_do_and_matches_it_with_repair(creature):
    raw, n = raw_scan(creature)
    arrays = (raw.verts, raw.faces)
    with pytest.raises(MeshError, match="repair=true would match its largest clean piece"):
        spidermatch.match(arrays, creature, features="wks", resolution=120)
    body = WKSExtractor()(creature)  # the raw scan's body is the target: its own features
    features = (np.vstack([body, np.zeros((raw.n_verts - n, body.shape[1]))]), body)
    matching = spidermatch.match(
        arrays, creature, features=features, resolution=200, time_limit=300, repair=True
    )
    assert matching.status == "optimal"
    assert matching.dense_map.shape == (raw.n_verts,)
    assert np.all(matching.dense_map[n:] == -1) and np.all(matching.dense_map[:n] >= 0)
    assert np.array_equal(np.flatnonzero(matching.source_overlap), np.arange(n))
    assert matching.matches[:, 0].max() < n
    # a copy matched to itself: the body's vertices find themselves (up to decimation)
    dense_error = np.linalg.norm(creature.verts[matching.dense_map[:n]] - creature.verts, axis=1)
    assert np.mean(dense_error) < 0.5 * mean_edge_length(creature)


def _match_files(tmp_path, pair: dict, *overrides: str) -> tuple[int, dict, object]:
    """``spidermatch-match`` on ``pair`` (option -> file in ``tmp_path``): exit code, result.json, folder."""
    files = [f"{key}={tmp_path / name}" for key, name in pair.items()]
    cfg = composed("match", [*files, "resolution=120", "output.png=false", "output.viewer=false", *overrides])
    out = tmp_path / ("run_" + "_".join(o.split("=")[0] for o in overrides))
    return run_match(cfg, out), result_of(out), out


def _raw_and_body_files(tmp_path, creature, raw_role: str) -> tuple[Mesh, int, np.ndarray, dict]:
    """The raw scan and the body saved, with ground truth that has one more row on the stray vertex."""
    raw, n = raw_scan(creature)
    save_mesh(raw, tmp_path / "raw.off")
    save_mesh(creature, tmp_path / "body.off")
    truth = np.arange(0, n, 7)
    np.savetxt(tmp_path / "raw.vts", np.r_[truth, raw.n_verts - 1] + 1, fmt="%d")  # the last: left out
    np.savetxt(tmp_path / "body.vts", np.r_[truth, 0] + 1, fmt="%d")
    other = "target" if raw_role == "source" else "source"
    pair = {
        raw_role: "raw.off",
        other: "body.off",
        f"{raw_role}_corr": "raw.vts",
        f"{other}_corr": "body.vts",
    }
    return raw, n, truth, pair


def test_the_command_line_repairs_a_raw_source_and_writes_its_own_indices(tmp_path, creature):
    raw, n, truth, pair = _raw_and_body_files(tmp_path, creature, "source")

    def run(*overrides: str):
        return _match_files(tmp_path, pair, *overrides)

    code, result, _ = run()
    assert code == 2 and "repair=true would match" in result["error"] and "raw.off" in result["error"]
    code, result, out = run("repair=true", "solver.time_limit=300")
    assert code == 0 and result["status"] == "optimal"
    assert result["gap"] == 0.0  # objective and bound both ~1e-18 (its own features): rounding, not a gap
    assert any("repair=true matches its largest clean piece" in text for text in result["warnings"])
    assert result["pair"]["mode"] == "whole"  # the body is closed: nothing was cut from it
    assert 0 < result["geodesic_error"]["n_points"] <= truth.size  # the sparse map's reference points
    dense_errors = np.load(out / "dense_geodesic_errors.npy")  # every reference point in the piece
    assert dense_errors.shape == truth.shape and dense_errors.mean() < 0.02
    matches = np.loadtxt(out / "matches.csv", delimiter=",", skiprows=1, dtype=np.int64)
    assert matches[:, 0].max() < n
    with np.load(out / "dense_map.npz") as dense:
        assert np.array_equal(dense["source_vertex"], np.arange(n))
    rows = np.loadtxt(out / "dense_matches.csv", delimiter=",", skiprows=1, dtype=np.int64)
    n_file = raw.n_verts  # the body's n vertices, then the debris'
    assert n_file > n and np.array_equal(rows[:, 0], np.arange(n_file))  # a row per vertex, in order
    assert (rows[:n, 1] >= 0).all() and (rows[n:, 1] == -1).all()  # left out: no image


def test_an_overlap_of_a_repaired_source_is_told_in_the_source_own_indices():
    """partial="both" on a repaired source: a piece of a piece, mapped back twice."""
    from spidermatch.api import Matching, on_whole_source
    from spidermatch.geometry.partial import PartialShape

    def piece(to_original, n_verts):
        mesh = Mesh(np.zeros((n_verts, 3)), np.zeros((0, 3), int))
        return PartialShape(mesh, np.asarray(to_original), 1.0, "x")

    repaired = piece([0, 2, 3, 5], 4)  # 4 of the 6 vertices given
    overlap = piece([1, 3], 2)  # 2 of the repaired piece's vertices
    matching = Matching(np.array([[0, 7], [1, 8]]), np.array([7, 8]), "optimal", 1.0, 1.0, 0.0, 100, "x")
    matching = on_whole_source(on_whole_source(matching, overlap, 4), repaired, 6)
    assert np.array_equal(matching.matches, [[2, 7], [5, 8]])
    assert np.array_equal(matching.dense_map, [-1, -1, 7, -1, -1, 8])
    assert np.array_equal(np.flatnonzero(matching.source_overlap), [2, 5])


def test_a_raw_target_is_repaired_too_and_its_own_indices_come_back(creature):
    raw, n = raw_scan(creature)
    body = WKSExtractor()(creature)
    features = (body, np.vstack([body, np.zeros((raw.n_verts - n, body.shape[1]))]))
    matching = spidermatch.match(
        creature, (raw.verts, raw.faces), features=features, resolution=200, time_limit=300, repair=True
    )
    assert matching.status == "optimal" and matching.source_overlap is None
    assert matching.dense_map.shape == (n,) and matching.dense_map.max() < n  # never a left-out vertex
    assert matching.matches[:, 1].max() < n
    dense_error = np.linalg.norm(creature.verts[matching.dense_map] - creature.verts, axis=1)
    assert np.mean(dense_error) < 0.5 * mean_edge_length(creature)


def test_the_command_line_writes_a_repaired_target_in_its_own_indices(tmp_path, creature):
    raw, n, truth, pair = _raw_and_body_files(tmp_path, creature, "target")
    code, result, out = _match_files(tmp_path, pair, "repair=true", "dense.inverse=true")
    assert code == 0
    assert any("raw.off: repair=true matches its largest clean piece" in text for text in result["warnings"])
    assert np.load(out / "dense_geodesic_errors.npy").shape == truth.shape
    matches = np.loadtxt(out / "matches.csv", delimiter=",", skiprows=1, dtype=np.int64)
    assert matches[:, 1].max() < n
    with np.load(out / "dense_map.npz") as dense:
        assert dense["vertex"].shape == (n,) and dense["vertex"].max() < n
        assert np.all(np.isin(raw.faces[dense["face"]], np.arange(n)))  # faces of the file, on the body
        assert dense["inverse_vertex"].shape == (raw.n_verts,)
        assert np.all(dense["inverse_vertex"][n:] == -1) and np.all(dense["inverse_vertex"][:n] >= 0)
        assert np.all(np.isnan(dense["inverse_gap"][n:]))
    rows = np.loadtxt(out / "dense_inverse_matches.csv", delimiter=",", skiprows=1, dtype=np.int64)
    assert rows.shape == (raw.n_verts, 2) and np.all(rows[n:, 1] == -1)
