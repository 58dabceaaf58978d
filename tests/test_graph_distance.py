import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

import spidermatch.geometry.graph_distance as graph_distance
from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.graph_distance import graph_distances_between


@pytest.fixture(scope="module")
def creature():
    return make_creature(1500, seed=3).mesh


def full_graph_distances(mesh, a, b, limit):
    """Dijkstra on the whole edge graph from every start, read at the pairs (the slow reference)."""
    starts, inverse = np.unique(a, return_inverse=True)
    return dijkstra(mesh.edge_graph(), indices=starts, limit=limit)[inverse, b]


def nearby_pairs(mesh, n, spread, seed=0):
    """Random start vertices, each with a vertex near a point ``spread`` away from it in space."""
    rng = np.random.default_rng(seed)
    a = rng.integers(mesh.n_verts, size=n)
    offsets = rng.normal(scale=spread, size=(n, 3))
    b = mesh.vertex_tree.query(mesh.verts[a] + offsets)[1]
    return a, np.asarray(b, dtype=np.int64)


@pytest.mark.parametrize("block_cells", [graph_distance.BLOCK_CELLS, 300])
def test_local_search_gives_the_whole_graphs_distances_up_to_the_limit(creature, block_cells, monkeypatch):
    monkeypatch.setattr(graph_distance, "BLOCK_CELLS", block_cells)  # 300: blocks split to single starts
    limit = 0.05 * np.sqrt(creature.area)
    a, b = nearby_pairs(creature, 3000, limit / 2)
    ours = graph_distances_between(creature, a, b, limit)
    reference = full_graph_distances(creature, a, b, limit)
    assert np.array_equal(np.isinf(ours), np.isinf(reference))
    assert np.isfinite(ours).mean() > 0.3 and np.isinf(ours).mean() > 0.05  # both kinds are checked
    np.testing.assert_allclose(ours[np.isfinite(ours)], reference[np.isfinite(reference)], rtol=1e-12)


def test_equal_and_adjacent_vertices_and_far_pairs(creature):
    edge = creature.edges[0]
    length = float(np.linalg.norm(creature.verts[edge[0]] - creature.verts[edge[1]]))
    far = int(np.argmax(np.linalg.norm(creature.verts - creature.verts[edge[0]], axis=1)))
    a = np.array([edge[0], edge[0], edge[1], edge[0]])
    b = np.array([edge[0], edge[1], edge[0], far])
    out = graph_distances_between(creature, a, b, limit=2 * length)
    np.testing.assert_allclose(out[:3], [0.0, length, length])
    assert np.isinf(out[3])
    assert np.isinf(graph_distances_between(creature, a[1:2], b[1:2], limit=0.5 * length)).all()


def test_greedy_walks_bound_the_distance_from_above_and_usually_arrive(creature):
    from spidermatch.geometry.graph_distance import greedy_path_lengths

    limit = 0.05 * np.sqrt(creature.area)
    a, b = nearby_pairs(creature, 2000, limit / 3, seed=1)
    walked = greedy_path_lengths(creature, a, b, 2 * limit)
    exact = full_graph_distances(creature, a, b, np.inf)
    arrived = np.isfinite(walked)
    assert arrived.mean() > 0.8
    assert (walked[arrived] >= exact[arrived] - 1e-12).all()
    assert (walked[arrived] <= 2 * limit).all()


def test_farther_than_answers_as_the_exact_distances_do(creature):
    from spidermatch.geometry.graph_distance import farther_than

    limit = 0.05 * np.sqrt(creature.area)
    a, b = nearby_pairs(creature, 3000, limit / 2, seed=2)
    bound = np.random.default_rng(2).uniform(0.3, 1.0, size=len(a)) * limit
    exact = full_graph_distances(creature, a, b, np.inf)
    answer = farther_than(creature, a, b, bound)
    np.testing.assert_array_equal(answer, exact > bound)
    assert 0.1 < answer.mean() < 0.9


def test_on_a_noisy_surface_most_pairs_are_settled_by_short_searches(creature, monkeypatch):
    """Noise as large as the edges stalls the greedy walk; a search up to the bound around every
    such pair would cover thousands of vertices each. Short searches settle most, exactly."""
    from spidermatch.geometry.graph_distance import farther_than

    rng = np.random.default_rng(4)
    edge = float(np.median(creature.edge_lengths))
    noisy = creature.with_positions(creature.verts + rng.normal(scale=1.5 * edge, size=creature.verts.shape))
    a, b = nearby_pairs(noisy, 2000, 2 * edge, seed=4)
    bound = rng.uniform(15, 25, size=len(a)) * float(np.median(noisy.edge_lengths))
    searched = []
    exact_search = graph_distance.graph_distances_between

    def recording(mesh, a, b, limit):
        searched.append((limit, len(a)))
        return exact_search(mesh, a, b, limit)

    monkeypatch.setattr(graph_distance, "graph_distances_between", recording)
    answer = farther_than(noisy, a, b, bound)
    np.testing.assert_array_equal(answer, full_graph_distances(noisy, a, b, np.inf) > bound)
    first_limit, stalled = searched[0]
    longest_limit, still_open = searched[-1]
    assert stalled > 0.3 * len(a)  # the greedy walk stalled for these
    assert first_limit < 0.5 * bound.min() and longest_limit == bound.max()
    assert still_open < 0.1 * stalled
