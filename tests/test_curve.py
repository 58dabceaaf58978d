import numpy as np
import pytest

from spidermatch.curve import CurveError, SpiderCurve, check_curve, spider_curve
from spidermatch.remesh import decimate
from spidermatch.synthetic import make_creature


@pytest.mark.parametrize("augmented", [False, True])
def test_spider_curve_invariants(augmented):
    mesh = decimate(make_creature(1500, 7).mesh, 200).mesh
    curve = spider_curve(mesh, augmented=augmented, seed=3)
    c = curve.vertices
    assert set(c.tolist()) == set(range(mesh.n_verts))  # covers every vertex
    assert np.all(c != np.roll(c, -1))
    edges = {tuple(e) for e in (mesh.augmented_edges if augmented else mesh.edges).tolist()}
    steps = np.sort(np.stack([c, np.roll(c, -1)], axis=1), axis=1)
    assert all(tuple(s) in edges for s in steps.tolist())  # consecutive entries adjacent, cyclic
    assert mesh.n_verts <= curve.length <= 2 * mesh.n_verts
    # self-intersections are exactly the repeated vertices; duplicates point back to their first layer
    counts = np.bincount(c)
    np.testing.assert_array_equal(curve.intersections, np.flatnonzero(counts > 1))
    assert curve.duplicate_layers.size == curve.length - mesh.n_verts
    assert np.all(c[curve.first_layer] == c)


def test_spider_curve_is_deterministic_per_seed():
    mesh = decimate(make_creature(1500, 8).mesh, 150).mesh
    first, again = spider_curve(mesh, seed=1), spider_curve(mesh, seed=1)
    np.testing.assert_array_equal(first.vertices, again.vertices)


def test_check_curve_rejects_gaps_and_jumps():
    edges = np.array([[0, 1], [1, 2], [0, 2], [2, 3]])
    check_curve(SpiderCurve(np.array([0, 1, 2, 3, 2]), 4), edges)
    with pytest.raises(CurveError, match="misses 1 vertices"):
        check_curve(SpiderCurve(np.array([0, 1, 2]), 4), edges)
    with pytest.raises(CurveError, match="not an edge"):
        check_curve(SpiderCurve(np.array([0, 1, 3, 2]), 4), edges)
