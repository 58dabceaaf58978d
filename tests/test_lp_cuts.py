"""Connectivity cuts in colgen's LP relaxation: separation, pricing with their duals, the bound."""

from dataclasses import replace

import numpy as np
import pytest

from spidermatch.solve.connectivity import connectivity_cuts
from spidermatch.solve.fixing import sign_corrected_duals
from spidermatch.solve.lp_cuts import CutDuals, violated_cut_sets
from spidermatch.solve.pricing import price
from spidermatch.solve.types import SolverOptions
from tests.test_colgen import tiny_lazy
from tests.test_ilp import square_instance_with_detached_copy
from tests.test_layer_flow import walking_path

EXACT = SolverOptions(mip_rel_gap=0.0)


def test_a_fractional_detached_cycle_is_separated_and_a_mix_of_paths_is_not():
    graph, _, optimum, detached = square_instance_with_detached_copy()
    everything = np.arange(graph.n_edges)
    cycle = np.flatnonzero(detached != optimum)  # the two intra edges of a 2-cycle no path enters
    half_cycle = optimum.copy()
    half_cycle[cycle] = 0.5
    sets = violated_cut_sets(graph, everything, half_cycle)
    layer, a, _, b, _ = graph.edge_tuples(cycle)[0]
    assert [sorted(s.tolist()) for s in sets] == [sorted([layer * 4 + a, layer * 4 + b])]
    rows, lower, _ = connectivity_cuts(graph, sets)
    assert (rows @ half_cycle < lower - 0.4).any()  # violated by the cycle's value, 0.5
    # every cut holds for every closed path, so for every mix of them: nothing to separate
    assert violated_cut_sets(graph, everything, optimum) == []
    assert violated_cut_sets(graph, everything, 0.5 * optimum + 0.5 * walking_path(graph)) == []


def test_a_cycle_that_the_path_runs_through_is_not_cut():
    """Half a unit round a 2-cycle at a vertex the path leaves the layer from satisfies every cut."""
    graph, _, optimum, _ = square_instance_with_detached_copy()
    tuples = graph.edge_tuples(np.flatnonzero(optimum > 0.5))
    leaving = tuples[tuples[:, 4] != 0][0]  # an edge to the next layer: its layer and tail
    layer, tail = int(leaving[0]), int(leaving[1])
    neighbour = next(int(b) for a, b in graph.target_edges.tolist() if a == tail)
    from tests.test_ilp import edge_id

    x = optimum.copy()
    x[edge_id(graph, layer, tail, neighbour, 0)] = x[edge_id(graph, layer, neighbour, tail, 0)] = 0.5
    assert violated_cut_sets(graph, np.arange(graph.n_edges), x) == []


@pytest.mark.parametrize("seed", [0, 1])
def test_pricing_with_cut_duals_subtracts_the_cut_rows(seed):
    """Reduced costs of every column with cut duals are c - A^T y - G^T mu (the full model, explicitly)."""
    lazy = tiny_lazy([0, 1, 0, 2], seed)
    model = lazy.full_model()
    rng = np.random.default_rng(seed)
    y = sign_corrected_duals(model, rng.normal(size=model.n_rows))
    n = lazy.graph.n_target
    sets = [np.array([0 * n + 0, 0 * n + 1]), np.array([2 * n + 1, 2 * n + 2])]  # in layers 0 and 2
    rows, _, _ = connectivity_cuts(lazy.graph, sets)
    mu = rng.uniform(0.1, 1.0, rows.shape[0])
    priced = price(lazy, y, np.inf, CutDuals.of(rows, mu))
    expected = model.costs - model.matrix.T @ y - rows.T @ mu
    assert np.array_equal(priced.columns, np.arange(lazy.n_vars))
    np.testing.assert_allclose(priced.reduced, expected, atol=1e-12)
    plain = price(lazy, y, np.inf)
    assert priced.bound <= plain.bound + 1e-12  # the cuts' right-hand sides are 0: only sum min(0, r) moves


