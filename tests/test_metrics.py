import numpy as np
import pytest
from scipy.spatial import cKDTree

from spidermatch.eval.metrics import (
    TEAR_THRESHOLD,
    consistency,
    flipped_faces,
    geodesic_errors,
    torn_edges,
    vertex_map_consistency,
)
from spidermatch.geometry.surface import vertex_points
from tests.conftest import icosphere


@pytest.fixture(scope="module")
def sphere():
    return icosphere(4)


def nearest_vertex_map(mesh, positions):
    return np.asarray(cKDTree(mesh.verts).query(positions)[1], dtype=np.int64)


def test_identity_has_no_tears_no_flips_and_no_error(sphere):
    identity = np.arange(sphere.n_verts)
    figures = vertex_map_consistency(sphere, sphere, identity)
    assert figures.tears == 0 and figures.flips == 0
    errors = geodesic_errors({"id": identity}, identity[::50], identity[::50], sphere)
    assert np.all(errors["id"] == 0)


def test_a_cut_and_rotated_half_tears_exactly_the_edges_across_the_cut(sphere):
    upper = sphere.verts[:, 2] > 0
    angle = np.pi / 2
    rotation = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    moved = np.where(upper[:, None], sphere.verts @ rotation.T, sphere.verts)
    mapping = nearest_vertex_map(sphere, moved)
    figures = vertex_map_consistency(sphere, sphere, mapping)
    edges = sphere.edges
    across = upper[edges[:, 0]] != upper[edges[:, 1]]
    face, bary = vertex_points(sphere, mapping)
    torn = torn_edges(sphere, sphere, sphere.verts[mapping], face, bary)
    assert figures.tears > 0
    assert not torn[~across].any()
    # Edges across the cut near the rotation axis stay short; the others tear.
    assert torn[across].mean() > 0.8
    # Below the cut the map is the identity: no flips there (above, snapping to vertices may collapse some).
    flipped, degenerate = flipped_faces(sphere, sphere, sphere.verts[mapping], face, bary)
    below = ~upper[sphere.faces].any(axis=1)
    assert not (flipped | degenerate)[below].any()


def test_a_mirror_map_flips_every_triangle_and_tears_nothing(sphere):
    mirrored = sphere.verts * np.array([-1.0, 1.0, 1.0])
    figures = vertex_map_consistency(sphere, sphere, nearest_vertex_map(sphere, mirrored))
    assert figures.tears == 0
    assert figures.flipped > 0.95 and figures.flips > 0.95


def test_collapsed_triangles_count_as_degenerate(sphere):
    collapsed = np.zeros(sphere.n_verts, dtype=np.int64)
    figures = vertex_map_consistency(sphere, sphere, collapsed)
    assert figures.degenerate == 1.0 and figures.flips == 1.0 and figures.tears == 0


def hairpin_strip(radius: float = 0.01, width: float = 0.2):
    """An open strip folded into a hairpin: two 1-long arms 2*radius apart, joined by a half circle."""
    from spidermatch.geometry.mesh import Mesh

    straight = np.linspace(0.0, 1.0, 101)
    turn = np.linspace(0.0, np.pi, 9)[1:-1]
    centre = np.concatenate(
        [
            np.stack([straight, np.zeros_like(straight)], axis=1),
            np.stack([1.0 + radius * np.sin(turn), radius - radius * np.cos(turn)], axis=1),
            np.stack([straight[::-1], np.full_like(straight, 2 * radius)], axis=1),
        ]
    )
    heights = np.linspace(0.0, width, 21)
    verts = np.array([[cx, cy, z] for cx, cy in centre for z in heights])
    rows, cols = len(centre), len(heights)
    index = np.arange(rows * cols).reshape(rows, cols)
    a, b, c, d = index[:-1, :-1], index[1:, :-1], index[1:, 1:], index[:-1, 1:]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return Mesh(verts, faces, "hairpin"), index


def test_geodesic_check_catches_tears_that_are_short_in_space():
    strip, index = hairpin_strip()
    threshold = TEAR_THRESHOLD * np.sqrt(strip.area)
    assert 0.02 < threshold  # the arms are closer in space than the threshold
    rows = index.shape[0]
    mapping = np.arange(strip.n_verts).reshape(index.shape)
    cut = rows // 4
    mapping[:cut] = index[::-1][:cut]  # the first quarter of arm one goes onto arm two
    mapping = mapping.reshape(-1)
    points = strip.verts[mapping]
    figures = consistency(strip, strip, points)
    edges = strip.edges
    crossing = (edges // index.shape[1]).min(axis=1) == cut - 1
    crossing &= (edges // index.shape[1]).max(axis=1) == cut
    short = np.linalg.norm(points[edges[:, 0]] - points[edges[:, 1]], axis=1) <= threshold
    assert crossing.any() and short[crossing].all()  # Euclidean distance would miss them
    face, bary = vertex_points(strip, mapping)
    torn = torn_edges(strip, strip, points, face, bary)
    assert torn[crossing].all() and not torn[~crossing].any()
    assert figures.tears == pytest.approx(crossing.mean())


def test_a_truth_that_jumps_onto_a_touching_part_is_told_from_its_neighbours():
    from spidermatch.eval.metrics import inconsistent_truth

    strip, index = hairpin_strip()  # two arms 0.02 apart in space, about 2 apart along the strip
    refs = np.arange(strip.n_verts)[::3]
    truth = refs.copy()
    assert not inconsistent_truth(strip, strip, refs, truth).any()
    facing = np.arange(strip.n_verts).reshape(index.shape)[::-1].reshape(-1)  # the vertex across the gap
    jumped = np.flatnonzero(np.isin(refs, index[30:32, 8:10]))  # a few points in the middle of arm one
    truth[jumped] = facing[refs[jumped]]
    flagged = inconsistent_truth(strip, strip, refs, truth)
    np.testing.assert_array_equal(np.flatnonzero(flagged), jumped)
