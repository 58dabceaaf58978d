import numpy as np
import pytest

from spidermatch.model.lazy_model import LazyModel
from spidermatch.solve.connectivity import detached_components
from spidermatch.solve.path_seed import cheapest_closed_path, path_plausible
from spidermatch.solve.plain import solve_plain
from spidermatch.solve.seeds import path_band_seed
from spidermatch.solve.types import SolverOptions
from tests.test_colgen import creature_lazy

EXACT = SolverOptions(mip_rel_gap=0.0)


def flow_only(lazy):
    """The same instance with CYC and CON only: a shortest closed path problem."""
    return LazyModel(
        lazy.graph, lazy.curve, lazy.source_verts, lazy.target_verts, lazy.vertex_costs, ("CYC", "CON")
    )


def entry_of_layer_0(lazy, x):
    layer, entry, next_layer = lazy.split(np.flatnonzero(x > 0.5))
    crossing_into_0 = (next_layer == 0) & (layer == lazy.graph.n_layers - 1)
    return int(lazy.graph.block_dst[entry[crossing_into_0]][0])


@pytest.mark.parametrize("seed", [3, 5])
def test_closed_path_is_one_walk_satisfying_cyc_and_con(seed):
    lazy = creature_lazy(24, seed)
    path, cost = cheapest_closed_path(lazy)
    model = flow_only(lazy).submodel(path)
    activity = model.matrix @ np.ones(path.size)
    np.testing.assert_allclose(activity, model.row_lower, atol=1e-12)  # CYC = 1, CON = 0: all equalities
    x = np.zeros(lazy.n_vars)
    x[path] = 1.0
    assert detached_components(lazy.graph, x) == []
    assert cost == pytest.approx(lazy.costs(path).sum())


@pytest.mark.parametrize("seed", [3, 5, 7])
def test_closed_path_is_the_flow_only_optimum_from_that_start(seed):
    flow = flow_only(creature_lazy(24, seed))
    optimum = solve_plain(flow.full_model(), flow.graph, flow.curve, EXACT)
    _, cost = cheapest_closed_path(flow, start_vertex=entry_of_layer_0(flow, optimum.x))
    assert cost == pytest.approx(optimum.objective, rel=1e-9)
    _, from_default = cheapest_closed_path(flow)
    assert from_default >= optimum.objective * (1 - 1e-12)  # never below the true flow-only optimum


def test_band_holds_the_path_and_its_rings():
    lazy = creature_lazy(24, 3)
    path, _ = cheapest_closed_path(lazy)
    band = path_band_seed(lazy)
    assert np.isin(path, band).all()
    assert np.all(np.diff(band) > 0)
    narrow, wide = path_plausible(lazy, path, rings=0, window=0), path_plausible(lazy, path, rings=2)
    assert (narrow <= wide).all() and wide.sum() > narrow.sum()
    layer, entry, _ = lazy.split(path)
    assert narrow[lazy.curve.vertices[layer], lazy.graph.block_src[entry]].all()
