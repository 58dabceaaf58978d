import numpy as np
import pytest
from conftest import icosphere
from scipy.spatial import cKDTree

from spidermatch.data.synthetic import creature_pair_ground_truth, make_creature
from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.surface import occluded
from spidermatch.report.colours import (
    checker_colours,
    greyed_uncovered,
    map_pairs,
    position_colours,
    spread_to_vertices,
    transfer_colours,
)
from spidermatch.report.plot import (
    save_correspondence_png,
    save_curve_png,
    save_error_png,
    save_texture_png,
    short_label,
    title_lines,
)
from spidermatch.report.render import View, project


@pytest.fixture(scope="module")
def creatures():
    source, target = make_creature(600, seed=0), make_creature(600, seed=1)
    return source.mesh, target.mesh, creature_pair_ground_truth(source, target)


@pytest.fixture(scope="module")
def symmetric_body() -> Mesh:
    """An ellipsoid, mirror-symmetric in x (left-right) and z (front-back), taller than wide."""
    sphere = icosphere(4)
    return Mesh(sphere.verts * np.array([0.8, 2.0, 0.4]), sphere.faces, "ellipsoid")


def mirror_partner(mesh: Mesh, axis: int) -> np.ndarray:
    """For each vertex, the vertex nearest its mirror image across the plane ``axis`` = 0, shape (V,)."""
    mirrored = mesh.verts.copy()
    mirrored[:, axis] *= -1
    return cKDTree(mesh.verts).query(mirrored)[1]


def rgb_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a - b, axis=1)


# RGB distances of a flip: the earlier scheme (RGB = normalised position) gave a median of 0.64
# and a mean of 0.43 for both flips; the hue wheel gives 1.02 / 0.81 (left-right), 0.74 / 0.47 (front-back).
@pytest.mark.parametrize(
    "axis, median_at_least, mean_at_least", [(0, 0.8, 0.6), (2, 0.6, 0.4)], ids=["left-right", "front-back"]
)
def test_a_mirrored_map_visibly_changes_the_colours(symmetric_body, axis, median_at_least, mean_at_least):
    colours = position_colours(symmetric_body.verts)
    flipped = transfer_colours(colours, symmetric_body, mirror_partner(symmetric_body, axis))
    identity = transfer_colours(colours, symmetric_body, np.arange(symmetric_body.n_verts))
    np.testing.assert_allclose(identity, colours)
    distance = rgb_distance(flipped, colours)
    # far from the mirror plane, the flipped colour is clearly another colour
    away = np.abs(symmetric_body.verts[:, axis]) > 0.5 * np.abs(symmetric_body.verts[:, axis]).max()
    assert np.median(distance[away]) > median_at_least
    assert np.mean(distance) > mean_at_least


def test_colours_are_valid_rgb_and_lighter_higher_up(symmetric_body):
    colours = position_colours(symmetric_body.verts)
    assert colours.shape == (symmetric_body.n_verts, 3)
    assert colours.min() >= 0 and colours.max() <= 1
    height = symmetric_body.verts[:, 1]
    assert colours[height > 1.5].mean() > colours[height < -1.5].mean() + 0.15


def test_dense_transfer_averages_and_fills_unmapped_from_the_nearest_mapped_vertex():
    target = icosphere(2)
    colours = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    top = int(np.argmax(target.verts[:, 1]))
    bottom = int(np.argmin(target.verts[:, 1]))
    result = transfer_colours(colours, target, np.array([top, top, bottom]))
    np.testing.assert_allclose(result[top], [0.5, 0.0, 0.5])
    np.testing.assert_allclose(result[bottom], [0.0, 1.0, 0.0])
    upper = target.verts[:, 1] > 0.3
    lower = target.verts[:, 1] < -0.3
    assert np.allclose(result[upper], [0.5, 0.0, 0.5]) and np.allclose(result[lower], [0.0, 1.0, 0.0])


def test_sparse_pairs_and_dense_map_agree_when_they_are_the_same_map(creatures):
    source, target, truth = creatures
    colours = position_colours(source.verts)
    pairs = np.stack([np.arange(source.n_verts), truth], axis=1)
    np.testing.assert_allclose(
        transfer_colours(colours, target, truth), transfer_colours(colours, target, pairs)
    )


def test_bad_maps_are_refused_with_a_clear_message():
    with pytest.raises(ValueError, match="one target vertex per source vertex: got 3 entries for 5"):
        map_pairs(np.zeros(3, dtype=int), 5)
    with pytest.raises(ValueError, match=r"\(V_src,\) or \(source, target\) pairs"):
        map_pairs(np.zeros((4, 3), dtype=int), 5)
    with pytest.raises(ValueError, match="out of range"):
        spread_to_vertices(icosphere(1), np.array([0, 999]), np.ones((2, 1)))
    with pytest.raises(ValueError, match="source vertex out of range"):
        transfer_colours(np.ones((3, 3)), icosphere(1), np.array([[7, 0]]))


