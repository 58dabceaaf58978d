import numpy as np
import pytest

from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.remesh import decimate
from spidermatch.model.costs import RobustLoss, feature_cost_matrix, product_edge_costs
from spidermatch.model.curve import spider_curve
from spidermatch.model.ilp import build_model
from spidermatch.model.lazy_model import LazyModel
from spidermatch.model.product_graph import build_product_graph


def small_problem(families=("CYC", "CON", "PES", "ANS"), faces=60, seed=5):
    source = decimate(make_creature(800, seed).mesh, faces).mesh
    target = decimate(make_creature(800, seed + 1).mesh, faces).mesh
    rng = np.random.default_rng(seed)
    features_x = rng.normal(size=(source.n_verts, 6))
    features_y = rng.normal(size=(target.n_verts, 6))
    curve = spider_curve(source, seed=0)
    graph = build_product_graph(curve.length, target.n_verts, target.edges)
    vertex_costs = feature_cost_matrix(features_x, features_y, RobustLoss())
    lazy = LazyModel(graph, curve, source.verts, target.verts, vertex_costs, families)
    costs = product_edge_costs(graph, curve.vertices, source.verts, target.verts, vertex_costs)
    return lazy, build_model(graph, curve, costs, families)


@pytest.mark.parametrize("families", [("CYC", "CON", "PES", "ANS"), ("CYC", "CON"), ("CYC", "CON", "ANS")])
def test_submodel_of_all_columns_is_the_full_model(families):
    lazy, model = small_problem(families)
    assert lazy.curve.duplicate_layers.size > 0  # PES rows exist
    sub = lazy.submodel(np.arange(lazy.n_vars))
    assert sub.row_families == model.row_families
    np.testing.assert_allclose(sub.costs, model.costs, rtol=1e-12)
    np.testing.assert_array_equal(sub.row_lower, model.row_lower)
    np.testing.assert_array_equal(sub.row_upper, model.row_upper)
    assert (sub.matrix != model.matrix).nnz == 0


def test_submodel_columns_are_the_full_models_columns():
    lazy, model = small_problem()
    columns = np.sort(np.random.default_rng(0).choice(lazy.n_vars, size=500, replace=False))
    sub = lazy.submodel(columns)
    assert (sub.matrix != model.matrix[:, columns]).nnz == 0
    np.testing.assert_allclose(sub.costs, model.costs[columns], rtol=1e-12)


def test_block_reduced_costs_equal_c_minus_a_transpose_y():
    lazy, model = small_problem()
    y = np.random.default_rng(1).normal(size=model.n_rows)
    expected = model.costs - model.matrix.T @ y
    potentials = lazy.potentials(y)
    got = np.concatenate([lazy.block_reduced_costs(a, b, potentials) for a, b in lazy.layer_blocks(7)])
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-10)


def test_blockwise_full_model_equals_build_model():
    lazy, model = small_problem()
    blockwise = lazy.full_model(block_columns=5 * lazy.graph.block_size + 3)  # uneven blocks
    assert blockwise.matrix.indices.dtype == np.int32
    assert (blockwise.matrix != model.matrix).nnz == 0
    np.testing.assert_allclose(blockwise.costs, model.costs, rtol=1e-12)
    assert blockwise.row_families == model.row_families


def test_compact_submodel_drops_only_rows_that_zero_satisfies_and_keeps_every_optimum():
    from spidermatch.solve.highs import HighsSession
    from spidermatch.solve.types import SolverOptions

    lazy, _ = small_problem()
    rng = np.random.default_rng(2)
    columns = np.sort(rng.choice(lazy.n_vars, lazy.n_vars // 3, replace=False))
    full_rows, compact = lazy.submodel(columns), lazy.compact_submodel(columns)
    assert compact.n_rows < full_rows.n_rows
    dropped = np.setdiff1d(np.arange(full_rows.n_rows), np.unique(full_rows.matrix.indices))
    assert compact.n_rows == full_rows.n_rows - dropped.size + np.sum(full_rows.row_lower[dropped] > 0)
    assert sum(stop - start for start, stop in compact.row_families.values()) == compact.n_rows
    for relax in (True, False):
        values = [
            HighsSession(m, SolverOptions(mip_rel_gap=0.0), relax=relax).run() for m in (full_rows, compact)
        ]
        assert values[0].status == values[1].status
        if values[0].status == "optimal":
            assert values[1].objective == pytest.approx(values[0].objective, rel=1e-9)


def test_compact_submodel_keeps_the_cycle_row_of_a_layer_without_columns():
    from spidermatch.solve.highs import HighsSession
    from spidermatch.solve.types import SolverOptions

    lazy, _ = small_problem()
    block = lazy.graph.block_size
    columns = np.arange(block, lazy.n_vars)  # layer 0 has no column: CYC row 0 reads 0 = 1
    compact = lazy.compact_submodel(columns)
    start, _ = compact.row_families["CYC"]
    assert compact.row_lower[start] == 1.0 and compact.matrix[start].nnz == 0
    assert HighsSession(compact, SolverOptions(), relax=True).run().status == "infeasible"
