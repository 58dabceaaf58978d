"""Projection of full-resolution vertices onto their decimation, along the surface."""

import numpy as np
import pytest

from spidermatch.geometry.coarse import (
    coarse_labels,
    faces_by_label,
    project_onto_coarse,
    ring_faces,
    vertex_rings,
)
from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.remesh import Decimated
from spidermatch.geometry.surface import closest_surface_points, closest_triangle_points


def grid(n: int, height: float, step: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """An n x n vertex grid in the plane z = height, every ``step``-th vertex, as (verts, faces)."""
    coords = np.arange(0, n, step, dtype=float) / (n - 1)
    m = len(coords)
    x, y = np.meshgrid(coords, coords, indexing="ij")
    verts = np.stack([x.ravel(), y.ravel(), np.full(m * m, height)], axis=1)
    index = np.arange(m * m).reshape(m, m)
    a, b, c, d = index[:-1, :-1], index[1:, :-1], index[:-1, 1:], index[1:, 1:]
    faces = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return verts, faces


def two_sheets() -> tuple[Mesh, Decimated, np.ndarray]:
    """Two parallel sheets 0.1 apart; the coarse upper sheet sits 0.15 above the fine one.

    So the coarse triangles nearest in space to the fine upper vertices are those of the lower
    sheet, as where two body parts nearly touch. Returns the mesh, its coarse version and a
    (V,) bool of the upper fine vertices.
    """
    lower, lower_faces = grid(9, 0.0)
    upper, upper_faces = grid(9, 0.1)
    full = Mesh(np.vstack([lower, upper]), np.vstack([lower_faces, upper_faces + len(lower)]), "sheets")
    coarse_lower, coarse_faces = grid(9, 0.0, step=2)
    coarse_upper, _ = grid(9, 0.25, step=2)
    low_mesh = Mesh(
        np.vstack([coarse_lower, coarse_upper]),
        np.vstack([coarse_faces, coarse_faces + len(coarse_lower)]),
        "coarse",
    )
    sub = np.arange(0, 9, 2)
    one_sheet = (sub[:, None] * 9 + sub[None, :]).ravel()
    to_full = np.concatenate([one_sheet, one_sheet + len(lower)])
    upper_mask = np.arange(full.n_verts) >= len(lower)
    return full, Decimated(low_mesh, to_full), upper_mask


def test_labels_follow_the_surface_not_space():
    full, low, upper = two_sheets()
    labels = coarse_labels(full, low)
    coarse_upper = low.mesh.verts[:, 2] > 0.1
    assert np.array_equal(coarse_upper[labels], upper)
    assert np.all(labels[low.to_full] == np.arange(len(low.to_full)))


def test_projection_stays_on_its_own_sheet_where_space_would_jump():
    full, low, upper = two_sheets()
    face, _ = project_onto_coarse(full, low)
    coarse_upper_face = low.mesh.verts[low.mesh.faces[:, 0], 2] > 0.1
    assert np.array_equal(coarse_upper_face[face], upper)
    spatial_face, _ = closest_surface_points(low.mesh, full.verts)
    assert not np.array_equal(coarse_upper_face[spatial_face], upper)  # the case is a real trap


def test_candidates_with_repeats_and_padding_give_the_free_search_result():
    verts, faces = grid(7, 0.0)
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(0, 1, (40, 2)), rng.normal(0, 0.05, 40)])
    free_face, free_bary = closest_triangle_points(verts, faces, points, n_candidates=len(faces))
    every = np.tile(np.arange(len(faces)), (len(points), 1))
    padded = np.concatenate([every, every[:, :5], np.full((len(points), 3), -1)], axis=1)
    face, bary = closest_triangle_points(verts, faces, points, candidates=padded)
    free_points = np.einsum("nk,nkd->nd", free_bary, verts[faces[free_face]])
    points_found = np.einsum("nk,nkd->nd", bary, verts[faces[face]])
    np.testing.assert_allclose(points_found, free_points, atol=1e-12)


@pytest.mark.parametrize("pairs", [1, 7, 64])
def test_points_searched_in_blocks_land_where_one_block_puts_them(pairs, monkeypatch):
    """The search runs a block of points at a time (bounded memory: a 320k-vertex scan asked 7.9 M
    point-face pairs at once); blocks of any size (a block holds whole rows) change nothing."""
    import spidermatch.geometry.surface as surface

    verts, faces = grid(7, 0.0)
    rng = np.random.default_rng(1)
    points = np.column_stack([rng.uniform(0, 1, (50, 2)), rng.normal(0, 0.05, 50)])
    candidates = rng.integers(-1, len(faces), (50, 9))
    candidates[:, 0] = rng.integers(0, len(faces), 50)  # every point needs one face
    for clip in (True, False):
        whole = closest_triangle_points(verts, faces, points, clip=clip, candidates=candidates)
        monkeypatch.setattr(surface, "POINT_BLOCK_PAIRS", pairs)
        blocks = surface._point_blocks(candidates, pairs)
        assert len(blocks) > 1 and [b.start for b in blocks[1:]] == [b.stop for b in blocks[:-1]]
        in_blocks = closest_triangle_points(verts, faces, points, clip=clip, candidates=candidates)
        monkeypatch.undo()
        np.testing.assert_array_equal(in_blocks[0], whole[0])
        np.testing.assert_array_equal(in_blocks[1], whole[1])


def test_rings_and_label_tables_cover_their_vertices():
    full, low, _ = two_sheets()
    rings = vertex_rings(low.mesh)
    assert np.all(rings[:, 0] == np.arange(low.mesh.n_verts))
    for a, b in low.mesh.edges:
        assert b in rings[a] and a in rings[b]
    around = ring_faces(low.mesh, np.array([0]))
    assert set(around[0][around[0] >= 0]) >= set(np.flatnonzero((low.mesh.faces == 0).any(axis=1)))
    labels = coarse_labels(full, low)
    table = faces_by_label(full, labels, low.mesh.n_verts)
    for face_index, corners in enumerate(full.faces):
        for label in set(labels[corners]):
            assert face_index in table[label]


def test_closest_points_near_their_rings_are_the_same_built_a_block_at_a_time(monkeypatch):
    """On a mesh with vertices of high degree the candidate table is built in blocks of points:
    the same faces and coordinates as from the whole table at once."""
    import spidermatch.geometry.coarse as coarse
    from spidermatch.data.synthetic import centroid_split, make_creature
    from spidermatch.geometry.mesh import Mesh

    mesh = make_creature(600, seed=2).mesh
    verts, faces = mesh.verts, mesh.faces
    chosen = np.arange(len(faces)) < len(faces) // 3
    for _ in range(2):
        verts, faces, chosen = centroid_split(verts, faces, chosen)
    mesh = Mesh(verts, faces)
    rng = np.random.default_rng(2)
    vertices = rng.integers(mesh.n_verts, size=500)
    points = mesh.verts[vertices] + rng.normal(scale=0.01, size=(500, 3))
    whole = closest_triangle_points(
        mesh.verts, mesh.faces, points, candidates=coarse.ring_faces(mesh, vertices)
    )
    monkeypatch.setattr(coarse, "RING_FACE_CELLS", 1)  # one point per block
    in_blocks = coarse.closest_points_near(mesh, points, vertices)
    np.testing.assert_array_equal(in_blocks[0], whole[0])
    np.testing.assert_array_equal(in_blocks[1], whole[1])
