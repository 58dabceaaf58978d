"""Reading a solution vector x of the SpiderMatch ILP: which columns it uses.

Solvers return values within their feasibility tolerance of their bounds, so a test against
exactly 0 or 1 would misread them. Three thresholds, for three different questions:
"""

from __future__ import annotations

import numpy as np

USED = 0.5
"""A column is used by a 0/1 solution where its value exceeds this (an integral value is within
the solver's tolerance, ~1e-6, of 0 or 1, so halfway is the safe cut)."""

LP_SUPPORT = 1e-9
"""An LP value above this puts its column in the LP solution's support (every column the LP
uses at all, however little, is kept in a restricted MIP)."""

FRACTIONAL = 1e-6
"""An LP value farther than this from 0 and from 1 counts as fractional (the simplex's own
feasibility tolerance: closer values are integral up to rounding)."""


def used_columns(x: np.ndarray) -> np.ndarray:
    """Indices of the columns a 0/1 solution x (n,) uses, ascending, int64."""
    return np.flatnonzero(np.asarray(x) > USED)
