import itertools
import math

import numpy as np
import pytest

from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.remesh import decimate
from spidermatch.model.curve import (
    TOURS,
    CurveError,
    SpiderCurve,
    check_curve,
    greedy_perfect_matching,
    spider_curve,
    two_opt_tour,
)


@pytest.mark.parametrize("augmented", [False, True])
@pytest.mark.parametrize(
    "matching, tour", [("greedy", "christofides"), ("blossom", "christofides"), ("greedy", "two_opt")]
)
@pytest.mark.parametrize("shape_seed, faces", [(7, 200), (11, 120), (3, 300)])
def test_spider_curve_invariants(augmented, matching, tour, shape_seed, faces):
    mesh = decimate(make_creature(1500, shape_seed).mesh, faces).mesh
    curve = spider_curve(mesh, augmented=augmented, seed=3, matching=matching, tour=tour)
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


def test_two_opt_finds_the_optimal_tour_of_points_in_convex_position():
    """Points on a circle: a tour without crossings is the optimum, which brute force confirms."""
    rng = np.random.default_rng(4)
    angles = np.sort(rng.uniform(0, 2 * np.pi, 8))
    points = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    distances = np.linalg.norm(points[:, None] - points[None], axis=2)
    shuffled = np.concatenate([[0], rng.permutation(np.arange(1, 8))])

    def length(order):
        return distances[order, np.roll(order, -1)].sum()

    best = min(length(np.array((0, *rest))) for rest in itertools.permutations(range(1, 8)))
    improved = two_opt_tour(shuffled, distances, neighbours=7)
    assert improved[0] == 0 and sorted(improved.tolist()) == list(range(8))
    assert length(shuffled) > best + 1e-6  # the start is not already optimal
    assert length(improved) == pytest.approx(best)


def test_two_opt_curve_is_shorter_with_fewer_self_intersections():
    mesh = decimate(make_creature(3000, 5).mesh, 600).mesh
    paper, shortened = spider_curve(mesh, seed=2), spider_curve(mesh, seed=2, tour="two_opt")
    assert shortened.length < paper.length
    assert shortened.intersections.size < paper.intersections.size
    check_curve(shortened, mesh.edges)
    with pytest.raises(ValueError, match="unknown curve tour"):
        spider_curve(mesh, tour="or_opt")


def _tour_pair():
    """A creature and another pose of it, coordinates as features: a pair that certifies in seconds."""
    source, target = make_creature(900, 3).mesh, make_creature(900, 4).mesh
    return source, target, source.centred().verts, target.centred().verts


def _recording_solver(monkeypatch, first_status: str, second_status: str = "optimal") -> list:
    """Replace the pipeline's solve: the real one, then each tour's result given the status asked for.

    Returns the list to which each call appends (curve length, time limit, status returned, solve time).
    """
    import dataclasses

    from spidermatch import pipeline

    real, calls = pipeline.solve_with_strategy, []

    def solve(strategy, model, graph, curve, options):
        solved = real(strategy, model, graph, curve, options)
        status = (first_status, second_status)[len(calls)]
        if status == "feasible":  # the same matching, not proven: half its objective as the bound
            solved = dataclasses.replace(solved, status=status, bound=solved.objective / 2, gap=0.5)
        elif status in ("no_solution", "infeasible"):
            solved = dataclasses.replace(solved, status=status, x=None, objective=math.inf, gap=math.nan)
        elif status == "within_gap":  # a loose requested gap met: "feasible" within it
            solved = dataclasses.replace(solved, status="feasible", gap=options.mip_rel_gap / 2)
        elif status == "raise":
            raise RuntimeError("out of memory building the second tour")
        calls.append((curve.length, options.time_limit, solved.status, solved.wall_time))
        return solved

    monkeypatch.setattr(pipeline, "solve_with_strategy", solve)
    return calls


def _auto_settings(time_limit: float = 100.0):
    from spidermatch.pipeline import MatchSettings
    from spidermatch.solve.types import SolverOptions

    solver = SolverOptions(time_limit=time_limit)
    return MatchSettings(
        resolution=120, strategy="colgen", curve_tour="auto", isolate_solver=False, dense=None, solver=solver
    )


def test_auto_tour_keeps_the_papers_curve_when_it_certifies_within_its_share(monkeypatch):
    from spidermatch.pipeline import AUTO_TOUR_SHARE, match

    calls = _recording_solver(monkeypatch, "optimal")
    result = match(*_tour_pair(), _auto_settings(100.0))
    assert [limit for _, limit, *_ in calls] == [pytest.approx(AUTO_TOUR_SHARE * 100.0)]
    assert result.solve.status == "optimal" and result.check.ok
    tried = [(t["tour"], t["status"], t["chosen"]) for t in result.tours]
    assert tried == [("christofides", "optimal", True)]
    paper = spider_curve(result.source.mesh)  # the curve matched is the paper's
    assert np.array_equal(result.curve.vertices, paper.vertices)