def test_short_label_keeps_file_names_and_cuts_the_middle():
    text = "/very/long/folder/FAUST_r/off/tr_reg_070.off -> /another/long/place/tr_reg_071.off"
    assert short_label(text, 80) == "tr_reg_070.off -> tr_reg_071.off"
    cut = short_label("x" * 50 + "MIDDLE" + "y" * 50, 30)
    assert len(cut) == 30 and cut.startswith("xxx") and cut.endswith("yyy") and "\u2026" in cut
    assert short_label("built-in synthetic pair a -> b", 80) == "built-in synthetic pair a -> b"


def test_title_lines_wrap_the_status_at_separators_and_never_cut_it():
    status = "optimal, gap 1.0e-04 | 250 faces, wks features | mean geodesic error 0.2163 over 127 points"
    lines = title_lines("/data/off/tr_reg_070.off -> /data/off/tr_reg_071.off", status, 60)
    assert lines == [
        "tr_reg_070.off -> tr_reg_071.off",
        "optimal, gap 1.0e-04 | 250 faces, wks features",
        "mean geodesic error 0.2163 over 127 points",
    ]
    assert title_lines("", "optimal, gap 0", 5) == ["optimal, gap 0"]


def test_occluded_points_are_those_behind_a_nearer_triangle():
    verts = np.array([[-1.0, -1.0, 0.0], [2.0, -1.0, 0.0], [-1.0, 2.0, 0.0]])
    faces = np.array([[0, 1, 2]])
    points = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [5.0, 5.0, -1.0]])
    np.testing.assert_array_equal(occluded(points, verts, faces, 1e-6), [True, False, False, False])


def test_views_keep_the_up_axis_up():
    rotation = View(37.0, 12.0, "").rotation()
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    top, bottom = project(np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]]), View(37.0, 12.0, ""), np.zeros(3))
    assert top[1] > 0 > bottom[1]


def coloured_rows(path) -> float:
    """Fraction of image rows that contain strongly coloured (mesh) pixels."""
    import matplotlib.image

    image = matplotlib.image.imread(path)[:, :, :3]
    saturated = image.max(axis=2) - image.min(axis=2) > 0.2
    return saturated.any(axis=1).mean()


@pytest.mark.parametrize("form", ["dense", "pairs"])
def test_correspondence_png_fills_its_panels(tmp_path, creatures, form):
    source, target, truth = creatures
    matches = truth if form == "dense" else np.stack([np.arange(0, source.n_verts, 7), truth[::7]], axis=1)
    path = save_correspondence_png(
        source,
        target,
        matches,
        tmp_path / "c.png",
        "/a/long/path/source.off -> /b/target.off",
        "optimal, gap 0",
    )
    assert path.stat().st_size > 10_000
    assert coloured_rows(path) > 0.6


def test_a_checkerboard_crosses_a_smooth_map_whole_and_a_scrambled_one_as_speckle(tmp_path):
    source = icosphere(4)  # 2562 vertices: a cell spans several edges
    checker = checker_colours(source.verts, cells=4)
    dark = checker.max(axis=1) < position_colours(source.verts).max(axis=1) * 0.5
    assert 0.3 < dark.mean() < 0.7  # about half the surface in dark cells
    identity = np.arange(source.n_verts)
    np.testing.assert_allclose(transfer_colours(checker, source, identity), checker)
    scrambled = np.random.default_rng(0).permutation(source.n_verts)

    def broken_edges(colours):  # edges whose two ends fall in cells of different shade
        shade = colours.max(axis=1) < position_colours(source.verts).max(axis=1) * 0.5
        return np.mean(shade[source.edges[:, 0]] != shade[source.edges[:, 1]])

    assert broken_edges(transfer_colours(checker, source, scrambled)) > 2 * broken_edges(checker)
    path = save_texture_png(source, source, identity, tmp_path / "t.png", "texture", "optimal")
    assert path.stat().st_size > 10_000 and coloured_rows(path) > 0.6


def test_the_target_region_a_part_does_not_cover_is_drawn_grey(tmp_path, creatures):
    source, target, truth = creatures
    covered = target.verts[:, 1] > np.median(target.verts[:, 1])
    colours = transfer_colours(position_colours(source.verts), target, truth)
    shaded = greyed_uncovered(colours, covered)
    np.testing.assert_array_equal(shaded[covered], colours[covered])
    outside = shaded[~covered]
    assert (outside.max(axis=1) - outside.min(axis=1)).max() < 0.2  # pale grey, not a colour
    plain = save_correspondence_png(source, target, truth, tmp_path / "plain.png")
    greyed = save_correspondence_png(source, target, truth, tmp_path / "grey.png", target_covered=covered)

    def saturated_pixels(path):
        import matplotlib.image

        image = matplotlib.image.imread(path)[:, :, :3]
        return int((image.max(axis=2) - image.min(axis=2) > 0.2).sum())

    assert saturated_pixels(greyed) < 0.85 * saturated_pixels(plain)


def test_error_png_and_curve_png_are_written(tmp_path, creatures):
    source, _, _ = creatures
    errors = np.linspace(0.0, 0.3, 40)
    path = save_error_png(source, np.arange(40) * 10, errors, tmp_path / "e.png", "pair", "optimal")
    assert path.stat().st_size > 10_000 and coloured_rows(path) > 0.6
    loop = np.array([0, 5, 9, 14, 9, 3])
    curve_path = save_curve_png(source, loop, tmp_path / "s.png", status="optimal, gap 0")
    assert curve_path.stat().st_size > 5_000
