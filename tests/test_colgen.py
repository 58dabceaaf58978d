import math
from dataclasses import replace

import numpy as np
import pytest

from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.remesh import decimate
from spidermatch.model.correspondence import active_edges, check_solution
from spidermatch.model.curve import SpiderCurve, spider_curve
from spidermatch.model.lazy_model import LazyModel
from spidermatch.model.product_graph import build_product_graph
from spidermatch.solve.fixing import dual_bound, sign_corrected_duals
from spidermatch.solve.plain import solve_plain
from spidermatch.solve.pricing import price
from spidermatch.solve.seeds import SEED_NEIGHBOURS, stay_seed
from spidermatch.solve.strategies import solve_with_strategy
from spidermatch.solve.types import OUT_OF_MEMORY, SolveResult, SolverOptions
from tests.test_ilp import TRIANGLE, brute_force

EXACT = SolverOptions(mip_rel_gap=0.0)


def tiny_lazy(curve_vertices, seed):
    """A LazyModel on a triangle target with random geometry and feature costs."""
    rng = np.random.default_rng(seed)
    curve = SpiderCurve(np.asarray(curve_vertices), int(max(curve_vertices)) + 1)
    graph = build_product_graph(curve.length, 3, TRIANGLE)
    return LazyModel(
        graph,
        curve,
        rng.normal(size=(curve.n_mesh_verts, 3)),
        rng.normal(size=(3, 3)),
        rng.uniform(0.1, 1.0, (curve.n_mesh_verts, 3)),
    )


def creature_lazy(faces, seed):
    source = decimate(make_creature(600, seed=seed).mesh.centred(), faces).mesh
    target = decimate(make_creature(600, seed=seed + 1).mesh.centred(), faces).mesh
    curve = spider_curve(source, seed=0)
    graph = build_product_graph(curve.length, target.n_verts, target.edges)
    vertex_costs = np.random.default_rng(seed).uniform(0.0, 1.0, (source.n_verts, target.n_verts))
    return LazyModel(graph, curve, source.verts, target.verts, vertex_costs)


def stopped_at_start(lazy, columns, incumbent, bound=-math.inf, message="stopped"):
    """A restricted MIP stopped at once: "feasible" with its start solution (and its cost) and ``bound``."""
    start = float(lazy.costs(np.flatnonzero(incumbent > 0.5)).sum())
    return SolveResult("feasible", incumbent, start, bound, math.nan, 0.0, columns.size, 1, 1, message)


