import numpy as np
import pytest
from scipy.optimize import linprog

from spidermatch.model.ilp import build_model
from spidermatch.model.product_graph import INTER, INTRA, STAY
from spidermatch.solve.connectivity import detached_components
from spidermatch.solve.cuts import CutPool, solve_with_cuts
from spidermatch.solve.layer_flow import flow_values, layer_flow
from spidermatch.solve.types import SolverOptions
from tests.test_ilp import (
    TRIANGLE,
    brute_force,
    edge_id,
    instance,
    square_instance_with_detached_copy,
)

EXACT = SolverOptions(mip_rel_gap=0.0)
SQUARE = np.array([[0, 1], [1, 2], [2, 3], [0, 3], [0, 2]])


def rows_hold(flow, x, g):
    return (flow.rows_x @ x + flow.rows_flow @ g <= flow.upper + 1e-9).all() and (
        (g >= -1e-9) & (g <= flow.flow_upper + 1e-9)
    ).all()


def some_flow_exists(flow, x):
    """Is there any g with 0 <= g <= K and the rows satisfied for this x? (an LP in g)"""
    if flow.n_flow == 0:
        return (flow.rows_x @ x <= flow.upper + 1e-9).all()
    answer = linprog(
        np.zeros(flow.n_flow),
        A_ub=flow.rows_flow.toarray(),
        b_ub=flow.upper - flow.rows_x @ x,
        bounds=list(zip(np.zeros(flow.n_flow), flow.flow_upper)),
        method="highs",
    )
    return answer.status == 0


def walking_path(graph):
    """A closed path on the square instance that walks inside every layer (1-2 intra edges each)."""
    steps = [
        (0, 0, 1, INTRA), (0, 1, 2, INTRA), (0, 2, 3, INTER),
        (1, 3, 0, INTRA), (1, 0, 0, STAY),
        (2, 0, 3, INTRA), (2, 3, 2, INTRA), (2, 2, 1, INTER),
        (3, 1, 0, INTRA), (3, 0, 0, STAY),
    ]  # fmt: skip
    x = np.zeros(graph.n_edges)
    x[[edge_id(graph, *step) for step in steps]] = 1
    return x


def test_flow_values_of_a_path_walking_in_every_layer_satisfy_the_rows():
    _, graph, _ = instance([0, 1, 0, 2], SQUARE, 4, 0)
    x = walking_path(graph)
    assert detached_components(graph, x) == []
    everything = np.arange(graph.n_edges)
    flow = layer_flow(graph, everything, np.arange(graph.n_layers))
    g = flow_values(graph, everything, x, flow)
    assert rows_hold(flow, x, g)
    assert sorted(g[g > 0].tolist()) == [1.0, 1.0, 1.0, 1.0, 2.0, 2.0]


def test_a_walk_that_revisits_a_vertex_within_a_layer_keeps_a_flow():
    curve, graph, _ = instance([0, 1, 0, 2], SQUARE, 4, 0)
    x = np.zeros(graph.n_edges)
    walk = [edge_id(graph, 0, 0, 1, INTRA), edge_id(graph, 0, 1, 0, INTRA)]
    walk += [edge_id(graph, layer, 0, 0, STAY) for layer in range(4)]
    x[walk] = 1
    assert detached_components(graph, x) == []
    everything = np.arange(graph.n_edges)
    flow = layer_flow(graph, everything, np.arange(4))
    g = flow_values(graph, everything, x, flow)
    assert rows_hold(flow, x, g)
    assert sorted(g[g > 0].tolist()) == [1.0, 2.0]  # a -> b carries 2 (two edges left), b -> a carries 1


