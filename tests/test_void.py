"""The void vertex of partial-to-partial matching (spidermatch.model.void): costs, rows and optima."""

import numpy as np
import pytest

from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.mesh import boundary_vertices
from spidermatch.geometry.partial import plane_cut
from spidermatch.geometry.remesh import decimate
from spidermatch.model.curve import spider_curve
from spidermatch.model.lazy_model import LazyModel
from spidermatch.model.product_graph import INTRA, STAY, build_product_graph
from spidermatch.model.void import matched_curve_vertices, void_cost, void_layers, with_void
from spidermatch.solve.strategies import solve_with_strategy
from spidermatch.solve.types import SolverOptions

EXACT = SolverOptions(mip_rel_gap=0.0)


def cut_meshes(faces=80, seed=2):
    """A creature and a plane cut of another (the target, with a boundary), decimated."""
    source = decimate(make_creature(600, seed=seed).mesh.centred(), faces).mesh
    whole = make_creature(600, seed=seed + 1).mesh.centred()
    target = decimate(plane_cut(whole, np.array([0.0, 1.0, 0.0]), 0.6, "cut").mesh, faces).mesh
    return source, target


def cut_problem(void_factor=None, faces=80, seed=2):
    """The LazyModel of :func:`cut_meshes` with random feature costs, with a void vertex unless no factor."""
    source, target = cut_meshes(faces, seed)
    curve = spider_curve(source, seed=0)
    vertex_costs = np.random.default_rng(seed).uniform(0.05, 1.0, (source.n_verts, target.n_verts))
    if void_factor is None:
        graph = build_product_graph(curve.length, target.n_verts, target.edges)
        return LazyModel(graph, curve, source.verts, target.verts, vertex_costs)
    boundary = boundary_vertices(target.faces)
    void = with_void(target.verts, boundary, vertex_costs, void_cost(vertex_costs, void_factor))
    graph = build_product_graph(curve.length, void.n_target, target.edges, void.crossing_edges)
    return LazyModel(graph, curve, source.verts, void.verts, void.vertex_costs, void_vertex=void.void)


def test_the_void_is_entered_only_from_the_boundary_while_the_curve_advances():
    lazy = cut_problem(void_factor=2.0)
    graph, void = lazy.graph, lazy.void_vertex
    touches = (graph.block_src == void) | (graph.block_dst == void)
    assert not np.any(touches & (graph.block_kind == INTRA))
    others = np.where(graph.block_src == void, graph.block_dst, graph.block_src)[touches]
    boundary = set(boundary_vertices(cut_meshes()[1].faces).tolist())
    assert set(others.tolist()) == boundary | {void}  # the boundary both ways, and the void's stay edge
    assert np.count_nonzero(touches & (graph.block_kind == STAY)) == 1


def test_an_edge_into_the_void_costs_the_source_step_only_and_no_ans_row_counts_it():
    lazy = cut_problem(void_factor=2.0)
    graph, void, c = lazy.graph, lazy.void_vertex, lazy.curve.vertices
    model = lazy.full_model()
    layer, entry = np.divmod(np.arange(lazy.n_vars), graph.block_size)
    into = np.flatnonzero((graph.block_dst[entry] == void) & (graph.block_kind[entry] != STAY))
    p, q = c[layer[into]], c[(layer[into] + 1) % graph.n_layers]
    step = np.linalg.norm(lazy.source_verts[p] - lazy.source_verts[q], axis=1)
    lam = lazy.vertex_costs[0, void]
    expected = step * (lazy.vertex_costs[p, graph.block_src[entry[into]]] + lam)
    np.testing.assert_allclose(model.costs[into], expected, rtol=1e-12)
    start, _ = model.row_families["ANS"]
    assert model.matrix[start + void].nnz == 0  # any number of curve vertices may have no partner


def test_a_costly_void_gives_the_plain_optimum_and_a_cheap_one_the_all_void_path():
    lazy_plain = cut_problem()
    plain = solve_with_strategy("colgen", lazy_plain, lazy_plain.graph, lazy_plain.curve, EXACT)
    costly = cut_problem(void_factor=1e4)
    with_costly = solve_with_strategy("colgen", costly, costly.graph, costly.curve, EXACT)
    assert plain.status == with_costly.status == "optimal"
    assert with_costly.objective == pytest.approx(plain.objective, rel=1e-9)
    assert not void_layers(costly.graph, with_costly.x, costly.void_vertex).any()
    cheap = cut_problem(void_factor=1e-3)
    with_cheap = solve_with_strategy("colgen", cheap, cheap.graph, cheap.curve, EXACT)
    in_void = void_layers(cheap.graph, with_cheap.x, cheap.void_vertex)
    assert in_void.all()
    c = cheap.curve.vertices
    length = np.linalg.norm(cheap.source_verts[c] - cheap.source_verts[np.roll(c, -1)], axis=1).sum()
    assert with_cheap.objective == pytest.approx(
        2 * cheap.vertex_costs[0, cheap.void_vertex] * length, rel=1e-9
    )
    assert not matched_curve_vertices(c, in_void, cheap.vertex_costs.shape[0]).any()


@pytest.mark.parametrize("factor", [2.0, 4.0])
def test_colgen_and_the_full_model_agree_on_the_void_optimum(factor):
    lazy = cut_problem(void_factor=factor, faces=60)
    colgen = solve_with_strategy("colgen", lazy, lazy.graph, lazy.curve, EXACT)
    plain = solve_with_strategy("plain", lazy.full_model(), lazy.graph, lazy.curve, EXACT)
    assert colgen.status == plain.status == "optimal"
    assert colgen.objective == pytest.approx(plain.objective, rel=1e-9)
    in_void = void_layers(lazy.graph, colgen.x, lazy.void_vertex)
    assert 0 < in_void.sum() < in_void.size  # a matching with some of the curve in the void
    # a self-intersection of the curve is in the void on both passes or on neither
    for vertex in np.unique(lazy.curve.vertices[lazy.curve.duplicate_layers]):
        layers = np.flatnonzero(lazy.curve.vertices == vertex)
        assert in_void[layers].all() or not in_void[layers].any()


def test_the_void_cost_follows_the_cheapest_partners():
    costs = np.array([[1.0, 2.0], [3.0, 0.5], [4.0, 4.0]])
    assert void_cost(costs, 2.0) == pytest.approx(2.0 * 1.0)  # median of 1, 0.5, 4
    with pytest.raises(ValueError, match="positive"):
        void_cost(costs, 0.0)


def test_the_void_cost_may_differ_per_source_vertex():
    costs = np.arange(6.0).reshape(3, 2)
    per_vertex = with_void(np.zeros((2, 3)), np.array([0]), costs, np.array([1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(per_vertex.vertex_costs[:, 2], [1.0, 2.0, 3.0])
    everywhere = with_void(np.zeros((2, 3)), np.array([0]), costs, 0.5)
    np.testing.assert_array_equal(everywhere.vertex_costs[:, 2], 0.5)
    np.testing.assert_array_equal(everywhere.vertex_costs[:, :2], costs)