def assert_one_checked_path(lazy, x):
    graph = lazy.graph
    undirected = graph.target_edges[: graph.target_edges.shape[0] // 2]
    assert check_solution(lazy.curve.vertices, undirected, graph.n_target, active_edges(graph, x)).ok


@pytest.mark.parametrize("curve_vertices", [[0, 1, 0, 2], [0, 1, 2, 3], [0, 1, 2, 1]])
@pytest.mark.parametrize("seed", [0, 1])
def test_colgen_optimum_equals_brute_force_and_plain(curve_vertices, seed):
    lazy = tiny_lazy(curve_vertices, seed)
    solved = solve_with_strategy("colgen", lazy, lazy.graph, lazy.curve, EXACT)
    expected = brute_force(lazy.curve, lazy.graph, lazy.costs(np.arange(lazy.n_vars)))
    plain = solve_with_strategy("plain", lazy, lazy.graph, lazy.curve, EXACT)
    assert solved.status == "optimal" and plain.status == "optimal"
    assert solved.objective == pytest.approx(expected, rel=1e-9)
    assert plain.objective == pytest.approx(expected, rel=1e-9)
    assert solved.bound <= expected + 1e-9
    assert_one_checked_path(lazy, solved.x)


@pytest.mark.parametrize("seed", [3, 7])
def test_colgen_bound_holds_when_the_optimum_needs_columns_the_seed_lacked(seed, monkeypatch, caplog):
    import spidermatch.solve.colgen as colgen

    lazy = creature_lazy(24, seed)
    plain = solve_plain(lazy.full_model(), lazy.graph, lazy.curve, EXACT)
    seeds = []

    def stay_only(model, neighbours=SEED_NEIGHBOURS):  # the first restricted model: stays at y0 only
        seeds.append(stay_seed(model))
        return seeds[-1]

    monkeypatch.setattr(colgen, "path_band_seed", stay_only)
    monkeypatch.setattr(colgen, "FIRST_STEP", 0.0)  # the first MIP: LP support and stay seed only
    with caplog.at_level("INFO", logger="spidermatch.solve.colgen"):
        solved = solve_with_strategy("colgen", lazy, lazy.graph, lazy.curve, EXACT)
    used = np.flatnonzero(solved.x > 0.5)
    assert not np.isin(used, seeds[0]).all()  # the optimal path uses columns the seed did not have
    assert "colgen round 2" in caplog.text  # they were priced in
    # whether the first MIP (LP support and stay seed) already holds the optimum depends on which
    # optimal LP vertex HiGHS returns (seed 7: it did with highspy 1.16, not with an earlier release);
    # widening is tested on its own below
    assert solved.status == "optimal"
    assert solved.objective == pytest.approx(plain.objective, rel=1e-6)
    assert solved.bound <= plain.objective * (1 + 1e-9)
    assert 0 < solved.columns_built <= lazy.n_vars
    assert_one_checked_path(lazy, solved.x)


def test_pricing_bound_is_valid_for_any_multipliers_and_matches_the_full_pass(rng):
    lazy = creature_lazy(24, 3)
    model = lazy.full_model()
    optimum = solve_plain(model, lazy.graph, lazy.curve, EXACT).objective
    for _ in range(3):
        y = rng.normal(0.0, 0.01, model.n_rows)
        full, corrected = dual_bound(model, y), sign_corrected_duals(model, y)
        priced = price(lazy, corrected, threshold=0.0)
        assert priced.bound == pytest.approx(full.bound, rel=1e-9, abs=1e-12)
        assert priced.bound <= optimum + 1e-9
        np.testing.assert_array_equal(
            priced.columns, np.flatnonzero(model.costs - model.matrix.T @ corrected <= 0)
        )
        assert priced.min_outside > 0.0


def test_stay_seed_alone_is_a_feasible_solution():
    lazy = creature_lazy(24, 5)
    model = lazy.full_model()
    x = np.zeros(lazy.n_vars)
    x[stay_seed(lazy)] = 1.0
    activity = model.matrix @ x
    assert (activity >= model.row_lower - 1e-12).all() and (activity <= model.row_upper + 1e-12).all()


def test_colgen_needs_a_lazy_model():
    lazy = tiny_lazy([0, 1, 0, 2], 0)
    with pytest.raises(TypeError, match="LazyModel"):
        solve_with_strategy("colgen", lazy.full_model(), lazy.graph, lazy.curve, EXACT)


def test_a_slice_of_one_pricing_pass_equals_pricing_at_the_lower_threshold(rng):
    from spidermatch.solve.pricing import up_to

    lazy = creature_lazy(24, 3)
    model = lazy.full_model()
    y = sign_corrected_duals(model, rng.normal(0.0, 0.01, model.n_rows))
    wide = price(lazy, y, threshold=0.05)
    for threshold in (-0.01, 0.0, 0.01, 0.05):
        direct, sliced = price(lazy, y, threshold), up_to(wide, threshold)
        np.testing.assert_array_equal(sliced.columns, direct.columns)
        assert sliced.min_outside == pytest.approx(direct.min_outside, rel=1e-12)
        assert sliced.bound == pytest.approx(direct.bound, rel=1e-12)
    with pytest.raises(ValueError, match="cutoff"):
        up_to(wide, 0.1)


@pytest.mark.parametrize("seed, route", [(0, "LP solution integral"), (1, "Optimal")])
def test_both_certificates_equal_brute_force(seed, route, monkeypatch):
    """Seed 0's LP is integral (certified by L(y) alone); seed 1 is certified by the MIPs.

    These tiny LPs are all integral; seed 1's once differed from its bound by rounding only and
    so took the MIPs. Now that rounding counts as no gap, the LP's own solution is withheld to
    send it there.
    """
    import spidermatch.solve.colgen as colgen

    if route == "Optimal":
        monkeypatch.setattr(colgen, "_lp_incumbent", lambda lazy, lp: None)
    lazy = tiny_lazy([0, 1, 0, 2], seed)
    solved = solve_with_strategy("colgen", lazy, lazy.graph, lazy.curve, EXACT)
    assert solved.message.endswith(route) or route in solved.message
    assert ("integral" in solved.message) == (route != "Optimal")
    expected = brute_force(lazy.curve, lazy.graph, lazy.costs(np.arange(lazy.n_vars)))
    assert solved.status == "optimal"
    assert solved.objective == pytest.approx(expected, rel=1e-9)
    assert solved.bound <= expected + 1e-9


def test_a_mip_stopped_above_its_outside_bound_widens_and_still_certifies_the_optimum(monkeypatch, caplog):
    """The first MIP stops at once with its start solution (as stop_when does): step 2 certifies."""

    import spidermatch.solve.colgen as colgen

    lazy = creature_lazy(24, 3)
    plain = solve_plain(lazy.full_model(), lazy.graph, lazy.curve, EXACT)
    original, calls = colgen._restricted_mip, []

    def first_stopped(lazy, columns, options, incumbent, *rest):
        calls.append(columns.size)
        if len(calls) > 1:
            return original(lazy, columns, options, incumbent, *rest)
        return stopped_at_start(lazy, columns, incumbent)  # what HiGHS reports when stopped at once

    monkeypatch.setattr(colgen, "_restricted_mip", first_stopped)
    monkeypatch.setattr(colgen, "_lp_incumbent", lambda lazy, lp: None)  # no LP shortcut: the MIPs run
    with caplog.at_level("INFO", logger="spidermatch.solve.colgen"):
        solved = solve_with_strategy("colgen", lazy, lazy.graph, lazy.curve, EXACT)
    assert "above what it could certify: widening" in caplog.text
    assert len(calls) >= 2 and solved.status == "optimal"
    assert solved.objective == pytest.approx(plain.objective, rel=1e-9)
    assert solved.bound <= plain.objective * (1 + 1e-9)
    assert_one_checked_path(lazy, solved.x)


@pytest.mark.parametrize(
    "why, message, expected",
    [("time", "stopped", "too little for a wider MIP"), ("memory", OUT_OF_MEMORY, "ran out of memory")],
)
def test_no_wider_mip_starts_after_one_stopped_for_time_or_memory_and_the_answer_stays_honest(
    monkeypatch, why, message, expected
):
    """As above, but with too little time for step 2, or HiGHS out of memory in step 1 (a wider MIP
    would need more): the incumbent, a valid bound, `feasible`, and why."""

    import spidermatch.solve.colgen as colgen

    lazy = creature_lazy(24, 3)
    plain = solve_plain(lazy.full_model(), lazy.graph, lazy.curve, EXACT)
    calls = []

    def first_stopped(lazy, columns, options, incumbent, *rest):
        calls.append(columns.size)
        return stopped_at_start(lazy, columns, incumbent, message=message)

    monkeypatch.setattr(colgen, "_restricted_mip", first_stopped)
    monkeypatch.setattr(colgen, "_lp_incumbent", lambda lazy, lp: None)
    if why == "time":
        monkeypatch.setattr(colgen, "LAST_STEP_MIN_S", 1e6)
    solved = solve_with_strategy("colgen", lazy, lazy.graph, lazy.curve, replace(EXACT, time_limit=600.0))
    assert len(calls) == 1
    assert solved.status == "feasible" and expected in solved.message
    assert solved.bound <= plain.objective * (1 + 1e-9) <= solved.objective * (1 + 1e-9)
    assert solved.gap == pytest.approx((solved.objective - solved.bound) / abs(solved.objective), rel=1e-6)
    assert_one_checked_path(lazy, solved.x)


def test_a_mip_that_would_not_fit_in_memory_is_not_started_and_the_answer_stays_honest(monkeypatch):
    """No memory for the first MIP: the stay path (or the LP's), the LP bound, `feasible`, and why."""
    import spidermatch.solve.colgen as colgen

    lazy = creature_lazy(24, 3)
    plain = solve_plain(lazy.full_model(), lazy.graph, lazy.curve, EXACT)
    monkeypatch.setattr(colgen, "_restricted_mip", lambda *args: pytest.fail("a MIP was started"))
    monkeypatch.setattr(colgen, "_lp_incumbent", lambda lazy, lp: None)
    monkeypatch.setattr(colgen, "available_memory", lambda share=1.0: 1024)  # 1 KiB left
    solved = solve_with_strategy("colgen", lazy, lazy.graph, lazy.curve, replace(EXACT, time_limit=600.0))
    assert solved.status == "feasible" and "would need about" in solved.message
    assert solved.bound <= plain.objective * (1 + 1e-9) <= solved.objective * (1 + 1e-9)
    assert_one_checked_path(lazy, solved.x)


def test_mip_memory_problem_names_both_sizes():
    from spidermatch.solve.colgen import MIP_BYTES_PER_COLUMN, mip_memory_problem

    assert mip_memory_problem(1000, room=1000 * MIP_BYTES_PER_COLUMN) is None
    assert "1001 columns" in mip_memory_problem(1001, room=1000 * MIP_BYTES_PER_COLUMN)


def test_two_solves_side_by_side_count_on_half_the_free_memory_each(monkeypatch):
    """Each of two solves side by side counts on half the free memory; RLIMIT_AS is per process."""
    import resource

    from spidermatch import memory
    from spidermatch.solve.colgen import MIP_BYTES_PER_COLUMN, _room

    free = 1000 * MIP_BYTES_PER_COLUMN
    monkeypatch.setattr(memory, "_mem_available", lambda: free)
    monkeypatch.setattr(memory, "_cgroup_room", lambda: None)
    monkeypatch.setattr(memory.resource, "getrlimit", lambda kind: (resource.RLIM_INFINITY,) * 2)
    assert _room(EXACT) == free and _room(replace(EXACT, memory_share=0.5)) == free // 2
    monkeypatch.setattr(memory, "_own_address_space", lambda: 0)
    monkeypatch.setattr(memory.resource, "getrlimit", lambda kind: (free // 4, free // 4))
    assert _room(replace(EXACT, memory_share=0.5)) == free // 4  # the process's own cap, not halved


def test_a_memory_share_outside_zero_to_one_is_refused_by_name():
    from spidermatch.validate import solver_problems

    for share in (0, 1.5, float("nan"), "half"):
        problems = solver_problems(
            {
                "time_limit": 1.0,
                "mip_rel_gap": 0.0,
                "threads": 0,
                "presolve": "choose",
                "strategy": "colgen",
                "memory_share": share,
            },
            ["colgen"],
            "",
        )
        assert [p for p in problems if "memory_share=" in p and "> 0 and <= 1" in p], share


def test_a_further_step_needs_five_seconds_and_five_percent_of_the_limit():
    from spidermatch.solve.colgen import too_little_time_for_a_step

    assert too_little_time_for_a_step(replace(EXACT, time_limit=600.0), 29.0)
    assert not too_little_time_for_a_step(replace(EXACT, time_limit=600.0), 31.0)
    assert too_little_time_for_a_step(replace(EXACT, time_limit=20.0), 4.9)
    assert not too_little_time_for_a_step(EXACT, 1.0)  # no time limit


@pytest.mark.parametrize(
    "threshold, incumbent_gap, expected",
    [(0.01, 0.05, 0.05), (0.01, 0.08, 0.08), (0.01, 0.5, 0.04), (0.0, 0.3, 0.3), (0.02, 0.03, 0.03)],
)
def test_next_threshold_jumps_to_the_incumbent_gap_when_near_and_grows_fourfold_otherwise(
    threshold, incumbent_gap, expected
):
    from spidermatch.solve.colgen import next_threshold

    grown = next_threshold(threshold, incumbent_gap)
    assert grown == pytest.approx(expected)
    assert threshold < grown <= incumbent_gap


def test_useless_beyond_stops_only_a_mip_that_cannot_certify_and_has_nothing_more_to_give():
    from spidermatch.solve.colgen import futile_mip_stop

    stop_when = futile_mip_stop(outside=10.0, near=11.0, rel_gap=0.0)
    assert not stop_when(100.0, 9.9)  # may still certify
    assert not stop_when(100.0, 10.5)  # cannot certify, but a better incumbent would let the next step jump
    assert stop_when(10.8, 10.5)  # cannot certify and its incumbent is near: the next step jumps to U - L
    assert stop_when(100.0, 11.5)  # every solution it holds is far: the next step grows fourfold anyway


def test_first_threshold_is_fixed_up_to_1000_faces_and_grows_with_the_curve_beyond_up_to_twice():
    from spidermatch.solve.colgen import FIRST_STEP, FIRST_STEP_LAYERS, first_threshold

    assert first_threshold(-2.0, FIRST_STEP_LAYERS // 2) == pytest.approx(2 * FIRST_STEP)
    assert first_threshold(2.0, FIRST_STEP_LAYERS) == pytest.approx(2 * FIRST_STEP)
    assert first_threshold(2.0, 2 * FIRST_STEP_LAYERS) == pytest.approx(4 * FIRST_STEP)
    assert first_threshold(2.0, 4 * FIRST_STEP_LAYERS) == pytest.approx(4 * FIRST_STEP)  # capped at twice


def test_a_signal_during_a_restricted_mip_reports_a_bound_for_the_full_model(monkeypatch):
    """The restricted MIP's own bound may exceed the full model's optimum; the reported one may not."""
    import signal

    import spidermatch.solve.colgen as colgen
    from spidermatch.shutdown import RunInterrupted

    lazy = creature_lazy(24, 3)
    plain = solve_plain(lazy.full_model(), lazy.graph, lazy.curve, EXACT)

    def interrupted(lazy, columns, options, incumbent, *rest):
        start = float(lazy.costs(np.flatnonzero(incumbent > 0.5)).sum())
        raise RunInterrupted(signal.SIGTERM, {"incumbent_objective": start, "bound": 1e9})

    monkeypatch.setattr(colgen, "_restricted_mip", interrupted)
    monkeypatch.setattr(colgen, "_lp_incumbent", lambda lazy, lp: None)
    with pytest.raises(RunInterrupted) as stop:
        solve_with_strategy("colgen", lazy, lazy.graph, lazy.curve, EXACT)
    known = stop.value.known
    assert known["bound"] <= plain.objective * (1 + 1e-9)
    assert known["gap"] == pytest.approx(
        (known["incumbent_objective"] - known["bound"]) / abs(known["incumbent_objective"])
    )


def test_full_model_figures_of_an_interrupted_mip_take_the_lp_bound_without_a_mip_bound():
    from spidermatch.solve.colgen import interrupted_full_model_figures

    assert interrupted_full_model_figures({"bound": None}, 10.0, 12.0) == {"bound": 10.0, "gap": None}
    figures = interrupted_full_model_figures({"bound": 15.0, "incumbent_objective": 20.0}, 10.0, 12.0)
    assert figures == {"bound": 12.0, "gap": pytest.approx(0.4)}
    assert interrupted_full_model_figures({"bound": 5.0}, 10.0, 12.0)["bound"] == 10.0


def test_every_strategy_raises_the_one_lp_not_solved():
    """An ``except LpNotSolved`` must catch a stopped LP from either module (there were two classes)."""
    from spidermatch.solve import colgen, rcfix, types

    assert colgen.LpNotSolved is rcfix.LpNotSolved is types.LpNotSolved


def test_a_wider_mip_out_of_memory_without_a_solution_keeps_the_last_step_and_says_why(monkeypatch):
    import math

    import spidermatch.solve.colgen as colgen
    from spidermatch.solve.types import SolveResult

    lazy = creature_lazy(24, 3)
    plain = solve_plain(lazy.full_model(), lazy.graph, lazy.curve, EXACT)
    calls = []

    def stopped_then_out_of_memory(lazy, columns, options, incumbent, *rest):
        calls.append(columns.size)
        if len(calls) > 1:
            return SolveResult(
                "no_solution", None, math.inf, -math.inf, math.nan, 0.0, 1, 1, 1, OUT_OF_MEMORY
            )
        start = float(lazy.costs(np.flatnonzero(incumbent > 0.5)).sum())
        return SolveResult(
            "feasible", incumbent, start, -math.inf, math.nan, 0.0, columns.size, 1, 1, "stopped"
        )

    monkeypatch.setattr(colgen, "_restricted_mip", stopped_then_out_of_memory)
    monkeypatch.setattr(colgen, "_lp_incumbent", lambda lazy, lp: None)
    solved = solve_with_strategy("colgen", lazy, lazy.graph, lazy.curve, replace(EXACT, time_limit=600.0))
    assert len(calls) == 2 and solved.status == "feasible" and "ran out of memory" in solved.message
    assert solved.bound <= plain.objective * (1 + 1e-9) <= solved.objective * (1 + 1e-9)
    assert_one_checked_path(lazy, solved.x)


@pytest.mark.parametrize("strategy", ["colgen", "rcfix", "plain"])
@pytest.mark.parametrize("seed", [3, 4])
def test_flow_rows_in_every_intersection_layer_keep_the_optimum_without_cut_rounds(strategy, seed, caplog):
    lazy = creature_lazy(24, seed)
    assert lazy.curve.is_intersection_layer.any()
    model = lazy if strategy == "colgen" else lazy.full_model()
    plain = solve_plain(lazy.full_model(), lazy.graph, lazy.curve, EXACT)
    options = replace(EXACT, flow_rows="intersections")
    with caplog.at_level("INFO"):
        solved = solve_with_strategy(strategy, model, lazy.graph, lazy.curve, options)
    # the instance needs a MIP (its LP solution is not a path); plain's full model always is one
    assert strategy == "plain" or "MIP over" in caplog.text
    assert solved.status == "optimal"
    assert solved.objective == pytest.approx(plain.objective, rel=1e-9)
    assert_one_checked_path(lazy, solved.x)
    n_intersections = int(lazy.curve.is_intersection_layer.sum())
    assert f"in {n_intersections} layers" in caplog.text  # from the first MIP on
    assert "cut round" not in caplog.text


def ablation_without_con(seed):
    base = creature_lazy(24, seed)
    families = ("CYC", "PES", "ANS")
    return LazyModel(
        base.graph, base.curve, base.source_verts, base.target_verts, base.vertex_costs, families
    )


def test_colgen_adds_no_connectivity_cuts_to_an_ablation_without_con(monkeypatch):
    """Without CON a solution need not be one closed path: cuts that exclude detached cycles would cut
    off the ablation's own optimum."""
    from spidermatch.solve.cuts import CutPool

    lazy = ablation_without_con(3)
    cut_calls = []
    original = CutPool.add_two_cycle_cuts
    monkeypatch.setattr(
        CutPool, "add_two_cycle_cuts", lambda pool, *args: cut_calls.append(1) or original(pool, *args)
    )
    solved = solve_with_strategy(
        "colgen", lazy, lazy.graph, lazy.curve, replace(EXACT, flow_rows="intersections")
    )
    plain = solve_plain(lazy.full_model(), lazy.graph, lazy.curve, EXACT)
    assert not cut_calls
    assert solved.status == "optimal"
    assert solved.objective == pytest.approx(plain.objective, rel=1e-9)


def test_pool_flow_rows_are_not_added_to_a_model_without_con(caplog):
    """The flow rows a pool holds (every intersection layer, as ``flow_rows="intersections"`` seeds it)
    exclude detached cycles too: a model without CON gets none."""
    from spidermatch.solve.cuts import CutPool, solve_with_cuts

    lazy = ablation_without_con(3)
    pool = CutPool(first_layer=lazy.curve.first_layer)
    pool.flow_layers |= {int(layer) for layer in np.flatnonzero(lazy.curve.is_intersection_layer)}
    model = lazy.full_model()
    with caplog.at_level("INFO"):
        solved = solve_with_cuts(model, lazy.graph, EXACT, pool=pool)
    assert "flow rows keep the path" not in caplog.text
    assert solved.objective == pytest.approx(
        solve_plain(model, lazy.graph, lazy.curve, EXACT).objective, rel=1e-9
    )


def test_a_wider_mip_that_proves_less_keeps_the_bound_of_the_step_before(monkeypatch, caplog):
    """Step 1 proves a bound for the full model, step 2 (wider) is stopped with a weaker MIP bound: the
    answer keeps step 1's (each step's bound holds for the full model)."""
    import re

    import spidermatch.solve.colgen as colgen

    lazy = creature_lazy(24, 3)
    plain = solve_plain(lazy.full_model(), lazy.graph, lazy.curve, EXACT)
    calls = []

    def weaker_each_step(lazy, columns, options, incumbent, *rest):
        calls.append(columns.size)
        bound = plain.objective * (0.9999 if len(calls) == 1 else 0.5)  # both valid, the second weaker
        return stopped_at_start(lazy, columns, incumbent, bound)

    monkeypatch.setattr(colgen, "_restricted_mip", weaker_each_step)
    monkeypatch.setattr(colgen, "_lp_incumbent", lambda lazy, lp: None)
    monkeypatch.setattr(colgen, "MAX_STEPS", 2)
    with caplog.at_level("INFO", logger="spidermatch.solve.colgen"):
        solved = solve_with_strategy("colgen", lazy, lazy.graph, lazy.curve, EXACT)
    first = float(re.search(r"colgen step 1: .* bound for the full model (\S+)", caplog.text).group(1))
    assert len(calls) == 2 and solved.status == "feasible"
    assert solved.bound == pytest.approx(first, rel=1e-7) and solved.bound <= plain.objective * (1 + 1e-9)
