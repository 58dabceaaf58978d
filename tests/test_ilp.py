import math
import threading

import numpy as np
import pytest
import scipy.sparse as sp

from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.remesh import decimate
from spidermatch.model.correspondence import active_edges, check_solution, extract_path
from spidermatch.model.curve import SpiderCurve, spider_curve
from spidermatch.model.ilp import ConstraintBlock, IlpModel, build_model, cyc_block, stack_blocks
from spidermatch.model.product_graph import INTER, INTRA, STAY, build_product_graph, cyclic_runs, split_layers
from spidermatch.pipeline import InfeasibleError, MatchResult
from spidermatch.solve.highs import solve_model
from spidermatch.solve.plain import solve_plain
from spidermatch.solve.strategies import solve_with_strategy
from spidermatch.solve.types import SolverOptions

TRIANGLE = np.array([[0, 1], [1, 2], [0, 2]])


def instance(curve_vertices, target_edges, n_target, seed):
    curve = SpiderCurve(np.asarray(curve_vertices), int(max(curve_vertices)) + 1)
    graph = build_product_graph(curve.length, n_target, target_edges)
    costs = np.random.default_rng(seed).uniform(0.1, 1.0, graph.n_edges)
    return curve, graph, costs


def edge_id(graph, layer, a, b, kind):
    n_dir = graph.target_edges.shape[0]
    if kind == STAY:
        return layer * graph.block_size + 2 * n_dir + a
    k = int(np.flatnonzero((graph.target_edges[:, 0] == a) & (graph.target_edges[:, 1] == b))[0])
    return layer * graph.block_size + k + (n_dir if kind == INTER else 0)


def simple_paths(start, neighbours):
    stack = [[start]]
    while stack:
        path = stack.pop()
        yield path
        stack.extend(path + [b] for b in neighbours[path[-1]] if b not in path)


def closed_walks(curve, graph):
    """Edge-id lists of every closed walk through all layers (within-layer walks simple), unchecked."""
    neighbours = {y: [] for y in range(graph.n_target)}
    for a, b in graph.target_edges.tolist():
        neighbours[a].append(b)
    walks = []

    def layer_options(layer, entry):
        for path in simple_paths(entry, neighbours):
            intra = [edge_id(graph, layer, a, b, INTRA) for a, b in zip(path, path[1:])]
            last = path[-1]
            yield intra + [edge_id(graph, layer, last, last, STAY)], last
            for b in neighbours[last]:
                yield intra + [edge_id(graph, layer, last, b, INTER)], b

    def descend(layer, entry, start, chosen):
        if layer == curve.length:
            if entry == start:
                walks.append(list(chosen))
            return
        for ids, exit_vertex in layer_options(layer, entry):
            descend(layer + 1, exit_vertex, start, chosen + ids)

    for start in range(graph.n_target):
        descend(0, start, start, [])
    return walks


