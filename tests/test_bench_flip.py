"""The mirrored-match test of bench/bench_flip_errors.py on a left-right symmetric grid."""

import numpy as np
from bench_flip_errors import mirrored_matches, turn_about_vertical
from scipy.spatial.transform import Rotation

from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.mesh import Mesh
from train.data import ValShape


def _grid() -> Mesh:
    """A flat 5 x 3 grid, x in [1, 3] (symmetric about x = 2), y in [0, 1]."""
    xs, ys = np.linspace(1.0, 3.0, 5), np.linspace(0.0, 1.0, 3)
    verts = np.array([[x, y, 0.0] for y in ys for x in xs])
    faces = []
    for row in range(2):
        for col in range(4):
            a = row * 5 + col
            faces += [[a, a + 1, a + 6], [a, a + 6, a + 5]]
    return Mesh(verts, np.array(faces), "grid")


def test_mirror_images_are_recognised_and_near_misses_are_not():
    mesh = _grid()
    shape = ValShape("grid", mesh, None, np.arange(mesh.n_verts))
    rows = np.arange(mesh.n_verts)
    column = rows % 5
    mirror = rows - column + (4 - column)  # same row, column reflected about the centre
    off_centre = column != 2
    assert mirrored_matches(shape, rows, mirror, axis=0)[off_centre].all()
    assert not mirrored_matches(shape, rows, rows, axis=0)[off_centre].any()  # correct matches
    shifted = np.where(column == 0, rows + 1, rows)  # one column off, not mirrored
    assert not mirrored_matches(shape, rows, shifted, axis=0)[column == 0].any()
    assert not mirrored_matches(shape, rows, mirror, axis=1)[off_centre & (rows // 5 != 1)].any()


def test_turn_about_the_vertical_axis_is_measured():
    creature = make_creature(n_verts=300, seed=2).mesh
    turned_verts = creature.verts @ Rotation.from_euler("y", 100, degrees=True).as_matrix().T + 5.0
    turned = Mesh(turned_verts, creature.faces, "turned")
    corr = np.arange(creature.n_verts)
    reference, shape = ValShape("a", creature, None, corr), ValShape("b", turned, None, corr)
    assert abs(turn_about_vertical(reference, shape) - 100.0) < 1e-6
    assert abs(turn_about_vertical(reference, reference)) < 1e-6