def synthetic_colgen_instance():
    """Two synthetic creatures at 100 faces with WKS features, prepared for colgen: its plain LP
    relaxation sends flow round cycles inside self-intersection layers (found by a search over seeds)."""
    from spidermatch.api import pair_features
    from spidermatch.data.synthetic import make_creature
    from spidermatch.pipeline import MatchSettings, prepare

    source, target = make_creature(1500, seed=2).mesh, make_creature(1500, seed=12).mesh
    features = pair_features("wks", source, target)[:2]
    settings = MatchSettings(resolution=100, strategy="colgen", dense=None)
    _, _, curve, graph, lazy = prepare(source, target, *features, settings, {})
    return lazy, curve


def test_cuts_raise_the_lp_bound_and_colgen_stays_exact(caplog):
    from spidermatch.solve.colgen import generate_columns
    from spidermatch.solve.seeds import path_band_seed, stay_seed
    from spidermatch.solve.strategies import solve_with_strategy

    lazy, curve = synthetic_colgen_instance()
    seed = np.union1d(path_band_seed(lazy), stay_seed(lazy))
    plain_lp = generate_columns(lazy, seed, replace(EXACT, lp_cuts=False))
    with caplog.at_level("INFO", logger="spidermatch.solve.colgen"):
        cut_lp = generate_columns(lazy, seed, EXACT)
    assert "connectivity cuts" in caplog.text
    assert plain_lp.cuts.shape[0] == 0 and cut_lp.cuts.shape[0] > 0
    assert cut_lp.bound > plain_lp.bound + 1e-6
    # the LP solution satisfies the cuts it was given
    x = np.zeros(lazy.n_vars)
    x[cut_lp.columns] = cut_lp.x
    assert (cut_lp.cuts @ x >= -1e-7).all()
    with_cuts = solve_with_strategy("colgen", lazy, lazy.graph, curve, EXACT)
    without = solve_with_strategy("colgen", lazy, lazy.graph, curve, replace(EXACT, lp_cuts=False))
    assert with_cuts.status == without.status == "optimal"
    assert with_cuts.objective == pytest.approx(without.objective, rel=1e-9)
    assert cut_lp.bound <= with_cuts.objective + 1e-9


def test_an_lp_stopped_after_cuts_keeps_the_last_complete_round(monkeypatch, caplog):
    """A time limit in the re-solve after a cut round ends column generation with the LP before it
    (its bound and duals hold), not without any LP (which left runs with no solution at all)."""
    import spidermatch.solve.colgen as colgen
    from spidermatch.solve.highs import HighsSession
    from spidermatch.solve.seeds import path_band_seed, stay_seed

    lazy, _ = synthetic_colgen_instance()
    seed = np.union1d(path_band_seed(lazy), stay_seed(lazy))
    plain_lp = colgen.generate_columns(lazy, seed, replace(EXACT, lp_cuts=False))
    cuts_added, real_add, real_run = [], colgen._cuts_added, HighsSession.run

    def add_and_note(*args):
        added = real_add(*args)
        cuts_added.append(added)
        return added

    def run_stopped_after_cuts(session):
        result = real_run(session)
        return replace(result, status="feasible", message="Time limit reached") if any(cuts_added) else result

    monkeypatch.setattr(colgen, "_cuts_added", add_and_note)
    monkeypatch.setattr(HighsSession, "run", run_stopped_after_cuts)
    with caplog.at_level("INFO", logger="spidermatch.solve.colgen"):
        lp = colgen.generate_columns(lazy, seed, EXACT)
    assert any(cuts_added) and "the last complete round stands" in caplog.text
    assert lp.cuts.shape[0] == 0  # the round before the cuts
    assert lp.bound == pytest.approx(plain_lp.bound, rel=1e-9)


def test_rows_on_columns_equals_scipy_column_slicing():
    from scipy import sparse

    from spidermatch.solve.cuts import rows_on_columns

    rng = np.random.default_rng(0)
    rows = sparse.random(6, 500, density=0.05, random_state=1, format="csr")
    for columns in (np.sort(rng.choice(500, 40, replace=False)), rng.choice(500, 40, replace=False)):
        np.testing.assert_array_equal(rows_on_columns(rows, columns).toarray(), rows[:, columns].toarray())
    assert rows_on_columns(rows, np.zeros(0, dtype=np.int64)).shape == (6, 0)
