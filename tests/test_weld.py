"""STL files and triangle soups: welded for matching, every output in the file's own vertices."""

import numpy as np
import pytest
import trimesh
from conftest import composed, icosphere, result_of

import spidermatch
from spidermatch.api import mesh_of
from spidermatch.cli.match import run_match
from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.descriptors import WKSExtractor
from spidermatch.geometry.io import load_mesh
from spidermatch.geometry.mesh import Mesh, MeshError, make_mesh, topology
from spidermatch.geometry.partial import mean_edge_length
from spidermatch.geometry.weld import welded


@pytest.fixture(scope="module")
def creature() -> Mesh:
    return make_creature(n_verts=700, seed=5).mesh


def soup_of(mesh: Mesh) -> Mesh:
    """``mesh`` as an STL stores it: three vertices of its own per face, corner by corner."""
    return Mesh(mesh.verts[mesh.faces].reshape(-1, 3), np.arange(3 * mesh.n_faces).reshape(-1, 3), "soup")


def assert_rebuilt(weld, mesh: Mesh, file_vertex_of: np.ndarray) -> None:
    """``weld`` made ``mesh`` again: one welded vertex per vertex of ``mesh``, the same faces."""
    pairs = np.unique(np.stack([file_vertex_of, weld.to_welded], axis=1), axis=0)
    assert len(pairs) == mesh.n_verts == weld.mesh.n_verts  # a bijection
    original_of = np.empty(mesh.n_verts, dtype=np.int64)
    original_of[pairs[:, 1]] = pairs[:, 0]
    assert np.array_equal(original_of[weld.mesh.faces], mesh.faces)
    assert np.array_equal(weld.mesh.verts, mesh.verts[original_of])


def test_a_triangle_soup_is_welded_back_into_its_surface(creature):
    weld = welded(soup_of(creature))
    assert_rebuilt(weld, creature, creature.faces.reshape(-1))
    assert np.array_equal(weld.to_file, np.sort(weld.to_file))  # numbered as they first appear
    assert np.array_equal(weld.to_welded[weld.to_file], np.arange(weld.mesh.n_verts))
    make_mesh(weld.mesh.verts, weld.mesh.faces)  # a valid surface
    assert "repeat the position of another" in weld.note and "every output names" in weld.note


def test_coincident_vertices_of_a_valid_surface_stay_apart(creature):
    """Two vertices at one position whose faces share no edge are two vertices (a self-contact)."""
    verts = creature.verts.copy()
    far = int(np.argmax(np.linalg.norm(verts - verts[0], axis=1)))
    verts[far] = verts[0]
    touching = Mesh(verts, creature.faces, "touching.off")
    assert welded(touching) is None
    mesh, repaired, weld = mesh_of(touching, "source", repair=False)
    assert weld is None and repaired is None and mesh.n_verts == creature.n_verts


def test_two_surfaces_touching_on_a_triangle_are_rebuilt_each_whole():
    """Two closed surfaces sharing one triangle by position (as remeshed self-contacts do).

    The triangle's three edges each carry four faces, and each corner's faces are cut off from
    the triangle on both sides: only pairing the faces of a crowded edge rebuilds the surfaces.
    """
    sphere = icosphere(2)
    corners = sphere.faces[0]
    a, b, c = sphere.verts[corners]
    normal = np.cross(b - a, c - a)
    normal /= np.linalg.norm(normal)
    mirrored = sphere.verts - 2 * np.outer((sphere.verts - a) @ normal, normal)  # across the triangle's plane
    mirrored[corners] = sphere.verts[corners]  # exactly where they were
    n = sphere.n_verts
    both = Mesh(np.vstack([sphere.verts, mirrored]), np.vstack([sphere.faces, sphere.faces[:, ::-1] + n]))
    weld = welded(soup_of(both))
    assert_rebuilt(weld, both, both.faces.reshape(-1))


