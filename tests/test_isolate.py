"""The solver process (issue 28): results, exceptions and deaths of the child reach the parent."""

import math
import os
import signal
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from spidermatch.solve import isolate
from spidermatch.solve.isolate import KnownFigures, describe_exit, solve_isolated
from spidermatch.solve.progress import report_known
from spidermatch.solve.types import OUT_OF_MEMORY, SolveResult, SolverOptions

MODEL = SimpleNamespace(n_vars=7, n_rows=3, nnz=12)


def returning(model, graph, curve, options):
    report_known(incumbent=5.0, bound=4.0)
    x = np.arange(model.n_vars, dtype=np.float64)
    return SolveResult("optimal", x, 5.0, 5.0, 0.0, 0.1, model.n_vars, model.n_rows, model.nnz, "Optimal")


def raising(model, graph, curve, options):
    raise ValueError("unknown solving strategy 'nope'")


def dying(model, graph, curve, options):
    report_known(incumbent=3.0)
    os.kill(os.getpid(), signal.SIGSEGV)


def test_the_child_result_comes_back_whole():
    result = solve_isolated(returning, MODEL, None, None, SolverOptions())
    assert result.status == "optimal" and result.objective == 5.0
    np.testing.assert_array_equal(result.x, np.arange(7.0))


def test_an_exception_in_the_child_is_raised_in_the_parent():
    with pytest.raises(ValueError, match="unknown solving strategy"):
        solve_isolated(raising, MODEL, None, None, SolverOptions())


def test_a_child_killed_by_a_signal_gives_an_error_result_with_the_figures_it_reported():
    result = solve_isolated(dying, MODEL, None, None, SolverOptions())
    assert result.status == "error" and result.x is None
    assert result.objective == 3.0 and result.bound == -math.inf and math.isnan(result.gap)
    assert "SIGSEGV (exit 139)" in result.message and "the retry died too" in result.message
    assert (result.n_vars, result.n_rows) == (7, 3)


def dying_with_heuristics(model, graph, curve, options):
    """Aborts as HiGHS 1.16 did inside a heuristic, unless the heuristics are off; a path first."""
    if options.extra.get("mip_heuristic_effort") != 0.0:
        report_known(incumbent=4.0, bound=3.5, path=np.array([2, 5]))
        os.abort()
    x = np.zeros(model.n_vars)
    x[[0, 1, 6]] = 1.0
    return SolveResult("optimal", x, 4.5, 3.9, 0.0, 0.1, model.n_vars, model.n_rows, model.nnz, "Optimal")


def test_a_child_that_dies_is_retried_with_the_heuristics_off_and_the_better_of_both_kept():
    options = SolverOptions(time_limit=60.0, mip_rel_gap=0.2, extra={"presolve": "on"})
    result = solve_isolated(dying_with_heuristics, MODEL, None, None, options)
    assert "retried after the solver process died" in result.message
    # the dead child's closed path (4.0) is cheaper than the retry's (4.5); the retry's bound larger
    assert result.objective == 4.0 and result.bound == 3.9
    np.testing.assert_array_equal(np.flatnonzero(result.x), [2, 5])
    assert result.status == "optimal" and result.gap == pytest.approx(0.025)
    # no time for a retry: the dead child's closed path, with its bound, not an error
    no_time = SolverOptions(time_limit=isolate.RETRY_MIN_S / 2, mip_rel_gap=0.2)
    kept = solve_isolated(dying_with_heuristics, MODEL, None, None, no_time)
    assert kept.status == "optimal" and kept.objective == 4.0 and kept.bound == 3.5
    assert "no time left for a retry" in kept.message
    np.testing.assert_array_equal(np.flatnonzero(kept.x), [2, 5])


def dying_on_many_threads(model, graph, curve, options):
    """Aborts as an allocation failing on a HiGHS worker thread does, unless HiGHS runs on one."""
    if options.threads != 1:
        os.abort()
    x = np.zeros(model.n_vars)
    x[[0, 3]] = 1.0
    return SolveResult("feasible", x, 4.5, 3.9, 0.1, 0.1, model.n_vars, model.n_rows, model.nnz, "stopped")


def test_the_retry_runs_highs_on_one_thread():
    result = solve_isolated(
        dying_on_many_threads, MODEL, None, None, SolverOptions(time_limit=60.0, threads=2)
    )
    assert result.status == "feasible" and "retried after the solver process died" in result.message
    np.testing.assert_array_equal(np.flatnonzero(result.x), [0, 3])


