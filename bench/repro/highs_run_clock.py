"""How HiGHS times re-solves of one ``Highs`` object (issue 28, part 3).

Run: ``python bench/repro/highs_run_clock.py``. Each model is solved four times in one
``Highs`` object with ``time_limit=1`` (changed a little between runs, so that every run has
work to do). With highspy 1.16.0 the LP's first run stops after 1 s and every later one at
once (``getRunTime()``, which the LP's time limit is compared with, keeps counting over all
runs), while each MIP run gets its full second (the MIP solver has a clock of its own).
"""

import time

import highspy
import numpy as np
import scipy.sparse as sp


def lp(rng):
    """A random LP that dual simplex does not finish in 1 s (60 000 columns, 20 000 rows)."""
    n, m = 60_000, 20_000
    matrix = sp.random(m, n, density=6 / m, random_state=1, format="csc")
    matrix.data[:] = rng.uniform(0.5, 1.5, matrix.nnz)
    h = highspy.Highs()
    for name, value in (("output_flag", False), ("presolve", "off"), ("solver", "simplex")):
        h.setOptionValue(name, value)
    h.passModel(
        n, m, matrix.nnz, int(highspy.MatrixFormat.kColwise), int(highspy.ObjSense.kMinimize), 0.0,
        rng.uniform(-1, 1, n), np.zeros(n), np.ones(n), np.full(m, -np.inf), np.ones(m),
        matrix.indptr.astype(np.int32), matrix.indices.astype(np.int32), matrix.data,
        np.zeros(n, dtype=np.int32),
    )  # fmt: skip
    return h, lambda: h.changeColsCost(n, np.arange(n, dtype=np.int32), rng.uniform(-1, 1, n))


def mip(rng):
    """A random multi-dimensional knapsack that HiGHS does not solve in 1 s."""
    n, m = 300, 40
    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    index = np.arange(n, dtype=np.int32)
    for _ in range(n):
        h.addVar(0, 1)
    h.changeColsIntegrality(n, index, np.ones(n, dtype=np.uint8))
    h.changeColsCost(n, index, -rng.integers(1, 100, size=n).astype(float))
    for weights in rng.integers(1, 100, size=(m, n)).astype(float):
        h.addRow(-np.inf, weights.sum() / 3, n, index, weights)

    def change():
        row = rng.integers(0, 2, size=n).astype(float)
        h.addRow(-np.inf, row.sum() / 2 + 3, n, index, row)

    return h, change


if __name__ == "__main__":
    print("highspy", highspy.__version__ if hasattr(highspy, "__version__") else "")
    for name, make in (("LP", lp), ("MIP", mip)):
        h, change = make(np.random.default_rng(0))
        for run in range(4):
            h.setOptionValue("time_limit", 1.0)
            start = time.perf_counter()
            h.run()
            print(
                f"{name} run {run}: time_limit 1, wall {time.perf_counter() - start:.2f} s, "
                f"getRunTime {h.getRunTime():.2f} s, {h.modelStatusToString(h.getModelStatus())}"
            )
            change()