def test_a_seam_split_by_an_exporter_is_closed(creature):
    """A closed surface whose vertex is doubled along a slit (valid, with a boundary) is matched closed."""
    centre = int(np.argmax(np.bincount(creature.faces.reshape(-1))))
    around = np.flatnonzero((creature.faces == centre).any(axis=1))
    ring = np.unique(creature.faces[around])
    ring = ring[ring != centre]
    a = ring[0]
    b = ring[np.argmax(np.linalg.norm(creature.verts[ring] - creature.verts[a], axis=1))]  # across the fan
    side = _one_side_of(creature.faces, around, centre, a, b)
    verts = np.vstack([creature.verts, creature.verts[centre]])
    faces = creature.faces.copy()
    faces[side] = np.where(faces[side] == centre, creature.n_verts, faces[side])
    slit = Mesh(verts, faces, "slit.obj")
    assert topology(make_mesh(verts, faces)).boundaries == 1  # valid as given, with a slit
    mesh, _, weld = mesh_of(slit, "source", repair=False)
    assert weld is not None and mesh.n_verts == creature.n_verts
    assert topology(mesh).boundaries == 0


def _one_side_of(faces, around, centre, a, b) -> np.ndarray:
    """Faces of the fan ``around`` vertex ``centre`` on one side of the path a - centre - b."""
    side = [around[np.flatnonzero((faces[around] == a).any(axis=1))[0]]]
    while True:
        last = faces[side[-1]]
        for face in around:
            if face in side:
                continue
            shared = np.intersect1d(faces[face], last)
            rim = shared[shared != centre]
            if len(shared) == 2 and rim[0] not in (a, b):
                side.append(face)
                break
        else:
            return np.array(side)


def test_the_api_matches_a_soup_and_names_the_file_vertices(creature):
    soup = soup_of(creature)
    body = WKSExtractor()(creature)
    features = (body[creature.faces.reshape(-1)], body)  # the soup's features: one row per corner
    matching = spidermatch.match(
        (soup.verts, soup.faces), creature, features=features, resolution=200, time_limit=300
    )
    assert matching.status == "optimal"
    assert matching.dense_map.shape == (soup.n_verts,) and matching.matches[:, 0].max() < soup.n_verts
    # every corner of one vertex has the same image, and a copy matched to itself finds itself
    original = creature.faces.reshape(-1)
    image_of_vertex = np.full(creature.n_verts, -1)
    image_of_vertex[original] = matching.dense_map
    assert np.array_equal(image_of_vertex[original], matching.dense_map)
    dense_error = np.linalg.norm(creature.verts[image_of_vertex] - creature.verts, axis=1)
    assert np.mean(dense_error) < 0.5 * mean_edge_length(creature)
    assert np.allclose(soup.verts[matching.matches[:, 0]], creature.verts[original[matching.matches[:, 0]]])


def test_the_command_line_reads_stl_files_and_writes_their_corners(tmp_path, creature):
    """STL source and target: the outputs name their corners (three per facet, in file order)."""
    trimesh.Trimesh(creature.verts, creature.faces, process=False).export(tmp_path / "a.stl")
    trimesh.Trimesh(creature.verts, creature.faces, process=False).export(tmp_path / "b.stl")
    corners = creature.faces.reshape(-1)
    first_corner = np.full(creature.n_verts, -1)
    first_corner[corners[::-1]] = np.arange(corners.size)[::-1]
    truth = np.arange(0, creature.n_verts, 7)
    np.savetxt(tmp_path / "a.vts", first_corner[truth] + 1, fmt="%d")
    np.savetxt(tmp_path / "b.vts", first_corner[truth] + 1, fmt="%d")
    files = [f"{key}={tmp_path / name}" for key, name in (("source", "a.stl"), ("target", "b.stl"))]
    files += [f"source_corr={tmp_path / 'a.vts'}", f"target_corr={tmp_path / 'b.vts'}"]
    cfg = composed(
        "match", [*files, "resolution=120", "output.png=false", "output.viewer=false", "dense.inverse=true"]
    )
    out = tmp_path / "run"
    assert run_match(cfg, out) == 0
    result = result_of(out)
    assert sum("repeat the position of another" in text for text in result["warnings"]) == 2
    assert result["pair"]["mode"] == "whole"
    assert np.load(out / "dense_geodesic_errors.npy").shape == truth.shape  # every reference point
    assert result["dense"]["dense"]["geodesic_error"] < 0.05  # a copy matched to itself
    n_corners = corners.size
    matches = np.loadtxt(out / "matches.csv", delimiter=",", skiprows=1, dtype=np.int64)
    assert matches.max() < n_corners
    rows = np.loadtxt(out / "dense_matches.csv", delimiter=",", skiprows=1, dtype=np.int64)
    assert np.array_equal(rows[:, 0], np.arange(n_corners)) and rows[:, 1].max() < n_corners
    with np.load(out / "dense_map.npz") as dense:
        assert dense["vertex"].shape == (n_corners,) and "source_vertex" not in dense
        assert np.array_equal(dense["vertex"], rows[:, 1]) and dense["face"].max() < creature.n_faces
        assert dense["inverse_vertex"].shape == (n_corners,) and dense["inverse_vertex"].max() < n_corners
    same_vertex = corners[rows[:, 1]]
    images_of_vertex = np.full(creature.n_verts, -1)
    images_of_vertex[corners] = same_vertex
    assert np.array_equal(images_of_vertex[corners], same_vertex)  # corners of a vertex: one image


