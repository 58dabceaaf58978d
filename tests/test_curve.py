import numpy as np
import pytest

from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.remesh import decimate
from spidermatch.model.curve import (
    CurveError,
    SpiderCurve,
    check_curve,
    greedy_perfect_matching,
    spider_curve,
)


@pytest.mark.parametrize("augmented", [False, True])
@pytest.mark.parametrize("matching", ["greedy", "blossom"])
@pytest.mark.parametrize("shape_seed, faces", [(7, 200), (11, 120), (3, 300)])
def test_spider_curve_invariants(augmented, matching, shape_seed, faces):
    mesh = decimate(make_creature(1500, shape_seed).mesh, faces).mesh
    curve = spider_curve(mesh, augmented=augmented, seed=3, matching=matching)
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


def test_greedy_matching_is_perfect_and_improved_by_exchanges():
    rng = np.random.default_rng(0)
    points = rng.uniform(size=(40, 2))
    distances = np.linalg.norm(points[:, None] - points[None], axis=2)
    odd = np.sort(rng.choice(40, size=20, replace=False))
    pairs = greedy_perfect_matching(distances, odd)
    assert sorted(v for pair in pairs for v in pair) == odd.tolist()  # every odd vertex exactly once
    no_exchange = greedy_perfect_matching(distances, odd, max_passes=0)
    assert sum(distances[a, b] for a, b in pairs) <= sum(distances[a, b] for a, b in no_exchange) + 1e-12
    # a 2-opt local optimum: no exchange of two pairs shortens it
    for a, b in pairs:
        for c, d in pairs:
            if {a, b} != {c, d}:
                assert distances[a, c] + distances[b, d] >= distances[a, b] + distances[c, d] - 1e-9 or (
                    c not in np.asarray(odd)[np.argsort(distances[np.ix_([a], odd)][0])[1:11]]
                )


def test_unknown_matching_is_rejected():
    mesh = decimate(make_creature(1500, 7).mesh, 100).mesh
    with pytest.raises(ValueError, match="unknown curve matching"):
        spider_curve(mesh, matching="fastest")
