"""The solver process (issue 28): results, exceptions and deaths of the child reach the parent."""

import math
import os
import signal
from types import SimpleNamespace

import numpy as np
import pytest

from spidermatch.solve.highs import SolveResult, SolverOptions
from spidermatch.solve.isolate import KnownFigures, describe_exit, solve_isolated
from spidermatch.solve.progress import report_known

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
    assert "SIGSEGV (exit 139)" in result.message
    assert (result.n_vars, result.n_rows) == (7, 3)


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
    import spidermatch
    from spidermatch.synthetic import make_creature

    source, target = make_creature(600, seed=seed).mesh, make_creature(600, seed=seed + 1).mesh
    return spidermatch.match(source, target, resolution=40).status


def test_a_match_inside_a_multiprocessing_pool_worker_solves_in_the_worker():
    import multiprocessing

    with multiprocessing.get_context("fork").Pool(1) as pool:  # daemonic workers: no children allowed
        assert pool.apply(_match_in_pool_worker, (3,)) == "optimal"
