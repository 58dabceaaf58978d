import numpy as np
import pytest

from spidermatch.model.correspondence import active_edges, check_solution
from spidermatch.model.curve import SpiderCurve
from spidermatch.model.ilp import build_model
from spidermatch.solve.connectivity import connectivity_cuts, detached_components
from spidermatch.solve.cuts import CutPool
from spidermatch.solve.plain import solve_plain
from spidermatch.solve.repair import freed_layers, repair_detached, window_layers
from spidermatch.solve.types import SolverOptions
from tests.test_ilp import creature_instance, square_instance_with_detached_copy

EXACT = SolverOptions(mip_rel_gap=0.0)


def passes_checker(curve, graph, x):
    undirected = graph.target_edges[: graph.target_edges.shape[0] // 2]
    return check_solution(curve.vertices, undirected, graph.n_target, active_edges(graph, x)).ok


def test_window_layers_wrap_around_the_curve():
    near = window_layers([0, 5], 10, window=1)
    assert np.flatnonzero(near).tolist() == [0, 1, 4, 5, 6, 9]


def test_a_solution_with_a_detached_cycle_is_repaired_into_a_checked_closed_path():
    graph, costs, optimum, detached = square_instance_with_detached_copy()
    curve = SpiderCurve(np.array([0, 1, 0, 2]), 3)
    model = build_model(graph, curve, costs)
    components = detached_components(graph, detached)
    pool = CutPool(first_layer=curve.first_layer)
    pool.add(*connectivity_cuts(graph, components))
    affected = pool.note_detached(graph, components)
    everything = np.arange(graph.n_edges)
    repaired = repair_detached(model, graph, everything, detached, affected, pool, EXACT)
    assert repaired is not None and detached_components(graph, repaired) == []
    assert passes_checker(curve, graph, repaired)
    # the window covers this 4-layer curve whole, so the repair MIP finds the optimum (within its gap)
    assert costs @ repaired == pytest.approx(costs @ optimum, rel=1e-3)


def test_the_repair_keeps_the_path_outside_the_windows():
    curve, graph, model = creature_instance(24, seed=3)
    solved = solve_plain(model, graph, curve, EXACT)
    far = graph.n_layers // 2
    pool = CutPool()
    repaired = repair_detached(model, graph, np.arange(graph.n_edges), solved.x, [far], pool, EXACT)
    assert repaired is not None and passes_checker(curve, graph, repaired)
    layer = np.arange(graph.n_edges) // graph.block_size
    outside = ~window_layers([far], graph.n_layers)[layer]
    assert set(np.flatnonzero((repaired > 0.5) & outside)) <= set(np.flatnonzero(solved.x > 0.5))
    assert model.costs @ repaired == pytest.approx(model.costs @ solved.x, rel=1e-3)  # it was optimal


def test_a_run_stops_in_time_for_a_repair_only_when_its_best_solution_has_detached_cycles():
    import time
    from types import SimpleNamespace

    from spidermatch.solve.cuts import _leaving_time_to_repair

    session = SimpleNamespace(best_usable=415.2, best_unusable=2.01)
    late = _leaving_time_to_repair(session, None, SolverOptions(time_limit=10.0), time.perf_counter() - 9.0)
    early = _leaving_time_to_repair(session, None, SolverOptions(time_limit=100.0), time.perf_counter())
    assert late(2.01, 2.0) and not early(2.01, 2.0)  # 10 s limit: the last 2 s are the repair's
    session.best_unusable = 500.0  # the best solution is a closed path: nothing to repair
    assert not late(415.2, 2.0)
    asked = _leaving_time_to_repair(
        session, lambda *_: True, SolverOptions(time_limit=100.0), time.perf_counter()
    )
    assert asked(415.2, 2.0)  # the caller's own stop still counts
    assert _leaving_time_to_repair(session, None, SolverOptions(), 0.0) is None  # no limit: nothing to leave


def test_freed_layers_also_free_the_windows_of_the_layers_pes_ties_to_them():
    first_layer = np.arange(20)
    first_layer[15] = 2  # layer 15 repeats layer 2's source vertex
    freed = freed_layers([0], first_layer, 20, window=2)  # window 18..2 holds layer 2, so 13..17 too
    assert np.flatnonzero(freed).tolist() == [0, 1, 2, 13, 14, 15, 16, 17, 18, 19]
    first_layer[14] = 5  # and layer 14 repeats layer 5's vertex: the second round frees 3..7
    freed = freed_layers([0], first_layer, 20, window=2)
    assert np.flatnonzero(freed).tolist() == [0, 1, 2, 3, 4, 5, 6, 7, 13, 14, 15, 16, 17, 18, 19]
    assert np.flatnonzero(freed_layers([0], None, 20, window=2)).tolist() == [0, 1, 2, 18, 19]


def reachable(graph, start: np.ndarray, rings: int) -> set:
    """Target vertices within ``rings`` edges of ``start`` (breadth first)."""
    seen, frontier = set(start.tolist()), set(start.tolist())
    for _ in range(rings):
        frontier = {int(b) for a, b in graph.target_edges if int(a) in frontier} - seen
        seen |= frontier
    return seen


def test_nearby_columns_lie_in_the_chosen_layers_within_the_rings_of_the_path():
    from spidermatch.solve.repair import nearby_columns
    from tests.test_colgen import creature_lazy

    lazy = creature_lazy(24, 3)
    graph = lazy.graph
    path = np.flatnonzero(solve_plain(lazy.full_model(), graph, lazy.curve, EXACT).x > 0.5)
    layers = window_layers([graph.n_layers // 2], graph.n_layers, window=1)
    found = nearby_columns(graph, path, layers, rings=1)
    tuples, on_path = graph.edge_tuples(found), graph.edge_tuples(path)
    assert set(np.unique(tuples[:, 0]).tolist()) == set(np.flatnonzero(layers).tolist())
    for layer in np.flatnonzero(layers):
        here = np.isin(on_path[:, 0], [layer - 1, layer, layer + 1]) | np.isin(
            on_path[:, 2], [layer - 1, layer, layer + 1]
        )
        visited = np.unique(on_path[here][:, [1, 3]])
        near = reachable(graph, visited, 1)
        mine = tuples[tuples[:, 0] == layer]
        assert set(mine[:, 1].tolist()) | set(mine[:, 3].tolist()) <= near
    in_layers = path[layers[path // graph.block_size]]
    assert set(in_layers.tolist()) <= set(found.tolist())  # the path's own edges are near it


def test_a_repair_with_nearby_columns_reroutes_where_the_restricted_columns_cannot():
    """A path broken in two layers, restricted columns of the stay path only: the repair mends the path."""
    from spidermatch.solve.repair import repair_with_nearby_columns
    from spidermatch.solve.seeds import stay_seed
    from tests.test_colgen import creature_lazy

    lazy = creature_lazy(24, 3)
    graph = lazy.graph
    optimum = solve_plain(lazy.full_model(), graph, lazy.curve, EXACT)
    path = np.flatnonzero(optimum.x > 0.5)
    broken_layers = [graph.n_layers // 2, graph.n_layers // 2 + 1]
    broken = path[~np.isin(path // graph.block_size, broken_layers)]
    restricted = np.sort(stay_seed(lazy))
    pool = CutPool(first_layer=lazy.curve.first_layer)
    repaired = repair_with_nearby_columns(lazy, restricted, broken, broken_layers, pool, EXACT)
    assert repaired is not None and passes_checker(lazy.curve, graph, repaired)
    assert detached_components(graph, repaired) == []
    uses = np.flatnonzero(repaired > 0.5)
    assert not set(uses.tolist()) <= set(np.union1d(restricted, broken).tolist())  # columns it added
    assert optimum.objective - 1e-9 <= lazy.costs(uses).sum() <= optimum.objective * (1 + 1e-3)


def test_the_nearby_repair_between_cut_rounds_reports_each_cheaper_path_it_finds():
    """colgen's wider repair for solve_with_cuts: a path mended from the pool's cut-off solution is
    reported at once (a solver process stopped from outside keeps it); the solution is taken from the
    pool; a path no cheaper than the best one known is not an answer."""
    from spidermatch.solve.colgen import _nearby_repair_between_rounds
    from spidermatch.solve.progress import set_known_sink
    from spidermatch.solve.seeds import stay_seed
    from tests.test_colgen import creature_lazy

    lazy = creature_lazy(24, 3)
    graph = lazy.graph
    optimum = solve_plain(lazy.full_model(), graph, lazy.curve, EXACT)
    path = np.flatnonzero(optimum.x > 0.5)
    broken_layers = {graph.n_layers // 2, graph.n_layers // 2 + 1}
    broken = path[~np.isin(path // graph.block_size, list(broken_layers))]
    restricted = np.sort(stay_seed(lazy))
    reports = []
    set_known_sink(lambda incumbent, bound, found: reports.append((incumbent, bound, found)))
    try:
        for best_known, expected in ((1e9, "a path"), (optimum.objective * 0.5, None)):
            pool = CutPool(first_layer=lazy.curve.first_layer)
            pool.note_detached_solution(broken, float(lazy.costs(broken).sum()), broken_layers)
            repair = _nearby_repair_between_rounds(lazy, restricted, pool, best_known, proven=-7.0)
            found = repair(EXACT)
            assert pool.detached is None  # taken
            if expected is None:
                assert found is None
                continue
            x, objective = found
            assert passes_checker(lazy.curve, graph, x) and detached_components(graph, x) == []
            assert objective == pytest.approx(lazy.costs(np.flatnonzero(x > 0.5)).sum())
            assert reports == [(objective, -7.0, pytest.approx(np.flatnonzero(x > 0.5)))]
    finally:
        set_known_sink(None)
    assert len(reports) == 1


def test_the_nearby_repair_tries_its_stages_smallest_first_each_but_the_last_with_a_share_of_the_time():
    from spidermatch.solve.repair import _in_growing_windows

    tries = []

    def attempt(near, rings, options):
        tries.append((int(near.sum()), rings, options.time_limit))
        return np.array([1, 4]), (np.array([1.0, 1.0]) if rings == 2 else None)

    stages = ((1, 0), (2, 1), (2, 2), (5, 2))
    found = _in_growing_windows(attempt, [10], CutPool(), 40, 6, SolverOptions(time_limit=8.0), stages, 0.5)
    assert found.tolist() == [0, 1, 0, 0, 1, 0]  # spread into the full vector at the positions
    assert [(size, rings) for size, rings, _ in tries] == [(3, 0), (5, 1), (5, 2)]  # windows 1, 2, 2
    # every try but the last gets half of what is left (the tries here take no time: 8 s stay left)
    assert [limit for *_, limit in tries] == [pytest.approx(4.0, abs=0.05)] * 3
    tries.clear()
    whole_time = SolverOptions(time_limit=8.0)
    assert _in_growing_windows(attempt, [10], CutPool(), 40, 6, whole_time, stages[:2]) is None
    assert tries[-1][2] == pytest.approx(8.0, abs=0.05)  # default share 1: each try gets all that is left