def test_a_soup_that_is_no_surface_is_refused_naming_the_weld(tmp_path):
    sphere = icosphere(1)
    faces = np.vstack([sphere.faces, sphere.faces[:1]])  # one facet twice: three faces on its edges
    trimesh.Trimesh(
        sphere.verts[faces].reshape(-1, 3), np.arange(3 * len(faces)).reshape(-1, 3), process=False
    ).export(tmp_path / "twice.stl")
    with pytest.raises(MeshError, match=r"twice\.stl.*repeated vertices welded"):
        mesh_of(str(tmp_path / "twice.stl"), "source", repair=False)
    with pytest.raises(
        MeshError, match="repeat the position of another"
    ):  # datasets and training read it too
        load_mesh(tmp_path / "twice.stl")


def test_a_sliver_facet_in_a_soup_is_left_to_the_repair(tmp_path):
    """A facet with a repeated corner on a body edge joins nothing; repair=true drops it."""
    sphere = icosphere(2)
    a, b = sphere.faces[0, :2]
    faces = np.vstack([sphere.faces, [[a, a, b]]])  # a sliver on the edge (a, b): three faces there
    soup = sphere.verts[faces].reshape(-1, 3)
    path = tmp_path / "sliver.stl"
    trimesh.Trimesh(soup, np.arange(len(soup)).reshape(-1, 3), process=False).export(path)
    with pytest.raises(MeshError, match=r"sliver\.stl: 1 degenerate faces.*repair=true would match.*welded"):
        mesh_of(str(path), "source", repair=False)
    mesh, repaired, weld = mesh_of(str(path), "source", repair=True)
    assert weld is not None and repaired is not None
    assert mesh.n_verts == sphere.n_verts and mesh.n_faces == sphere.n_faces  # the body, whole
    assert topology(mesh).boundaries == 0


def test_a_glb_file_is_read_and_its_split_vertices_welded(tmp_path, creature):
    """glTF stores a vertex per corner where normals or texture coordinates differ: welded like a soup."""
    soup = soup_of(creature)
    trimesh.Trimesh(soup.verts, soup.faces, process=False).export(tmp_path / "scan.glb")
    read = load_mesh(tmp_path / "scan.glb", validate=False)
    assert read.n_faces == creature.n_faces and np.allclose(read.verts, soup.verts, atol=1e-6)
    mesh, _, weld = mesh_of(str(tmp_path / "scan.glb"), "source", repair=False)
    assert weld is not None and mesh.n_verts == creature.n_verts


def test_a_vertex_an_exporter_left_unused_at_a_split_seam_joins_its_copies(creature):
    """Every face around vertex 0 takes a copy of it (a seam split): the original is left unused."""
    around = np.flatnonzero((creature.faces == 0).any(axis=1))
    faces = creature.faces.copy()
    copy = creature.n_verts
    faces[around] = np.where(faces[around] == 0, copy, faces[around])
    split = Mesh(np.vstack([creature.verts, creature.verts[:1]]), faces, "split.obj")
    with pytest.raises(MeshError, match="not used by any face"):
        make_mesh(split.verts, split.faces)  # as given: a stray vertex
    weld = welded(split)
    assert weld.to_welded[0] == weld.to_welded[copy]  # the unused original is its copy's point
    assert_rebuilt(weld, creature, np.append(np.arange(creature.n_verts), 0))
    mesh, repaired, used_weld = mesh_of(split, "source", repair=False)
    assert repaired is None and used_weld is not None and mesh.n_verts == creature.n_verts
    # an unused vertex at a position of its own is still a stray vertex
    stray = Mesh(np.vstack([split.verts, [[9.0, 9.0, 9.0]]]), faces, "stray.obj")
    with pytest.raises(MeshError, match="not used by any face"):
        mesh_of(stray, "source", repair=False)


