"""Standalone reproduction of HiGHS's abort in a sub-MIP's presolve (issue 28).

Usage::

    python bench/repro/highs_submip_presolve_abort.py bench/repro/centaur_mip3.mps.xz \
        bench/repro/centaur_mip3_start.txt [option=value ...]

Reads the restricted MIP (``.mps``, or ``.mps.xz`` unpacked to a temporary file), offers
the start solution (a text file of the columns at 1) if given, sets ``mip_rel_gap=1e-4``,
``mip_abs_gap=0`` and any further options, and runs HiGHS with its log.

With highspy 1.16.0, ``centaur_mip3.mps.xz`` (the third restricted MIP of ``colgen`` on
TOSCA centaur0 -> centaur1 at 1000 faces, 106 043 binary columns, 31 134 rows) and its start
solution, the process dies after about 65 s with ``free(): invalid pointer`` (SIGABRT, exit
134) in ``HPresolve::~HPresolve`` under ``HighsPrimalHeuristics::rootReducedCost`` ->
``solveSubMip``; with ``mip_heuristic_run_root_reduced_cost=false`` it does not. The same
abort came later from ``HighsPrimalHeuristics::RENS`` on another model (a TOSCA part, 1000
faces), so spidermatch turns RENS and RINS off too. See docs/solver_failures.md.
"""

import lzma
import shutil
import sys
import tempfile

import highspy
import numpy as np


def parse(value: str):
    """An option value from the command line: bool, int, float or str."""
    lowered = value.lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    for kind in (int, float):
        try:
            return kind(value)
        except ValueError:
            pass
    return value


def main(argv: list[str]) -> None:
    model = argv[0]
    start = next((arg for arg in argv[1:] if arg.endswith(".txt")), None)
    options = dict(arg.split("=", 1) for arg in argv[1:] if "=" in arg)
    h = highspy.Highs()
    h.setOptionValue("mip_rel_gap", 1e-4)
    h.setOptionValue("mip_abs_gap", 0.0)
    for name, value in options.items():
        if h.setOptionValue(name, parse(value)) == highspy.HighsStatus.kError:
            raise SystemExit(f"HiGHS rejected {name}={value}")
    with tempfile.TemporaryDirectory() as folder:
        path = model
        if model.endswith(".xz"):
            path = f"{folder}/model.mps"
            with lzma.open(model) as packed, open(path, "wb") as unpacked:
                shutil.copyfileobj(packed, unpacked)
        if h.readModel(path) == highspy.HighsStatus.kError:
            raise SystemExit(f"cannot read {model}")
    if start is not None:
        n = h.getNumCol()
        x = np.zeros(n)
        x[np.loadtxt(start, dtype=np.int64)] = 1.0
        h.setSolution(n, np.arange(n, dtype=np.int32), x)
    h.run()
    info = h.getInfo()
    print(
        f"status {h.modelStatusToString(h.getModelStatus())}, objective {info.objective_function_value:.8g}, "
        f"bound {info.mip_dual_bound:.8g}, {h.getRunTime():.1f} s"
    )


if __name__ == "__main__":
    main(sys.argv[1:])