def test_auto_tour_tries_the_shortened_curve_in_the_time_left_and_keeps_the_certified_one(monkeypatch):
    from spidermatch.pipeline import match

    calls = _recording_solver(monkeypatch, "feasible", "optimal")
    result = match(*_tour_pair(), _auto_settings(100.0))
    (first_length, first_limit, *_), (second_length, second_limit, *_) = calls
    first_time = result.tours[0]["solve_s"]
    assert second_limit == pytest.approx(100.0 - first_time, abs=0.01)  # the whole budget, no more
    assert second_length < first_length  # the 2-opt curve is the shorter
    assert [(t["tour"], t["status"], t["chosen"]) for t in result.tours] == [
        ("christofides", "feasible", False),
        ("two_opt", "optimal", True),
    ]
    assert result.solve.status == "optimal" and result.curve.length == second_length and result.check.ok
    shortened = spider_curve(result.source.mesh, tour="two_opt")
    assert np.array_equal(result.curve.vertices, shortened.vertices)
    assert result.timings["solve"] >= sum(t["solve_s"] for t in result.tours) - 0.01  # both solves counted


def test_auto_tour_keeps_the_first_matching_when_the_second_tour_finds_none(monkeypatch):
    from spidermatch.pipeline import match

    calls = _recording_solver(monkeypatch, "feasible", "no_solution")
    result = match(*_tour_pair(), _auto_settings(100.0))
    assert [status for _, _, status, _ in calls] == ["feasible", "no_solution"]
    assert result.tours[0]["chosen"] and not result.tours[1]["chosen"]
    assert result.solve.status == "feasible" and result.low_map is not None and result.check.ok
    assert result.curve.length == calls[0][0]  # the first tour's solution, held while the second ran


def test_an_unknown_tour_is_refused_by_name_in_the_api():
    import dataclasses

    from spidermatch.pipeline import match
    from spidermatch.validate import OptionError

    settings = dataclasses.replace(_auto_settings(), curve_tour="three_opt")
    with pytest.raises(OptionError, match="curve_tour='three_opt': choose from christofides, two_opt, auto"):
        match(*_tour_pair(), settings)


@pytest.mark.parametrize("limit, first_limit", [(15.0, 15.0), (math.inf, math.inf), (100.0, 40.0)])
def test_auto_tour_gives_the_papers_curve_all_of_a_limit_too_short_to_share(monkeypatch, limit, first_limit):
    from spidermatch.pipeline import match

    calls = _recording_solver(monkeypatch, "feasible", "optimal")
    match(*_tour_pair(), _auto_settings(limit))
    assert calls[0][1] == first_limit  # 15 s: its 60 % would be under MIN_SECOND_TOUR_S
    assert calls[1][1] == pytest.approx(limit - calls[0][3], abs=0.01)  # stopped early: the rest is used


@pytest.mark.parametrize(
    "first, second, tried, kept",
    [
        ("infeasible", "optimal", 2, "two_opt"),  # infeasibility is the curve's: the other is tried
        ("within_gap", "optimal", 1, "christofides"),  # the requested gap is met: nothing to try
        ("feasible", "raise", 1, "christofides"),  # a second tour that fails leaves the first's map
    ],
)
def test_auto_tour_second_tour_only_when_it_can_help_and_never_at_the_first_maps_cost(
    monkeypatch, first, second, tried, kept
):
    import dataclasses

    from spidermatch.pipeline import match

    calls = _recording_solver(monkeypatch, first, second)
    settings = _auto_settings(100.0)
    if first == "within_gap":
        loose = dataclasses.replace(settings.solver, mip_rel_gap=0.05)
        settings = dataclasses.replace(settings, solver=loose)
    result = match(*_tour_pair(), settings)
    assert len(result.tours) == tried and len(calls) == tried
    assert [t["tour"] for t in result.tours if t["chosen"]] == [kept]
    if kept == "christofides" and first != "infeasible":
        assert result.low_map is not None and result.check.ok


def _side_by_side_solver(monkeypatch, hanging: str | None = None) -> dict:
    """Record each tour's curve length while it is prepared; the solve (in its solver process) then
    reports its options in its message, and the ``hanging`` tour's never ends (it sleeps past its limit).

    Returns the tour of each prepared curve length (filled by ``match``).
    """
    import dataclasses
    import time

    from spidermatch import pipeline

    real_prepare, real_solve, tour_of_length = pipeline.prepare, pipeline.solve_with_strategy, {}

    def prepare(*args, **kwargs):
        prepared = real_prepare(*args, **kwargs)
        tour_of_length[prepared[2].length] = args[4].curve_tour
        return prepared

    def solve(strategy, model, graph, curve, options):  # runs in the solver process
        if tour_of_length[curve.length] == hanging:
            time.sleep(3 * options.time_limit)
        solved = real_solve(strategy, model, graph, curve, options)
        return dataclasses.replace(solved, message=f"threads={options.threads} share={options.memory_share}")

    monkeypatch.setattr(pipeline, "prepare", prepare)
    monkeypatch.setattr(pipeline, "solve_with_strategy", solve)
    return tour_of_length


def _isolated_auto_settings(time_limit: float = 30.0):
    import dataclasses

    return dataclasses.replace(_auto_settings(time_limit), isolate_solver=True)


