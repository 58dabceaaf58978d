"""Type tests for option values, shared by every check (a leaf module: it imports nothing of spidermatch)."""

from __future__ import annotations

import math
from numbers import Integral, Real


def is_whole(value) -> bool:
    """An integer that is not a bool (``True`` is an ``Integral`` in Python)."""
    return isinstance(value, Integral) and not isinstance(value, bool)


def is_number(value) -> bool:
    """A real number that is not a bool and not NaN (infinity passes)."""
    return isinstance(value, Real) and not isinstance(value, bool) and not math.isnan(value)


def is_finite(value) -> bool:
    """A real number that is not a bool, NaN or infinite."""
    return is_number(value) and math.isfinite(value)


def show(value) -> str:
    """``value`` as an option message shows it: strings quoted, everything else as printed."""
    return repr(value) if isinstance(value, str) else str(value)