def test_no_flow_exists_for_a_solution_with_a_detached_cycle_in_a_covered_layer():
    graph, _, optimum, detached = square_instance_with_detached_copy()
    everything = np.arange(graph.n_edges)
    [component] = detached_components(graph, detached)
    layer = int(component[0] // graph.n_target)
    covered = layer_flow(graph, everything, np.array([layer]))
    assert some_flow_exists(covered, optimum)
    assert not some_flow_exists(covered, detached)
    others = np.setdiff1d(np.arange(graph.n_layers), [layer])
    assert some_flow_exists(layer_flow(graph, everything, others), detached)  # only its layer's rows see it


def test_flow_rows_on_a_column_subset_use_positions_in_that_subset():
    graph, _, optimum, _ = square_instance_with_detached_copy()
    columns = np.union1d(np.flatnonzero(optimum > 0.5), np.arange(0, graph.n_edges, 3))
    flow = layer_flow(graph, columns, np.arange(graph.n_layers))
    assert flow.rows_x.shape[1] == columns.size
    x_sub = optimum[columns]
    assert rows_hold(flow, x_sub, flow_values(graph, columns, x_sub, flow))


@pytest.mark.parametrize("curve_vertices", [[0, 1, 0, 2], [0, 1, 0, 1], [0, 1, 2, 1]])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_flow_rows_in_every_layer_give_the_brute_force_optimum_without_cut_rounds(curve_vertices, seed):
    curve, graph, costs = instance(curve_vertices, TRIANGLE, 3, seed)
    model = build_model(graph, curve, costs)
    pool = CutPool(flow_layers=set(range(graph.n_layers)))
    solved = solve_with_cuts(model, graph, EXACT, pool=pool)
    expected = brute_force(curve, graph, costs)
    assert solved.status == "optimal"
    assert solved.objective == pytest.approx(expected, rel=1e-9)
    assert solved.cut_rounds == 0  # HiGHS never returned a detached cycle
    assert solved.x.shape == (graph.n_edges,)


def test_a_detached_cycle_puts_its_layer_and_the_layers_of_its_source_vertex_under_flow_rows():
    graph, _, _, detached = square_instance_with_detached_copy()
    first_layer = np.array([0, 1, 0, 3])  # curve [0, 1, 0, 2]: layers 0 and 2 hold one vertex
    components = detached_components(graph, detached)
    layer = int(components[0][0] // graph.n_target)
    pool = CutPool(first_layer=first_layer)
    covered = pool.note_detached(graph, components)
    expected = {0, 2} if layer in (0, 2) else {layer}
    assert covered == expected


@pytest.mark.parametrize("flow_rows", ["found", "intersections"])
def test_flow_rows_setting_decides_which_layers_get_flow_rows_before_and_after_a_detached_cycle(flow_rows):
    from spidermatch.solve.cuts import cut_pool

    graph, _, _, detached = square_instance_with_detached_copy()
    components = detached_components(graph, detached)
    own = {int(components[0][0] // graph.n_target)}
    others = {layer for layer in range(graph.n_layers) if layer not in own}
    intersections = np.array(sorted(own | {min(others)}))  # the cycle's layer and one more
    first_layer = np.arange(graph.n_layers)  # no two layers share a source vertex here
    pool = cut_pool(first_layer, intersections, SolverOptions(flow_rows=flow_rows))
    assert pool.flow_layers == (set(intersections.tolist()) if flow_rows == "intersections" else set())
    assert pool.note_detached(graph, components) == own  # what the repair frees: the cycle's layer only
    assert pool.flow_layers == (own if flow_rows == "found" else set(intersections.tolist()))


def test_a_start_with_a_detached_cycle_is_not_offered_once_flow_rows_exist(caplog):
    from spidermatch.solve.cuts import offer_start_path
    from spidermatch.solve.highs import HighsSession
    from spidermatch.solve.layer_flow import SessionFlows

    _, _, optimum, detached = square_instance_with_detached_copy()
    curve, graph, costs = instance([0, 1, 0, 2], SQUARE, 4, 4)  # the same instance
    session = HighsSession(build_model(graph, curve, costs), EXACT)
    flows = SessionFlows(graph, np.arange(graph.n_edges), session)
    flows.cover(range(graph.n_layers))
    with caplog.at_level("WARNING"):
        offer_start_path(session, flows, detached)
    assert session.offered is None and "not offered" in caplog.text
    offer_start_path(session, flows, optimum)
    assert session.offered is not None and session.offered[1].size == session.n_vars