def passes_checker(curve, graph, ids) -> bool:
    """Whether the walk with edge ids ``ids`` passes the independent checker."""
    target_edges = graph.target_edges[: graph.target_edges.shape[0] // 2]
    return check_solution(curve.vertices, target_edges, graph.n_target, graph.edge_tuples(np.array(ids))).ok


def checked_walks(curve, graph):
    """The closed walks of :func:`closed_walks` that pass the independent checker."""
    return [ids for ids in closed_walks(curve, graph) if passes_checker(curve, graph, ids)]


def brute_force(curve, graph, costs):
    """Cheapest single closed walk passing the independent checker (within-layer walks simple)."""
    for ids in sorted(closed_walks(curve, graph), key=lambda ids: costs[ids].sum()):
        if passes_checker(curve, graph, ids):
            return costs[ids].sum()
    return None


@pytest.mark.parametrize("curve_vertices", [[0, 1, 0, 2], [0, 1, 2, 3], [0, 1, 0, 1], [0, 1, 2, 1]])
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("strategy", ["plain", "rcfix"])
@pytest.mark.parametrize("flow_rows", ["found", "intersections"])
def test_ilp_optimum_equals_brute_force(curve_vertices, seed, strategy, flow_rows):
    curve, graph, costs = instance(curve_vertices, TRIANGLE, 3, seed)
    model = build_model(graph, curve, costs)
    options = SolverOptions(mip_rel_gap=0.0, flow_rows=flow_rows)
    exact = solve_with_strategy(strategy, model, graph, curve, options)
    assert exact.status == "optimal"
    expected = brute_force(curve, graph, costs)
    assert exact.objective == pytest.approx(expected, rel=1e-9)
    assert exact.bound <= exact.objective + 1e-9
    target_edges = graph.target_edges[:3]
    assert check_solution(curve.vertices, target_edges, 3, active_edges(graph, exact.x)).ok
    # the ILP of method.md without connectivity cuts is a relaxation: never above the optimum
    relaxed = solve_model(model, SolverOptions(mip_rel_gap=0.0))
    assert relaxed.objective <= expected + 1e-9


def test_infeasible_instance_is_reported():
    curve, graph, costs = instance([0, 1, 0, 2], TRIANGLE, 3, 0)
    model = build_model(graph, curve, costs)
    cyc = cyc_block(graph)
    # demand two boundary crossings out of layer 0 on top of CYC's one: impossible
    impossible = ConstraintBlock(
        "X",
        cyc.rows[cyc.rows == 0] * 0,
        cyc.cols[cyc.rows == 0],
        cyc.values[cyc.rows == 0],
        np.array([2.0]),
        np.array([2.0]),
    )
    extra = stack_blocks([impossible], costs)
    combined = IlpModel(
        costs,
        sp.vstack([model.matrix, extra.matrix]).tocsc(),
        np.concatenate([model.row_lower, [2.0]]),
        np.concatenate([model.row_upper, [2.0]]),
        {},
    )
    for strategy in ("plain", "rcfix"):
        solved = solve_with_strategy(strategy, combined, graph, curve, SolverOptions())
        assert solved.status == "infeasible" and solved.x is None
        result = MatchResult(None, None, curve, graph, solved)
        with pytest.raises(InfeasibleError, match="infeasible"):
            result.raise_for_status()


def test_product_graph_and_model_sizes_follow_formula():
    low = decimate(make_creature(1500, seed=5).mesh, 120)
    target = decimate(make_creature(1500, seed=6).mesh, 140).mesh
    curve = spider_curve(low.mesh)
    graph = build_product_graph(curve.length, target.n_verts, target.edges)
    n_dir = 2 * len(target.edges)
    assert graph.n_edges == curve.length * (2 * n_dir + target.n_verts)
    model = build_model(graph, curve, np.ones(graph.n_edges))
    n_dup = curve.length - low.mesh.n_verts
    assert (
        model.n_rows == curve.length + curve.length * target.n_verts + n_dup * target.n_verts + target.n_verts
    )
    assert model.row_families["PES"][1] - model.row_families["PES"][0] == n_dup * target.n_verts
    # each edge: +1 tail and -1 head in CON, and one CYC entry if it crosses a boundary
    con = model.matrix[slice(*model.row_families["CON"])]
    np.testing.assert_array_equal(np.asarray(con.sum(axis=0)).ravel(), 0)
    assert (abs(con).sum(axis=0) == 2).all()


def test_checker_detects_broken_solutions():
    curve, graph, costs = instance([0, 1, 0, 2], TRIANGLE, 3, 3)
    solved = solve_plain(build_model(graph, curve, costs), graph, curve, SolverOptions())
    tuples = active_edges(graph, solved.x)
    edges = graph.target_edges[:3]
    assert check_solution(curve.vertices, edges, 3, tuples).ok
    assert not check_solution(curve.vertices, edges, 3, tuples[1:]).ok  # a missing edge
    detached = np.array([[1, 0, 1, 1, INTRA], [1, 1, 1, 0, INTRA]])
    report = check_solution(curve.vertices, edges, 3, np.vstack([tuples, detached]))
    assert not report.ok
    bogus = tuples.copy()
    bogus[0, 4] = INTRA if bogus[0, 4] != INTRA else STAY
    assert not check_solution(curve.vertices, edges, 3, bogus).ok
    path = extract_path(graph, solved.x)
    assert len(path.entry) == 4 and len(path.edges) == len(tuples)


def square_instance_with_detached_copy():
    """The optimum of a small instance, and a copy with one detached intra-layer 2-cycle added."""
    square = np.array([[0, 1], [1, 2], [2, 3], [0, 3], [0, 2]])
    curve, graph, costs = instance([0, 1, 0, 2], square, 4, 4)
    solved = solve_plain(build_model(graph, curve, costs), graph, curve, SolverOptions(mip_rel_gap=0.0))
    visited = {(int(layer), int(y)) for layer, y in extract_path(graph, solved.x).layer_vertex_pairs()}
    layer, a, b = next(
        (layer, a, b)
        for layer in range(4)
        for a, b in square.tolist()
        if (layer, a) not in visited and (layer, b) not in visited
    )
    detached = solved.x.copy()
    detached[edge_id(graph, layer, a, b, INTRA)] = detached[edge_id(graph, layer, b, a, INTRA)] = 1
    return graph, costs, solved.x, detached


def test_connectivity_cuts_separate_detached_cycles_and_keep_every_path():
    from spidermatch.solve.connectivity import connectivity_cuts, detached_components

    graph, _, optimum, detached = square_instance_with_detached_copy()
    assert detached_components(graph, optimum) == []
    components = detached_components(graph, detached)
    assert len(components) == 1
    added = np.flatnonzero(detached != optimum)  # the two intra edges of the detached 2-cycle
    layer, a, _, b, _ = graph.edge_tuples(added)[0]
    assert sorted(components[0].tolist()) == sorted([layer * 4 + a, layer * 4 + b])
    rows, lower, _ = connectivity_cuts(graph, components)
    assert (rows @ detached < lower).any()  # the detached cycle is cut off
    assert (rows @ optimum >= lower).all()  # the single closed path is not


def creature_instance(faces, seed):
    """A small SpiderMatch instance on two synthetic creatures with random vertex-pair costs
    (random costs make the LP relaxation fractional, as real features do at larger sizes)."""
    from spidermatch.model.costs import product_edge_costs

    source = decimate(make_creature(600, seed=seed).mesh.centred(), faces).mesh
    target = decimate(make_creature(600, seed=seed + 1).mesh.centred(), faces).mesh
    curve = spider_curve(source, seed=0)
    graph = build_product_graph(curve.length, target.n_verts, target.edges)
    vertex_costs = np.random.default_rng(seed).uniform(0.0, 1.0, (source.n_verts, target.n_verts))
    costs = product_edge_costs(graph, curve.vertices, source.verts, target.verts, vertex_costs)
    return curve, graph, build_model(graph, curve, costs)


def test_dual_bound_is_valid_for_any_multipliers_and_fixing_keeps_the_optimum(rng):
    from spidermatch.solve.fixing import dual_bound
    from spidermatch.solve.rcfix import solve_lp

    curve, graph, model = creature_instance(24, seed=3)
    optimum = solve_plain(model, graph, curve, SolverOptions(mip_rel_gap=0.0))
    assert optimum.status == "optimal"
    lp = solve_lp(model, SolverOptions())
    assert lp.dual.bound <= optimum.objective + 1e-9
    assert lp.dual.bound >= 0.9 * optimum.objective  # the LP duals give a useful bound
    for _ in range(5):  # any multipliers at all, however bad, give a valid bound
        noisy = dual_bound(model, rng.normal(0.0, 1.0, model.n_rows))
        assert noisy.bound <= optimum.objective + 1e-9
    survivors = lp.dual.surviving_columns(optimum.objective)
    assert np.isin(np.flatnonzero(optimum.x), survivors).all()
    assert survivors.size < model.n_vars  # fixing removes columns


@pytest.mark.parametrize("seed", [3, 7])
def test_rcfix_matches_plain_when_it_needs_the_fixing_phase(seed, monkeypatch, caplog):
    import spidermatch.solve.rcfix as rcfix

    curve, graph, model = creature_instance(24, seed=seed)
    plain = solve_plain(model, graph, curve, SolverOptions(mip_rel_gap=0.0))
    # seed the first restricted MIP with the LP support only, so the later phases must run
    monkeypatch.setattr(rcfix, "SEED_GAP", 0.0)
    monkeypatch.setattr(rcfix, "SEED_FRACTION", 0.0)
    with caplog.at_level("INFO", logger="spidermatch.solve.rcfix"):
        fixed = solve_with_strategy("rcfix", model, graph, curve, SolverOptions(mip_rel_gap=0.0))
    assert "rcfix phase 2" in caplog.text
    assert fixed.status == "optimal" and plain.status == "optimal"
    assert fixed.objective == pytest.approx(plain.objective, rel=1e-6)
    assert fixed.bound <= plain.objective * (1 + 1e-9)
    undirected = graph.target_edges[: graph.target_edges.shape[0] // 2]
    assert check_solution(curve.vertices, undirected, graph.n_target, active_edges(graph, fixed.x)).ok


def test_session_time_limit_bounds_all_runs_together():
    """HiGHS gives every run() its whole time_limit; the session must pass on only what is left."""
    from spidermatch.solve.highs import HighsSession

    curve, graph, model = creature_instance(24, seed=3)
    fresh = HighsSession(model, SolverOptions(time_limit=60.0))
    assert fresh.run().status == "optimal"
    spent = HighsSession(model, SolverOptions(time_limit=60.0))
    spent.started -= 61.0  # as if earlier runs (e.g. connectivity-cut rounds) used the budget
    stopped = spent.run()
    assert stopped.status == "no_solution" and stopped.x is None
    assert "time limit" in stopped.message.lower()


@pytest.mark.parametrize("relax", [True, False])
def test_a_rerun_is_given_the_time_left_on_the_clock_highs_uses(monkeypatch, relax):
    """HiGHS compares an LP's time_limit with getRunTime(), which counts over all runs of a Highs.

    So an LP run is given getRunTime() plus what is left (else, after earlier runs had used as
    much as is left, it stopped at once); a MIP, timed by a clock of its own, just what is left.
    """
    import spidermatch.solve.highs as highs_module
    from spidermatch.solve.highs import HighsSession

    passed = []

    def recording_set_option(highs, name, value):
        if name == "time_limit":
            passed.append(value)
        return set_option(highs, name, value)

    set_option = highs_module.set_option
    monkeypatch.setattr(highs_module, "set_option", recording_set_option)
    # the session's own clock stands still: 20 s have passed since it started, whatever the machine does
    monkeypatch.setattr(highs_module.time, "perf_counter", lambda: 1020.0)
    curve, graph, model = creature_instance(24, seed=3)
    session = HighsSession(model, SolverOptions(time_limit=60.0), relax=relax)
    session.started = 1000.0
    assert session.run().status == "optimal"
    session.highs.getRunTime = lambda: 500.0  # as if earlier runs had taken 500 s on HiGHS's run clock
    passed.clear()
    assert session.run().status == "optimal"  # an LP given 60 - 20 < 500 would stop at once
    (limit,) = passed
    assert limit == (500.0 + 40.0 if relax else 40.0)


class _OverrunningHighs:
    """A Highs whose run() ignores the time limit (as HiGHS does in some heuristics) until cancelled.

    Once the session's ``cancel`` is set it runs the real HiGHS, whose interrupt callbacks then stop it.
    """

    def __init__(self, highs, cancel):
        self._highs, self.cancel, self.finished = highs, cancel, threading.Event()

    def __getattr__(self, name):
        return getattr(self._highs, name)

    def run(self):
        self.cancel.wait()
        self._highs.run()
        self.finished.set()


def test_a_run_that_overruns_its_time_limit_is_interrupted_and_waited_for(monkeypatch):
    """Past the deadline HiGHS is interrupted through its callbacks; run() returns once it has stopped.

    A run is never left running on its thread (issue 28): the result is read from the stopped HiGHS.
    """
    import spidermatch.solve.highs as highs_module
    from spidermatch.solve.highs import HighsSession

    monkeypatch.setattr(highs_module, "OVERRUN_GRACE_S", 0.05)
    curve, graph, model = creature_instance(24, seed=3)
    start = solve_model(model, SolverOptions(time_limit=60.0))
    session = HighsSession(model, SolverOptions(time_limit=0.1))
    session.set_solution(start.x)
    stuck = _OverrunningHighs(session.highs, session.cancel)
    session.highs = stuck
    result = session.run()
    assert stuck.finished.is_set()  # it returned only after HiGHS had stopped
    assert result.status in ("feasible", "optimal") and result.x is not None
    assert result.objective <= start.objective + 1e-6 * abs(start.objective)
    again = solve_model(model, SolverOptions(time_limit=60.0))
    assert again.status == "optimal"


def test_two_cycle_cuts_cover_the_two_cycles_of_the_chosen_layers_once():
    from spidermatch.solve.connectivity import two_cycle_components
    from spidermatch.solve.cuts import CutPool

    graph, _, optimum, detached = square_instance_with_detached_copy()
    everything = np.arange(graph.n_edges)
    pairs = two_cycle_components(graph, np.array([0, 1, 2, 3]), everything)
    assert len(pairs) == 4 * 5  # every undirected square edge in every layer
    one_way = np.setdiff1d(everything, [edge_id(graph, 1, 0, 1, INTRA)])  # 1->0 alone is no 2-cycle
    in_layer_1 = {tuple(p) for p in two_cycle_components(graph, np.array([1]), one_way)}
    assert len(in_layer_1) == 4 and (4 + 0, 4 + 1) not in in_layer_1
    pool = CutPool()
    assert pool.add_two_cycle_cuts(graph, np.array([0, 1, 2, 3]), everything) == 2 * len(pairs)
    assert pool.add_two_cycle_cuts(graph, np.array([1]), everything) == 0  # already in the pool
    assert (pool.rows @ optimum >= pool.lower).all()  # valid for the closed path
    assert (pool.rows @ detached < pool.lower).any()  # and they cut off the detached 2-cycle


def test_session_records_improving_solutions_and_restart_skips_detached_ones():
    from types import SimpleNamespace

    from spidermatch.solve.cuts import cheapest_connected
    from spidermatch.solve.highs import HighsSession

    curve, graph, model = creature_instance(24, seed=3)
    session = HighsSession(model, SolverOptions(mip_rel_gap=0.0))
    result = session.run()
    objectives = [objective for objective, _ in session.improving]
    assert objectives and all(later < earlier for earlier, later in zip(objectives, objectives[1:]))
    assert objectives[-1] == pytest.approx(result.objective, rel=1e-9)
    assert np.array_equal(np.round(session.improving[-1][1]), result.x)

    graph, costs, optimum, detached = square_instance_with_detached_copy()
    found = SimpleNamespace(improving=[(costs @ optimum + 1.0, optimum), (costs @ detached - 1.0, detached)])
    assert np.array_equal(cheapest_connected(graph, found, None, graph.n_edges), optimum)
    assert (
        cheapest_connected(graph, SimpleNamespace(improving=found.improving[1:]), None, graph.n_edges) is None
    )


def test_reported_mip_bound_is_only_what_the_gap_tolerance_proves():
    from spidermatch.solve.types import certified_mip_bound

    # HiGHS reports the incumbent as its dual bound once it has pruned everything within the gap
    assert certified_mip_bound(2.0, 2.0, 1e-4) == pytest.approx(2.0 * (1 - 1e-4))
    assert certified_mip_bound(1.5, 2.0, 1e-4) == 1.5
    assert certified_mip_bound(1.5, math.inf, 1e-4) == 1.5  # no incumbent, nothing pruned by the gap
    curve, graph, model = creature_instance(24, seed=3)
    exact = solve_model(model, SolverOptions(mip_rel_gap=0.0))
    loose = solve_model(model, SolverOptions(mip_rel_gap=0.2))
    assert loose.status == "optimal"  # "within 20 %"
    assert loose.bound <= exact.objective + 1e-12
    assert loose.bound <= loose.objective * (1 - 0.2) * (1 + 1e-12)


def test_connectivity_cuts_keep_a_closed_walk_that_revisits_a_vertex_within_a_layer():
    """A walk may go a -> b -> a inside one layer (the model allows it, e.g. to pad PES);
    cuts built for the node set {a, b} must not cut it off."""
    from spidermatch.solve.connectivity import connectivity_cuts, detached_components, two_cycle_components

    square = np.array([[0, 1], [1, 2], [2, 3], [0, 3], [0, 2]])
    curve, graph, _ = instance([0, 1, 0, 2], square, 4, 0)
    walk = [edge_id(graph, 0, 0, 1, INTRA), edge_id(graph, 0, 1, 0, INTRA)]
    walk += [edge_id(graph, layer, 0, 0, STAY) for layer in range(4)]
    x = np.zeros(graph.n_edges)
    x[walk] = 1
    assert detached_components(graph, x) == []  # one closed walk
    pair = two_cycle_components(graph, np.array([0]), np.array(walk))
    assert [p.tolist() for p in pair] == [[0, 1]]
    rows, lower, _ = connectivity_cuts(graph, pair)
    assert (rows @ x >= lower).all()


def test_split_layers_flags_exactly_the_layers_where_a_mixture_of_two_paths_crosses_differently():
    curve, graph, _ = instance([0, 1, 2, 3], TRIANGLE, 3, 0)
    # path A stays at target vertex 0; path B moves 0 -> 1 between layers 1 and 2, back 1 -> 0 after layer 2
    path_a = [edge_id(graph, layer, 0, 0, STAY) for layer in range(4)]
    path_b = [
        edge_id(graph, 0, 0, 0, STAY),
        edge_id(graph, 1, 0, 1, INTER),
        edge_id(graph, 2, 1, 0, INTER),
        edge_id(graph, 3, 0, 0, STAY),
    ]
    x = np.zeros(graph.n_edges)
    x[path_a] = 1.0
    assert not split_layers(graph, x).any()
    x[path_a] = 0.5
    x[path_b] += 0.5
    assert split_layers(graph, x).tolist() == [False, True, True, False]
    assert cyclic_runs(split_layers(graph, x)) == [(1, 2)]


@pytest.mark.parametrize(
    "flags, runs",
    [
        ([True, True, False, False, True], [(4, 3)]),
        ([False, True, False, True, True], [(1, 1), (3, 2)]),
        ([True, True, True], [(0, 3)]),
        ([False, False], []),
        ([], []),
    ],
)
def test_cyclic_runs_joins_a_run_that_wraps_around(flags, runs):
    assert cyclic_runs(np.array(flags)) == runs


def test_a_mip_stops_once_stop_when_says_so():
    """At each MIP progress report the session asks stop_when(incumbent, dual bound)."""
    from types import SimpleNamespace

    import highspy

    from spidermatch.solve.cuts import solve_with_cuts
    from spidermatch.solve.highs import HighsSession

    curve, graph, model = creature_instance(24, seed=3)
    session = HighsSession(model, SolverOptions(mip_rel_gap=0.0))
    session.stop_when = lambda incumbent, dual_bound: incumbent < 10.0 and dual_bound > 4.0
    report = highspy.cb.HighsCallbackType.kCallbackMipInterrupt
    asked = []
    for incumbent, dual_bound in [(20.0, 5.0), (8.0, 3.0), (8.0, 5.0)]:
        data_in = SimpleNamespace(user_interrupt=False)
        data_out = SimpleNamespace(
            mip_primal_bound=incumbent, mip_dual_bound=dual_bound, mip_node_count=0, running_time=0.0,
            mip_gap=0.0, objective_function_value=incumbent,
        )  # fmt: skip
        session._on_callback(report, "", data_out, data_in, None)
        asked.append(data_in.user_interrupt)
    assert asked == [False, False, True]
    optimum = solve_plain(model, graph, curve, SolverOptions(mip_rel_gap=0.0))
    never = solve_with_cuts(model, graph, SolverOptions(mip_rel_gap=0.0), stop_when=lambda *_: False)
    assert never.status == "optimal" and never.objective == pytest.approx(optimum.objective)


def test_stop_when_is_also_asked_at_the_lp_solvers_reports_inside_a_mip():
    """HiGHS's root node may go minutes without a MIP report: its simplex and IPM reports ask too."""
    from types import SimpleNamespace

    import highspy

    from spidermatch.solve.highs import HighsSession

    _, _, model = creature_instance(24, seed=3)
    kinds = highspy.cb.HighsCallbackType
    data_out = SimpleNamespace(simplex_iteration_count=10, running_time=0.0)
    for relax, expected in ((False, True), (True, False)):
        session = HighsSession(model, SolverOptions(mip_rel_gap=0.0), relax=relax)
        session.stop_when = lambda incumbent, dual_bound: True
        for kind in (kinds.kCallbackSimplexInterrupt, kinds.kCallbackIpmInterrupt):
            data_in = SimpleNamespace(user_interrupt=False)
            session._on_callback(kind, "", data_out, data_in, None)
            assert data_in.user_interrupt is expected and session.stopped_early is expected


def test_a_time_limit_between_cut_rounds_keeps_the_cheapest_connected_solution():
    """Not 'no solution' while a closed path is known: the cheapest connected one, marked feasible."""
    from types import SimpleNamespace

    from spidermatch.solve.cuts import _stopped_while_separating
    from spidermatch.solve.types import SolveResult

    graph, costs, optimum, detached = square_instance_with_detached_copy()
    last = SolveResult("optimal", detached, costs @ detached, costs @ detached - 1.0, 0.0, 1.0, 1, 1, 1)
    session = SimpleNamespace(
        improving=[(costs @ detached, detached)], offered=(costs @ optimum, optimum), costs=costs
    )
    kept = _stopped_while_separating(last, graph, session, None, graph.n_edges, 0.0, 3)
    assert kept.status == "feasible" and np.array_equal(kept.x, optimum)
    assert kept.objective == pytest.approx(costs @ optimum) and kept.bound == last.bound
    assert "separating detached cycles" in kept.message and not kept.proven_optimal
    nothing = SimpleNamespace(improving=[(costs @ detached, detached)], offered=None, costs=costs)
    lost = _stopped_while_separating(last, graph, nothing, None, graph.n_edges, 0.0, 3)
    assert lost.status == "no_solution" and lost.x is None


def test_a_run_after_one_stopped_on_request_is_not_stopped_by_the_old_request():
    """HiGHS keeps its interrupt flag between runs of a session; the callback must clear it."""
    from spidermatch.solve.highs import HighsSession

    curve, graph, model = creature_instance(24, seed=3)
    session = HighsSession(model, SolverOptions(mip_rel_gap=0.0))
    session.stop_when = lambda incumbent, dual_bound: True
    first = session.run()
    assert first.status in ("no_solution", "feasible") and session.stopped_early
    # HiGHS calls every interrupt "Interrupted by user"; the message says who stopped it
    assert first.message.startswith("stopped early by spidermatch") and "user" not in first.message
    session.stop_when = None
    second = session.run()
    assert second.status == "optimal" and not session.stopped_early
    assert second.objective == pytest.approx(
        solve_plain(model, graph, curve, SolverOptions(mip_rel_gap=0.0)).objective
    )


def test_the_relative_gap_of_vanishing_costs_is_rounding_not_a_gap():
    from spidermatch.solve.types import relative_gap

    assert relative_gap(-7.047e-19, -8.674e-19) == 0.0  # a mesh matched to its exact copy
    assert relative_gap(2.0, 1.0) == pytest.approx(0.5)
    assert relative_gap(100.0, 100.0 - 1e-6) == pytest.approx(1e-8)  # small, but a real gap
    assert math.isnan(relative_gap(float("inf"), 1.0))


def test_a_mip_stopped_on_request_with_detached_cycles_keeps_its_bound_and_cuts_without_a_re_solve(
    monkeypatch,
):
    from spidermatch.solve.cuts import CutPool, solve_with_cuts
    from spidermatch.solve.highs import HighsSession
    from spidermatch.solve.types import SolveResult

    graph, costs, optimum, detached = square_instance_with_detached_copy()
    curve = SpiderCurve(np.array([0, 1, 0, 2]), 3)
    model = build_model(graph, curve, costs)
    runs = []

    def stopped_with_a_detached_cycle(self):
        if self.stop_when is not None:  # the restricted MIP (not the repair MIP, which gives nothing here)
            runs.append(self.offered)
        self.stopped_early = True
        value = float(costs @ detached)
        return SolveResult(
            "feasible", detached, value, value - 1.0, 0.1, 0.0, self.n_vars, self.n_rows, self.nnz
        )

    monkeypatch.setattr(HighsSession, "run", stopped_with_a_detached_cycle)
    pool = CutPool()
    result = solve_with_cuts(
        model, graph, SolverOptions(), incumbent=optimum, pool=pool, stop_when=lambda *_: True
    )
    assert len(runs) == 1  # no re-solve
    assert result.status == "feasible" and np.array_equal(result.x, optimum)  # the connected start
    assert result.bound == pytest.approx(costs @ detached - 1.0)  # the stopped run's bound still holds
    assert pool.rows is not None and (pool.rows @ detached < pool.lower).any()  # cut for later solves
    assert pool.flow_layers and "stopped early" in result.message


def test_a_re_solve_stopped_before_its_root_bound_keeps_the_bound_of_the_run_before(monkeypatch):
    """Cuts only remove solutions with detached cycles: the first run's bound holds for the re-solve."""
    import math

    from spidermatch.solve.cuts import solve_with_cuts
    from spidermatch.solve.highs import HighsSession
    from spidermatch.solve.types import SolveResult

    graph, costs, optimum, detached = square_instance_with_detached_copy()
    model = build_model(graph, SpiderCurve(np.array([0, 1, 0, 2]), 3), costs)
    first_bound, runs = float(costs @ optimum) - 0.25, []

    def detached_then_stopped_at_the_root(self):
        if self.stop_when is None:  # a repair MIP: nothing
            return SolveResult("no_solution", None, math.inf, -math.inf, math.nan, 0.0, self.n_vars, 0, 0)
        runs.append(len(runs))
        if len(runs) == 1:  # optimal over its rows, with a detached 2-cycle
            return SolveResult(
                "optimal", detached, float(costs @ detached), first_bound, 0.0, 0.0, self.n_vars, 0, 0
            )
        value = float(costs @ optimum)  # the re-solve, stopped before its root bound
        return SolveResult("feasible", optimum, value, -math.inf, math.nan, 0.0, self.n_vars, 0, 0, "stopped")

    monkeypatch.setattr(HighsSession, "run", detached_then_stopped_at_the_root)
    result = solve_with_cuts(model, graph, SolverOptions(), stop_when=lambda *_: False)
    assert len(runs) == 2 and result.cut_rounds == 1 and np.array_equal(result.x, optimum)
    assert result.bound == pytest.approx(first_bound)  # not -inf
    assert result.gap == pytest.approx(0.25 / (costs @ optimum))


@pytest.mark.parametrize("re_solve_finds", ["nothing", "a cheaper path"])
def test_a_wider_repair_between_cut_rounds_gives_the_answer_unless_the_re_solve_finds_a_cheaper_path(
    monkeypatch, re_solve_finds
):
    """The restricted repair finds nothing: the caller's wider repair is asked once, at once, for the
    solution just cut off; its path is the answer (feasible, the bound untouched) unless the re-solve
    from the old start finds a cheaper one."""
    import math

    from spidermatch.solve.cuts import CutPool, solve_with_cuts
    from spidermatch.solve.highs import HighsSession
    from spidermatch.solve.types import SolveResult

    graph, costs, optimum, detached = square_instance_with_detached_copy()
    model = build_model(graph, SpiderCurve(np.array([0, 1, 0, 2]), 3), costs)
    first_bound, runs, asked = float(costs @ optimum) - 0.25, [], []
    wider_cost = float(costs @ optimum) + (1.0 if re_solve_finds == "a cheaper path" else 0.0)

    def detached_then_the_re_solve(self):
        if self.stop_when is None:  # a repair MIP within the restricted columns: nothing
            return SolveResult("no_solution", None, math.inf, -math.inf, math.nan, 0.0, self.n_vars, 0, 0)
        runs.append(len(runs))
        if len(runs) == 1:  # optimal over its rows, with a detached 2-cycle
            value = float(costs @ detached)
            return SolveResult("optimal", detached, value, first_bound, 0.0, 0.0, self.n_vars, 0, 0)
        if re_solve_finds == "nothing":
            return SolveResult("no_solution", None, math.inf, first_bound, math.nan, 0.0, self.n_vars, 0, 0)
        value = float(costs @ optimum)
        return SolveResult("optimal", optimum, value, value, 0.0, 0.0, self.n_vars, 0, 0)

    def wider_repair(options):
        asked.append((options.time_limit, pool.detached))
        return optimum.copy(), wider_cost

    monkeypatch.setattr(HighsSession, "run", detached_then_the_re_solve)
    pool = CutPool()
    result = solve_with_cuts(
        model, graph, SolverOptions(time_limit=100.0), pool=pool, stop_when=lambda *_: False,
        repair_wider=wider_repair,
    )  # fmt: skip
    assert len(runs) == 2 and len(asked) == 1  # asked before the re-solve, once
    budget, cut_off = asked[0]
    assert 0 < budget <= 30.0 and cut_off is not None and cut_off.objective == pytest.approx(costs @ detached)
    assert np.array_equal(result.x, optimum)
    if re_solve_finds == "nothing":
        assert result.status == "feasible" and "wider repair" in result.message
        assert result.objective == pytest.approx(wider_cost) and result.bound == pytest.approx(first_bound)
    else:
        assert result.status == "optimal" and result.objective == pytest.approx(costs @ optimum)


def test_no_wider_repair_after_a_run_stopped_on_request(monkeypatch):
    """A stopped run returns at once: the caller repairs after it (with the time it keeps for that)."""
    from spidermatch.solve.cuts import CutPool, solve_with_cuts
    from spidermatch.solve.highs import HighsSession
    from spidermatch.solve.types import SolveResult

    graph, costs, optimum, detached = square_instance_with_detached_copy()
    model = build_model(graph, SpiderCurve(np.array([0, 1, 0, 2]), 3), costs)

    def stopped_with_a_detached_cycle(self):
        self.stopped_early = True
        value = float(costs @ detached)
        return SolveResult("feasible", detached, value, value - 1.0, 0.1, 0.0, self.n_vars, 0, 0)

    monkeypatch.setattr(HighsSession, "run", stopped_with_a_detached_cycle)
    asked = []
    result = solve_with_cuts(
        model, graph, SolverOptions(), incumbent=optimum, pool=CutPool(), stop_when=lambda *_: True,
        repair_wider=lambda options: asked.append(options),
    )  # fmt: skip
    assert asked == [] and np.array_equal(result.x, optimum) and "stopped early" in result.message


def test_stop_when_judges_the_cheapest_closed_path_not_an_incumbent_with_detached_cycles():
    from types import SimpleNamespace

    import highspy

    from spidermatch.solve.connectivity import detached_components
    from spidermatch.solve.highs import HighsSession

    graph, costs, optimum, detached = square_instance_with_detached_copy()
    curve = SpiderCurve(np.array([0, 1, 0, 2]), 3)
    session = HighsSession(build_model(graph, curve, costs), SolverOptions(mip_rel_gap=0.0))
    session.usable = lambda x: not detached_components(graph, np.round(x))
    seen = []
    session.stop_when = lambda incumbent, dual_bound: seen.append(incumbent) or False
    session.set_solution(optimum)
    kinds = highspy.cb.HighsCallbackType
    found = SimpleNamespace(mip_solution=detached, objective_function_value=float(costs @ optimum) - 1.0)
    session._on_callback(kinds.kCallbackMipImprovingSolution, "", found, None, None)
    report = SimpleNamespace(
        mip_primal_bound=float(costs @ optimum) - 1.0, mip_dual_bound=0.0, mip_node_count=0, running_time=0.0,
        mip_gap=0.0, objective_function_value=0.0,
    )  # fmt: skip
    session._on_callback(kinds.kCallbackMipInterrupt, "", report, SimpleNamespace(user_interrupt=False), None)
    assert seen == [pytest.approx(costs @ optimum)]  # the detached one is cheaper but not a closed path


def test_a_mip_out_of_memory_with_detached_cycles_is_not_solved_again(monkeypatch):
    """HiGHS out of memory on a solution with detached cycles: cuts kept for later solves, no
    re-solve (it would need more memory), the connected start, no bound claimed, and why."""
    import math

    from spidermatch.solve.cuts import CutPool, solve_with_cuts
    from spidermatch.solve.highs import HighsSession
    from spidermatch.solve.types import OUT_OF_MEMORY, SolveResult

    graph, costs, optimum, detached = square_instance_with_detached_copy()
    model = build_model(graph, SpiderCurve(np.array([0, 1, 0, 2]), 3), costs)
    runs = []

    def out_of_memory_with_a_detached_cycle(self):
        runs.append(self)
        value = float(costs @ detached)
        return SolveResult(
            "feasible", detached, value, -math.inf, math.nan, 0.0, self.n_vars, self.n_rows, self.nnz,
            f"{OUT_OF_MEMORY}: test",
        )  # fmt: skip

    monkeypatch.setattr(HighsSession, "run", out_of_memory_with_a_detached_cycle)
    pool = CutPool()
    result = solve_with_cuts(model, graph, SolverOptions(), incumbent=optimum, pool=pool)
    assert sum(run is runs[0] for run in runs) == 1  # the MIP's session ran once (the repair's MIPs aside)
    assert result.status == "feasible" and np.array_equal(result.x, optimum) and result.out_of_memory
    assert result.bound == -math.inf and pool.rows is not None


@pytest.mark.parametrize("curve_vertices", [[0, 1, 0, 2], [0, 1, 2, 1]])
@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("strategy", ["plain", "rcfix"])
def test_costs_within_highs_tolerances_are_still_solved_to_the_optimum(
    curve_vertices, seed, strategy, caplog
):
    """Costs of about 1e-9 (as a mesh matched to a copy of itself has): HiGHS alone calls a path up to
    three times the optimum "optimal" (its tolerances are 1e-7); solved again with scaled costs."""
    curve, graph, costs = instance(curve_vertices, TRIANGLE, 3, seed)
    costs = costs * 1e-9
    model = build_model(graph, curve, costs)
    with caplog.at_level("WARNING", logger="spidermatch.solve.strategies"):
        exact = solve_with_strategy(strategy, model, graph, curve, SolverOptions(mip_rel_gap=0.0))
    assert "within HiGHS's tolerances" in caplog.text
    assert exact.status == "optimal"
    assert exact.objective == pytest.approx(brute_force(curve, graph, costs), rel=1e-9)
    assert exact.bound <= exact.objective * (1 + 1e-9)


def test_callback_figures_of_a_run_with_scaled_costs_are_read_in_the_model_costs():
    """HiGHS returns its results unscaled but passes its callbacks figures in the scaled costs."""
    from types import SimpleNamespace

    import highspy

    from spidermatch.solve.highs import HighsSession

    curve, graph, model = creature_instance(24, seed=3)
    session = HighsSession(model, SolverOptions(extra={"user_objective_scale": 10}))
    data_out = SimpleNamespace(
        mip_primal_bound=2048.0, mip_dual_bound=1024.0, mip_node_count=0, running_time=0.0, mip_gap=0.0,
        objective_function_value=2048.0,
    )  # fmt: skip
    data_in = SimpleNamespace(user_interrupt=False)
    session._on_callback(highspy.cb.HighsCallbackType.kCallbackMipInterrupt, "", data_out, data_in, None)
    assert session.last_mip == (2.0, 1.0)  # 2^10 times too large as HiGHS passes them