@pytest.mark.parametrize("hanging, kept", [("two_opt", "christofides"), ("christofides", "two_opt")])
def test_auto_tour_side_by_side_stops_the_other_tour_once_one_is_certified(monkeypatch, hanging, kept):
    from spidermatch import pipeline
    from spidermatch.solve.isolate import CANCELLED

    monkeypatch.setattr(pipeline, "usable_cores", lambda: 4)
    tour_of_length = _side_by_side_solver(monkeypatch, hanging)
    result = pipeline.match(*_tour_pair(), _isolated_auto_settings(30.0))
    assert sorted(tour_of_length.values()) == ["christofides", "two_opt"]  # both prepared before solving
    records = {t["tour"]: t for t in result.tours}
    assert all(t["side_by_side"] for t in result.tours)
    assert records[kept]["chosen"] and records[kept]["status"] == "optimal"
    assert records[kept]["message"] == "threads=2 share=0.5"  # half the cores and memory each
    # the hanging tour was stopped once the other was certified, not at its limit
    assert records[hanging]["status"] == "no_solution" and CANCELLED in records[hanging]["message"]
    assert tour_of_length[result.curve.length] == kept and result.check.ok
    assert result.solve.status == "optimal"


def test_auto_tour_on_one_core_solves_the_tours_in_turn(monkeypatch):
    import dataclasses

    from spidermatch import pipeline

    monkeypatch.setattr(pipeline, "usable_cores", lambda: 1)
    _side_by_side_solver(monkeypatch)
    result = pipeline.match(*_tour_pair(), _isolated_auto_settings(30.0))
    tried = [(t["tour"], t["side_by_side"], t["chosen"]) for t in result.tours]
    assert tried == [("christofides", False, True)]
    assert result.tours[0]["message"] == "threads=0 share=1.0"  # the settings as given
    assert pipeline.side_by_side_threads(_auto_settings()) == 0  # no solver processes: in turn too
    monkeypatch.setattr(pipeline, "usable_cores", lambda: 4)
    one_thread = _isolated_auto_settings()
    one_thread = dataclasses.replace(one_thread, solver=dataclasses.replace(one_thread.solver, threads=1))
    assert pipeline.side_by_side_threads(one_thread) == 0  # solver.threads=1: one core, in turn
    assert pipeline.side_by_side_threads(_isolated_auto_settings()) == 2


def test_auto_tour_side_by_side_keeps_the_certified_tour_when_the_other_fails(monkeypatch):
    from spidermatch import pipeline

    monkeypatch.setattr(pipeline, "usable_cores", lambda: 2)
    tour_of_length = _side_by_side_solver(monkeypatch)
    real = pipeline.solve_with_strategy

    def solve(strategy, model, graph, curve, options):
        if tour_of_length[curve.length] == "christofides":
            raise RuntimeError("a failure inside the paper's tour's solve")
        return real(strategy, model, graph, curve, options)

    monkeypatch.setattr(pipeline, "solve_with_strategy", solve)
    result = pipeline.match(*_tour_pair(), _isolated_auto_settings(30.0))
    records = {t["tour"]: t for t in result.tours}
    failed = records["christofides"]
    assert failed["status"] == "error" and "a failure inside" in failed["message"]
    assert records["two_opt"]["chosen"] and records["two_opt"]["message"] == "threads=1 share=0.5"
    assert result.solve.status == "optimal" and result.check.ok


def test_auto_tour_side_by_side_stops_both_solver_processes_on_a_signal(monkeypatch):
    import os
    import signal
    import threading
    import time

    from spidermatch import pipeline, shutdown

    monkeypatch.setattr(pipeline, "usable_cores", lambda: 2)
    prepared = _side_by_side_solver(monkeypatch)
    real = pipeline.solve_with_strategy

    def solve(strategy, model, graph, curve, options):  # both hang: only a signal ends them early
        time.sleep(3 * options.time_limit)
        return real(strategy, model, graph, curve, options)

    monkeypatch.setattr(pipeline, "solve_with_strategy", solve)

    returned = threading.Event()

    def signal_once_both_solve():
        while len(prepared) < 2:
            time.sleep(0.05)
        time.sleep(1.0)
        if not returned.is_set():  # never at pytest itself once the match is over
            os.kill(os.getpid(), signal.SIGTERM)

    before = set(_children_of_this_process())  # another test's, if any
    threading.Thread(target=signal_once_both_solve, daemon=True).start()
    # at the limit both processes would be killed and the run would end without an interrupt
    try:
        with shutdown.signals_handled(), pytest.raises(shutdown.RunInterrupted) as stopped:
            pipeline.match(*_tour_pair(), _isolated_auto_settings(60.0))
    finally:
        returned.set()
    assert stopped.value.signum == signal.SIGTERM and stopped.value.known["curve_tour"] in TOURS
    assert set(_children_of_this_process()) <= before  # both solver processes ended and reaped


def _children_of_this_process() -> list[int]:
    from test_isolate import children_of_this_process

    return children_of_this_process()