def hanging_after_a_path(model, graph, curve, options):
    """Reports an incumbent with its solution and a bound, then never returns (HiGHS in a phase
    without interrupt checks)."""
    report_known(incumbent=2.0, bound=1.5, path=np.array([1, 4]))
    report_known(incumbent=1.9)  # a cheaper one reported without its solution
    time.sleep(600)


def hanging_before_any_path(model, graph, curve, options):
    report_known(bound=1.5)
    time.sleep(600)


def test_a_solver_process_past_its_time_limit_is_stopped_and_its_last_path_returned(monkeypatch):
    monkeypatch.setattr(isolate, "OVERRUN_KILL_S", 0.5)
    result = solve_isolated(hanging_after_a_path, MODEL, None, None, SolverOptions(time_limit=0.5))
    assert result.status == "feasible" and "past the time limit" in result.message
    np.testing.assert_array_equal(result.x, [0, 1, 0, 0, 1, 0, 0])
    assert (result.objective, result.bound) == (2.0, 1.5) and result.gap == pytest.approx(0.25)


def test_a_stopped_solver_process_whose_path_is_within_the_gap_is_optimal(monkeypatch):
    monkeypatch.setattr(isolate, "OVERRUN_KILL_S", 0.5)
    options = SolverOptions(time_limit=0.5, mip_rel_gap=0.3)
    assert solve_isolated(hanging_after_a_path, MODEL, None, None, options).status == "optimal"


def test_a_solver_process_stopped_before_any_path_has_no_solution(monkeypatch):
    monkeypatch.setattr(isolate, "OVERRUN_KILL_S", 0.5)
    result = solve_isolated(hanging_before_any_path, MODEL, None, None, SolverOptions(time_limit=0.5))
    assert result.status == "no_solution" and result.x is None and result.bound == 1.5


def test_paths_found_by_a_restricted_solve_are_reported_in_full_model_columns():
    """rcfix solves restricted models: each reported incumbent must be a closed path of the
    full model with the reported cost (else a stopped run would return a wrong matching)."""
    from spidermatch.solve.connectivity import is_closed_path
    from spidermatch.solve.progress import set_known_sink
    from spidermatch.solve.strategies import solve_with_strategy
    from tests.test_ilp import creature_instance

    curve, graph, model = creature_instance(60, seed=5)
    reported = []
    set_known_sink(lambda incumbent, bound, path: path is None or reported.append((incumbent, path)))
    try:
        result = solve_with_strategy("rcfix", model, graph, curve, SolverOptions(time_limit=60.0))
    finally:
        set_known_sink(None)
    assert result.status == "optimal" and reported
    for objective, path in reported:
        x = np.zeros(model.n_vars)
        x[path] = 1.0
        assert model.costs @ x == pytest.approx(objective, rel=1e-9)
        rows = model.matrix @ x
        assert np.all(rows >= model.row_lower - 1e-9) and np.all(rows <= model.row_upper + 1e-9)
        assert is_closed_path(graph, x)
    assert min(objective for objective, _ in reported) == pytest.approx(result.objective, rel=1e-9)


def test_known_figures_keep_the_cheapest_incumbent_and_the_largest_bound():
    known = KnownFigures()
    assert known.as_dict() == {"incumbent_objective": None, "bound": None, "gap": None}
    assert known.update(10.0, 8.0) and not known.update(11.0, 7.0) and known.update(None, 9.0)
    assert known.as_dict() == {"incumbent_objective": 10.0, "bound": 9.0, "gap": pytest.approx(0.1)}


def test_exits_are_described_in_words():
    assert describe_exit(-6) == "SIGABRT (exit 134)"
    assert describe_exit(1) == "exit code 1"


def test_a_solver_process_forked_after_a_solve_in_the_parent_solves_too():
    """HiGHS keeps a thread pool per calling thread: the child's solves run on a thread of its own.

    (A child forked from a process whose forking thread had run HiGHS could wait for workers it
    does not have.)
    """
    from functools import partial

    from spidermatch.solve.highs import solve_model
    from spidermatch.solve.strategies import solve_with_strategy
    from tests.test_ilp import creature_instance

    curve, graph, model = creature_instance(24, seed=3)
    in_parent = solve_model(model, SolverOptions(time_limit=60.0))
    in_child = solve_isolated(partial(solve_with_strategy, "plain"), model, graph, curve, SolverOptions(60.0))
    assert in_parent.status == in_child.status == "optimal"
    assert in_child.objective == pytest.approx(in_parent.objective, rel=1e-9)


