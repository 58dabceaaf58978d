"""Differential tests too slow for the default run: ``pytest -m slow``.

Larger instances than the brute-force tests of ``test_ilp.py``: the strategy ``auto`` picks
for WKS (rcfix) and plain HiGHS must agree on the optimum, each bound must stay below the other's
objective, and the solution must pass the independent checker, with real WKS costs.
"""

import numpy as np
import pytest

from features.extractor import WKSExtractor
from spidermatch.data.synthetic import make_creature
from spidermatch.pipeline import MatchSettings, match
from spidermatch.solve.types import SolverOptions

pytestmark = pytest.mark.slow


def _match(source, target, features, strategy):
    settings = MatchSettings(resolution=120, strategy=strategy, solver=SolverOptions(mip_rel_gap=0.0))
    return match(source.mesh, target.mesh, features[0], features[1], settings)


@pytest.mark.parametrize("seed", [21, 22, 23, 24])
def test_rcfix_and_plain_agree_on_wks_costs(seed):
    source, target = make_creature(1500, seed=seed), make_creature(1500, seed=seed + 100)
    extractor = WKSExtractor(use_cache=False)
    features = extractor(source.mesh.centred()), extractor(target.mesh.centred())
    plain = _match(source, target, features, "plain")
    fixed = _match(source, target, features, "rcfix")
    for result in (plain, fixed):
        result.raise_for_status()
        assert result.solve.status == "optimal"
        assert result.check.ok  # the pipeline's independent checker ran on this solution
        assert np.isfinite(result.solve.bound)
    assert fixed.solve.objective == pytest.approx(plain.solve.objective, rel=1e-6)
    assert fixed.solve.bound <= plain.solve.objective * (1 + 1e-9)
    assert plain.solve.bound <= fixed.solve.objective * (1 + 1e-9)