def _split_in_two(mesh: Mesh, shift: float) -> tuple[Mesh, np.ndarray]:
    """``mesh`` cut into two parts (upper and lower faces), each with its own vertices, as a scene
    exporter stores them: the lower part placed by a float32 node transform moving it ``shift`` back.

    Returns the joined mesh and the original vertex of each of its vertices.
    """
    upper = mesh.verts[mesh.faces].mean(axis=1)[:, 1] > np.median(mesh.verts[:, 1])
    verts, faces, original, start = [], [], [], 0
    for part, moved in ((upper, 0.0), (~upper, shift)):
        used, local = np.unique(mesh.faces[part], return_inverse=True)
        stored = (mesh.verts[used] + [0.0, 0.0, moved]).astype(np.float32)  # in the file
        placed = (stored - np.float32([0.0, 0.0, moved])).astype(np.float64)  # after its transform
        verts.append(placed)
        faces.append(local.reshape(-1, 3) + start)
        original.append(used)
        start += used.size
    return Mesh(np.vstack(verts), np.vstack(faces), "scene.glb"), np.concatenate(original)


def test_a_scene_whose_parts_were_placed_in_single_precision_is_welded_along_its_seam(creature):
    """Two parts of one body stored with their own node transforms: the seam's two sides lie a
    float32 rounding error apart, not at the same position. Refused as two components before."""
    scene, original = _split_in_two(creature, shift=5.0)
    assert len(np.unique(scene.verts, axis=0)) > creature.n_verts  # the seam does not repeat exactly
    mesh, repaired, weld = mesh_of(scene, "source", repair=False)
    assert repaired is None and mesh.n_verts == creature.n_verts
    assert 0 < weld.gap < 1e-5 and "lie within" in weld.note
    pairs = np.unique(np.stack([original, weld.to_welded], axis=1), axis=0)
    assert len(pairs) == creature.n_verts  # a bijection


def test_boundaries_further_apart_than_a_rounding_error_stay_open(creature):
    """The same two parts a hundredth of an edge apart stay two pieces (a gap of the shape's own)."""
    scene, _ = _split_in_two(creature, shift=0.0)
    lower = np.arange(scene.n_verts) >= np.unique(scene.faces[: scene.n_faces // 2]).size
    apart = scene.verts.copy()
    apart[lower, 2] += 0.01 * mean_edge_length(creature)
    assert welded(Mesh(apart, scene.faces, "apart.obj")) is None


def test_a_fold_on_a_seam_between_scene_objects_is_welded_as_it_was(creature):
    """Remeshing leaves folds: two faces on one triangle, sharing an edge, their third vertices
    apart at one position (tr_reg_078). Cut into objects across the fold and placed in single
    precision, the fold's faces cover each other's edges, so its corners were not looked for among
    the other objects' (only open edges were): the weld closed it into one face twice (refused)."""
    verts, faces = creature.verts.copy(), creature.faces
    height = verts[faces].mean(axis=1)[:, 1]
    middle = np.median(verts[:, 1])
    for first in np.argsort(np.abs(height - middle)):  # a face near the cut
        a, b, tip = faces[first]
        on_edge = (np.isin(faces, [a, b]).sum(axis=1) == 2) & (np.arange(len(faces)) != first)
        other = int(np.setdiff1d(faces[np.flatnonzero(on_edge)[0]], [a, b])[0])
        tip_faces = np.flatnonzero((faces == tip).any(axis=1))
        if (height[tip_faces] <= middle).any() and (height[tip_faces] > middle).any():
            break
    verts[other] = verts[tip]  # the fold: the face across edge ab now lies on the first
    folded = Mesh(verts, faces, "folded")
    make_mesh(folded.verts, folded.faces)  # valid as given
    scene, original = _split_in_two(folded, shift=5.0)
    mesh, _, weld = mesh_of(scene, "source", repair=False)
    assert mesh.n_verts == creature.n_verts
    pairs = np.unique(np.stack([original, weld.to_welded], axis=1), axis=0)
    assert len(pairs) == creature.n_verts  # the fold's two tips stay two vertices
