from dataclasses import replace

import numpy as np
import pytest

from spidermatch.solve.colgen import generate_columns
from spidermatch.solve.fixing import sign_corrected_duals
from spidermatch.solve.path_costs import path_reduced_costs
from spidermatch.solve.plain import solve_plain
from spidermatch.solve.pricing import price, with_path_reduced_costs
from spidermatch.solve.seeds import stay_seed
from spidermatch.solve.types import SolverOptions
from tests.test_colgen import creature_lazy, tiny_lazy
from tests.test_ilp import checked_walks

EXACT = SolverOptions(mip_rel_gap=0.0)


def lp_duals(lazy):
    seed = np.union1d(stay_seed(lazy), np.arange(0, lazy.n_vars, 7))
    return generate_columns(lazy, seed, EXACT).y


def assert_bounds_every_walk(lazy, walks, y, cutoff):
    """Every walk (edge-id lists) costs at least L(y) + R_j for each of its columns j in the pass."""
    priced = price(lazy, y, cutoff)
    path_costs = path_reduced_costs(lazy.graph, priced.columns, priced.reduced, priced.cutoff)
    position = np.full(lazy.n_vars, -1)
    position[priced.columns] = np.arange(priced.columns.size)
    for ids in walks:
        cost = lazy.costs(np.array(ids)).sum()
        inside = position[ids][position[ids] >= 0]
        if inside.size:
            assert cost >= priced.bound + path_costs[inside].max() - 1e-9
        if inside.size < len(ids):  # a column outside the pass: its reduced cost is above the cutoff
            assert cost >= priced.bound + priced.cutoff - 1e-9


@pytest.mark.parametrize("curve_vertices", [[0, 1, 0, 2], [0, 1, 2, 3], [0, 1, 2, 1], [0, 1]])
@pytest.mark.parametrize("seed", [0, 1])
def test_path_reduced_costs_bound_every_checked_walk_for_lp_and_random_multipliers(curve_vertices, seed):
    lazy = tiny_lazy(curve_vertices, seed)
    model = lazy.full_model()
    rng = np.random.default_rng(seed)
    random = [sign_corrected_duals(model, rng.normal(0, 0.3, model.n_rows)) for _ in range(3)]
    multipliers = [lp_duals(lazy), *random]
    walks = checked_walks(lazy.curve, lazy.graph)
    assert walks
    for y in multipliers:
        for cutoff in (0.0, 0.2, 1.0, 10.0):  # distances capped by a low cutoff must stay valid
            assert_bounds_every_walk(lazy, walks, y, cutoff)


def test_path_reduced_costs_are_never_below_reduced_costs_and_often_above(rng):
    lazy = creature_lazy(24, 3)
    y = lp_duals(lazy)
    priced = price(lazy, y, 0.5)
    path_costs = path_reduced_costs(lazy.graph, priced.columns, priced.reduced, priced.cutoff)
    assert (path_costs >= np.maximum(priced.reduced, 0.0) - 1e-12).all()
    assert (path_costs > np.maximum(priced.reduced, 0.0) + 1e-9).mean() > 0.5
    assert (path_costs <= 3 * priced.cutoff + 1e-9).all()  # each distance is capped at the cutoff


def test_a_pass_by_path_keeps_its_columns_bound_and_min_outside():
    lazy = creature_lazy(24, 3)
    priced = price(lazy, lp_duals(lazy), 0.3)
    pathed = with_path_reduced_costs(lazy, priced)
    np.testing.assert_array_equal(pathed.columns, priced.columns)
    kept = (pathed.bound, pathed.cutoff, pathed.min_outside)
    assert kept == (priced.bound, priced.cutoff, priced.min_outside)
    assert (pathed.reduced >= priced.reduced - 1e-12).all()


@pytest.mark.parametrize("seed", [3, 5])
def test_path_reduced_costs_bound_the_optimum_through_each_column(seed):
    """On creature pairs: the cheapest solution that uses column j costs at least L(y) + R_j.

    Column j is forced in by lowering its cost by a constant larger than any solution's cost.
    """
    lazy = creature_lazy(18, seed)
    priced = price(lazy, lp_duals(lazy), 1.0)
    path_costs = path_reduced_costs(lazy.graph, priced.columns, priced.reduced, priced.cutoff)
    model = lazy.full_model()
    reward = 10.0 * model.costs.sum()
    checked = np.argsort(path_costs)[-2:]  # the strongest bounds, where an error would show
    for k in checked:
        costs = model.costs.copy()
        costs[priced.columns[k]] -= reward
        result = solve_plain(replace(model, costs=costs), lazy.graph, lazy.curve, EXACT)
        assert result.status == "optimal" and result.x[priced.columns[k]] > 0.5
        assert result.objective + reward >= priced.bound + path_costs[k] - 1e-7
        assert path_costs[k] > max(priced.reduced[k], 0.0) + 1e-6  # stronger than reduced-cost fixing here


@pytest.mark.parametrize("seed", [0, 1])
def test_dual_bound_along_paths_bounds_every_checked_walk_and_keeps_columns_above_the_cutoff(seed):
    """rcfix's form (full reduced-cost vector): brute force over the walks of a tiny instance."""
    from spidermatch.solve.fixing import dual_bound

    lazy = tiny_lazy([0, 1, 0, 2], seed)
    model = lazy.full_model()
    rng = np.random.default_rng(seed)
    walks = checked_walks(lazy.curve, lazy.graph)
    for y in [lp_duals(lazy), rng.normal(0, 0.3, model.n_rows)]:
        dual = dual_bound(model, y)
        for cutoff in (0.0, 0.3, 5.0):
            along = dual.along_paths(lazy.graph, cutoff)
            assert along.bound == dual.bound
            above = dual.reduced > cutoff
            np.testing.assert_array_equal(along.reduced[above], dual.reduced[above])
            assert (along.column_bounds() >= dual.column_bounds() - 1e-12).all()
            for ids in walks:
                cost = lazy.costs(np.array(ids)).sum()
                assert cost >= along.column_bounds()[ids].max() - 1e-9


def test_by_path_leaves_a_model_without_closed_paths_alone():
    from spidermatch.model.lazy_model import LazyModel

    lazy = creature_lazy(18, 3)
    no_con = LazyModel(
        lazy.graph, lazy.curve, lazy.source_verts, lazy.target_verts, lazy.vertex_costs, ("CYC", "PES")
    )
    y = np.zeros(no_con.n_rows)
    priced = price(no_con, y, 0.5)
    assert with_path_reduced_costs(no_con, priced) is priced
