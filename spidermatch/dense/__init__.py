"""Densification: a map for every full-resolution source vertex from the certified sparse map.

:func:`spidermatch.dense.densify.densify` with :class:`DenseSettings` gives a :class:`DenseMap`
(the function is not re-exported: here its name is its module's). The deformation's fit is in
:mod:`~spidermatch.dense.registration`, the fold-free rounding in :mod:`~spidermatch.dense.unfold`,
ZoomOut in :mod:`~spidermatch.dense.zoomout`.
"""

from spidermatch.dense.maps import DenseMap
from spidermatch.dense.settings import METHODS, DenseSettings

__all__ = ["METHODS", "DenseMap", "DenseSettings"]
