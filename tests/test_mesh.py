import re

import numpy as np
import pytest

from spidermatch.geometry.io import load_mesh, read_vts, save_mesh
from spidermatch.geometry.mesh import Mesh, MeshError, augment_edges, make_mesh, unique_edges, validate_mesh
from tests.conftest import icosphere

TETRA_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def write_off(path, verts, faces):
    lines = ["OFF", f"{len(verts)} {len(faces)} 0"]
    lines += [" ".join(str(c) for c in v) for v in verts]
    lines += ["3 " + " ".join(str(int(i)) for i in f) for f in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_reads_without_reordering(tmp_path, rng):
    sphere = icosphere(2)
    perm = rng.permutation(sphere.n_verts)
    inverse = np.argsort(perm)
    path = write_off(tmp_path / "s.off", sphere.verts[perm], inverse[sphere.faces])
    mesh = load_mesh(path)
    np.testing.assert_allclose(mesh.verts, sphere.verts[perm])
    np.testing.assert_array_equal(mesh.faces, inverse[sphere.faces])


@pytest.mark.parametrize("suffix", [".off", ".obj", ".ply"])
def test_round_trip_formats(tmp_path, suffix):
    sphere = icosphere(1)
    save_mesh(sphere, tmp_path / f"s{suffix}")
    loaded = load_mesh(tmp_path / f"s{suffix}")
    np.testing.assert_allclose(loaded.verts, sphere.verts, atol=1e-6)
    np.testing.assert_array_equal(loaded.faces, sphere.faces)


BAD_MESHES = {
    "nan": (np.vstack([TETRA_V[:3], [np.nan, 0, 1]]), TETRA_F, "NaN or infinite"),
    "missing vertex": (TETRA_V, np.vstack([TETRA_F[:3], [1, 2, 7]]), "does not exist|outside the range"),
    "degenerate": (np.vstack([TETRA_V, [0.5, 0.5, 0]]), np.vstack([TETRA_F, [1, 2, 4]]), "degenerate"),
    "repeated index": (TETRA_V, np.vstack([TETRA_F, [1, 1, 2]]), "degenerate"),
    "non-manifold": (
        np.vstack([TETRA_V, [1, 1, 1]]),
        np.vstack([TETRA_F, [1, 2, 4]]),
        "non-manifold",
    ),
    "components": (
        np.vstack([TETRA_V, TETRA_V + 5]),
        np.vstack([TETRA_F, TETRA_F + 4]),
        "2 connected components",
    ),
    "unreferenced": (np.vstack([TETRA_V, [3, 3, 3]]), TETRA_F, "not used by any face"),
}


@pytest.mark.parametrize("case", sorted(BAD_MESHES))
def test_bad_files_name_file_and_problem(tmp_path, case):
    verts, faces, expected = BAD_MESHES[case]
    path = write_off(tmp_path / f"{case.replace(' ', '_')}.off", verts, faces)
    with pytest.raises(MeshError) as error:
        load_mesh(path)
    assert str(path) in str(error.value)
    assert re.search(expected, str(error.value))
    with pytest.raises(MeshError, match="mine"):
        validate_mesh(verts, faces, "mine")


def test_empty_and_missing_and_unsupported_files(tmp_path):
    empty = tmp_path / "empty.off"
    empty.write_text("")
    with pytest.raises(MeshError, match="empty.off: empty mesh"):
        load_mesh(empty)
    header_only = tmp_path / "header.off"
    header_only.write_text("OFF\n0 0 0\n")
    with pytest.raises(MeshError, match="header.off: empty mesh"):
        load_mesh(header_only)
    with pytest.raises(MeshError, match="no such file"):
        load_mesh(tmp_path / "nope.off")
    with pytest.raises(MeshError, match="unsupported mesh type"):
        load_mesh(write_off(tmp_path / "x.vtk", TETRA_V, TETRA_F))
    with pytest.raises(MeshError, match=r"x\.stl: "):  # an OFF text named .stl: not an STL
        load_mesh(write_off(tmp_path / "x.stl", TETRA_V, TETRA_F))
    garbage = tmp_path / "garbage.off"
    garbage.write_text("OFF\n3 1 0\n0 0 zero\n1 0 0\n0 1 0\n3 0 1 2\n")
    with pytest.raises(MeshError, match="garbage.off"):
        load_mesh(garbage)


def test_validator_rejects_wrong_shapes():
    with pytest.raises(MeshError, match="shape"):
        validate_mesh(np.zeros((4, 2)), TETRA_F, "m")
    with pytest.raises(MeshError, match="triangles"):
        validate_mesh(TETRA_V, np.zeros((2, 4), dtype=int), "m")


def test_vts_errors(tmp_path):
    good = tmp_path / "a.vts"
    good.write_text("1\n4\n2\n")
    np.testing.assert_array_equal(read_vts(good, 4), [0, 3, 1])
    with pytest.raises(MeshError, match="exceeds"):
        read_vts(good, 3)
    zero = tmp_path / "z.vts"
    zero.write_text("0\n1\n")
    with pytest.raises(MeshError, match="1-based"):
        read_vts(zero)
    text = tmp_path / "t.vts"
    text.write_text("1\nabc\n")
    with pytest.raises(MeshError, match="integer"):
        read_vts(text)


def test_area_centring_and_edges():
    sphere = icosphere(3)
    assert abs(sphere.area - 4 * np.pi) / (4 * np.pi) < 0.01
    shifted = Mesh(sphere.verts + [1.0, 2.0, 3.0], sphere.faces)
    np.testing.assert_allclose(shifted.centred().verts.mean(axis=0), 0.0, atol=1e-12)
    edges = unique_edges(sphere.faces)
    assert len(edges) == 3 * sphere.n_faces // 2  # closed triangle mesh
    assert (edges[:, 0] < edges[:, 1]).all()


def test_augmented_edges_add_one_flip_per_interior_edge():
    sphere = icosphere(2)
    plain, augmented = sphere.edges, augment_edges(sphere.faces)
    plain_set = {tuple(e) for e in plain.tolist()}
    flips = [e for e in augmented.tolist() if tuple(e) not in plain_set]
    assert len(augmented) == len(plain) + len(flips)
    assert len(flips) == len(plain)  # no flip edge of an icosphere is already an edge
    # every flip joins the two vertices opposite an edge
    faces_of = {}
    for f in sphere.faces.tolist():
        for k in range(3):
            faces_of.setdefault(tuple(sorted((f[k - 1], f[k - 2]))), []).append(f[k])
    expected = {tuple(sorted(opp)) for opp in faces_of.values()}
    assert {tuple(e) for e in flips} == expected


def test_mesh_is_read_only():
    mesh = make_mesh(TETRA_V, TETRA_F)
    with pytest.raises(ValueError):
        mesh.verts[0, 0] = 5.0