def _match_in_pool_worker(seed):
    """(status, whether a solver process was started) of a small match."""
    import logging

    import spidermatch
    from spidermatch.data.synthetic import make_creature

    messages = []
    handler = logging.Handler()
    handler.emit = lambda record: messages.append(record.getMessage())
    logger = logging.getLogger("spidermatch.solve.isolate")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    source, target = make_creature(600, seed=seed).mesh, make_creature(600, seed=seed + 1).mesh
    status = spidermatch.match(source, target, resolution=40).status
    return status, any(message.startswith("solver process") for message in messages)


def test_a_match_inside_a_multiprocessing_pool_worker_has_a_solver_process_too():
    """``multiprocessing`` refuses children to the pool's daemonic workers; the solver process is
    forked directly, so a run there is also protected from native crashes and overruns."""
    import multiprocessing

    with multiprocessing.get_context("fork").Pool(1) as pool:
        assert pool.apply(_match_in_pool_worker, (3,)) == ("optimal", True)


def path_and_detached_copy(lazy):
    """The optimum of ``lazy`` (edge ids), and a copy with a detached intra-layer 2-cycle added."""
    from spidermatch.model.correspondence import extract_path
    from spidermatch.model.product_graph import INTRA
    from spidermatch.solve.plain import solve_plain
    from tests.test_ilp import edge_id

    graph = lazy.graph
    optimum = solve_plain(lazy.full_model(), graph, lazy.curve, SolverOptions(mip_rel_gap=0.0)).x
    visited = {(int(layer), int(y)) for layer, y in extract_path(graph, optimum).layer_vertex_pairs()}
    target_edges = graph.target_edges[: graph.target_edges.shape[0] // 2].tolist()
    layer, a, b = next(
        (layer, a, b)
        for layer in range(graph.n_layers)
        for a, b in target_edges
        if (layer, a) not in visited and (layer, b) not in visited
    )
    two_cycle = [edge_id(graph, layer, a, b, INTRA), edge_id(graph, layer, b, a, INTRA)]
    path = np.flatnonzero(optimum > 0.5)
    return path, np.sort(np.concatenate([path, two_cycle]))


def hanging_with_a_cheaper_detached_solution(expensive, detached, lazy, graph, curve, options):
    """Reports an expensive closed path, then a cheaper solution with detached cycles, and hangs
    (the MIP stuck in a phase without callbacks that 4000 faces show)."""
    from spidermatch.solve.progress import report_detached

    report_known(incumbent=float(lazy.costs(expensive).sum()), bound=0.0, path=expensive)
    report_detached(float(lazy.costs(detached).sum()), detached)
    time.sleep(600)


def _recorded(cls, instances: list):
    """``cls`` whose every new instance is appended to ``instances``."""

    def make(*args, **kwargs):
        instances.append(cls(*args, **kwargs))
        return instances[-1]

    return make


def test_a_solver_stuck_with_a_cheaper_detached_solution_gives_way_to_its_repair_in_the_reserve(monkeypatch):
    """The parent stops the child when the reserve begins and repairs the reported solution in a
    fresh process: the run ends with a closed path near it, within the limit, not the stay path."""
    from functools import partial

    from spidermatch.solve.connectivity import detached_components
    from spidermatch.solve.seeds import stay_seed
    from tests.test_colgen import creature_lazy

    lazy = creature_lazy(24, 3)
    path, detached = path_and_detached_copy(lazy)
    stay = np.sort(stay_seed(lazy))
    limit = 20.0
    monkeypatch.setattr(isolate, "parent_reserve", lambda time_limit: time_limit - 1.0)  # repair after 1 s
    forked = []
    monkeypatch.setattr(isolate, "ForkedChild", _recorded(isolate.ForkedChild, forked))
    child = partial(hanging_with_a_cheaper_detached_solution, stay, detached)
    result = solve_isolated(child, lazy, lazy.graph, lazy.curve, SolverOptions(time_limit=limit))
    # the hanging solver was killed when the reserve began, not waited for (it sleeps 600 s)
    assert forked[0].exitcode == -signal.SIGKILL
    assert result.status == "feasible" and "repair" in result.message and result.bound == 0.0
    assert detached_components(lazy.graph, result.x) == []
    uses = np.flatnonzero(result.x > 0.5)
    assert result.objective == pytest.approx(lazy.costs(uses).sum())
    assert result.objective < lazy.costs(stay).sum()  # better than the path the child had
    assert result.objective == pytest.approx(lazy.costs(path).sum(), rel=1e-3)  # the 2-cycle dropped


def test_a_detached_solution_older_than_the_last_closed_path_is_left_alone(monkeypatch):
    from functools import partial

    from spidermatch.solve.progress import report_detached
    from tests.test_colgen import creature_lazy

    lazy = creature_lazy(24, 3)
    path, detached = path_and_detached_copy(lazy)

    def detached_then_path(lazy, graph, curve, options):
        report_detached(float(lazy.costs(detached).sum()) - 1.0, detached)
        report_known(incumbent=float(lazy.costs(path).sum()), bound=0.0, path=path)
        time.sleep(600)

    monkeypatch.setattr(isolate, "OVERRUN_KILL_S", 0.5)
    monkeypatch.setattr(isolate, "parent_reserve", lambda time_limit: time_limit - 0.2)
    result = solve_isolated(
        partial(detached_then_path), lazy, lazy.graph, lazy.curve, SolverOptions(time_limit=1.0)
    )
    assert "past the time limit" in result.message and "repair" not in result.message
    np.testing.assert_array_equal(np.flatnonzero(result.x), path)


def test_a_child_that_repairs_itself_is_left_to_its_repair(monkeypatch):
    from functools import partial

    from spidermatch.solve.progress import report_detached, report_repairing
    from tests.test_colgen import creature_lazy

    lazy = creature_lazy(24, 3)
    path, detached = path_and_detached_copy(lazy)

    def repairing_itself(lazy, graph, curve, options):
        report_known(incumbent=float(lazy.costs(path).sum()), bound=0.0, path=path)
        report_detached(float(lazy.costs(detached).sum()) - 1.0, detached)
        report_repairing()
        time.sleep(600)

    monkeypatch.setattr(isolate, "OVERRUN_KILL_S", 0.5)
    monkeypatch.setattr(isolate, "parent_reserve", lambda time_limit: time_limit - 0.2)
    result = solve_isolated(
        partial(repairing_itself), lazy, lazy.graph, lazy.curve, SolverOptions(time_limit=1.0)
    )
    assert "past the time limit" in result.message and "repair" not in result.message


def test_highs_out_of_memory_keeps_its_incumbent_and_claims_no_bound():
    """HiGHS's `Memory limit reached` is a stop (the incumbent kept), not an error, and no certificate."""
    import highspy

    from spidermatch.solve.highs import _read_result

    status = highspy.HighsModelStatus

    def session(model_status, has_solution):
        info = SimpleNamespace(
            primal_solution_status=2 if has_solution else 0, objective_function_value=7.0, mip_dual_bound=6.9
        )
        highs = SimpleNamespace(
            getModelStatus=lambda: model_status,
            getInfo=lambda: info,
            modelStatusToString=lambda s: (
                "Memory limit reached" if s == status.kMemoryLimit else "Time limit reached"
            ),
            getSolution=lambda: SimpleNamespace(col_value=[1.0, 0.0, 1.0]),
        )
        return SimpleNamespace(highs=highs, relax=False, options=SolverOptions(), n_vars=3, n_rows=1, nnz=3)

    stopped = _read_result(session(status.kMemoryLimit, True), 1.0)
    assert stopped.status == "feasible" and stopped.out_of_memory and stopped.objective == 7.0
    assert stopped.bound == -math.inf and math.isnan(stopped.gap)
    np.testing.assert_array_equal(stopped.x, [1.0, 0.0, 1.0])
    assert _read_result(session(status.kMemoryLimit, False), 1.0).status == "no_solution"
    assert not _read_result(session(status.kTimeLimit, True), 1.0).out_of_memory


def dying_after_a_detached_solution(expensive, detached, lazy, graph, curve, options, always_dies=False):
    """Reports an expensive closed path and a cheaper solution with detached cycles, then aborts
    (a restricted MIP dying before column generation mends its solution); on one thread, the
    retry, it finds only the expensive path."""
    from spidermatch.solve.progress import report_detached

    x = np.zeros(lazy.n_vars)
    x[expensive] = 1.0
    cost = float(lazy.costs(expensive).sum())
    if options.threads != 1 or always_dies:
        report_known(incumbent=cost, bound=0.0, path=expensive)
        report_detached(float(lazy.costs(detached).sum()), detached)
        os.abort()
    return SolveResult("feasible", x, cost, 0.0, 1.0, 0.1, lazy.n_vars, 1, 1, "stopped")


def test_a_dead_process_s_detached_solution_is_mended_before_the_retry():
    from functools import partial

    from spidermatch.solve.connectivity import detached_components
    from spidermatch.solve.seeds import stay_seed
    from tests.test_colgen import creature_lazy

    lazy = creature_lazy(24, 3)
    path, detached = path_and_detached_copy(lazy)
    stay = np.sort(stay_seed(lazy))
    child = partial(dying_after_a_detached_solution, stay, detached)
    result = solve_isolated(child, lazy, lazy.graph, lazy.curve, SolverOptions(time_limit=60.0))
    assert result.status == "feasible" and "retried after the solver process died" in result.message
    assert detached_components(lazy.graph, result.x) == []
    assert result.objective == pytest.approx(lazy.costs(np.flatnonzero(result.x > 0.5)).sum())
    assert result.objective == pytest.approx(lazy.costs(path).sum(), rel=1e-3)  # not the stay path
    # the retry dies too: the mended path is the result, not an error
    child = partial(dying_after_a_detached_solution, stay, detached, always_dies=True)
    twice = solve_isolated(child, lazy, lazy.graph, lazy.curve, SolverOptions(time_limit=60.0))
    assert twice.status == "feasible" and "the retry died too" in twice.message and twice.bound == 0.0
    assert twice.objective == pytest.approx(lazy.costs(path).sum(), rel=1e-3)


@pytest.mark.parametrize(
    "message, remedy", [("Time limit reached", "raise solver.time_limit"), (OUT_OF_MEMORY, "more memory")]
)
def test_a_run_without_a_solution_names_the_remedy_for_its_stop(message, remedy):
    from spidermatch.pipeline import MatchResult, NoSolutionError

    solved = SolveResult("no_solution", None, math.inf, 1.0, math.nan, 3.0, 7, 3, 12, message)
    result = MatchResult(None, None, None, SimpleNamespace(n_layers=10, n_target=20), solved)
    with pytest.raises(NoSolutionError, match=remedy):
        result.raise_for_status()


def children_of_this_process() -> list[int]:
    """Pids of this process's children, alive or not yet reaped (Linux ``/proc``)."""
    tasks = Path(f"/proc/{os.getpid()}/task")
    return [int(pid) for task in tasks.iterdir() for pid in (task / "children").read_text().split()]


def test_a_cancelled_solve_forks_nothing_or_stops_its_process_and_keeps_the_path_reported():
    import threading

    options, cancel = SolverOptions(time_limit=60.0), threading.Event()
    before = set(children_of_this_process())  # another test's, if any
    cancel.set()
    solved = solve_isolated(hanging_after_a_path, MODEL, None, None, options, cancel=cancel)
    assert solved.status == "no_solution" and isolate.CANCELLED in solved.message
    assert set(children_of_this_process()) <= before  # nothing forked
    started = isolate.start_solver_process(hanging_after_a_path, MODEL, None, None, options)
    solved = solve_isolated(hanging_after_a_path, MODEL, None, None, options, cancel=cancel, started=started)
    assert isolate.CANCELLED in solved.message  # forked, then no longer wanted: killed and reaped
    assert started.child.exitcode is not None and set(children_of_this_process()) <= before
    cancel.clear()
    threading.Timer(1.0, cancel.set).start()  # while the child hangs after reporting a path
    solved = solve_isolated(hanging_after_a_path, MODEL, None, None, options, cancel=cancel)
    assert solved.status == "feasible" and solved.objective == 2.0 and solved.bound == 1.5
    assert np.flatnonzero(solved.x).tolist() == [1, 4] and isolate.CANCELLED in solved.message
    assert set(children_of_this_process()) <= before
