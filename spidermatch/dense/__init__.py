"""Densification: a map for every full-resolution source vertex from the certified sparse map.

:func:`densify` with :class:`DenseSettings` gives a :class:`DenseMap` (:mod:`spidermatch.dense.densify`);
the deformation's fit is in :mod:`~spidermatch.dense.registration`, the fold-free rounding in
:mod:`~spidermatch.dense.unfold`, ZoomOut in :mod:`~spidermatch.dense.zoomout`.
"""

from spidermatch.dense.densify import METHODS, DenseMap, DenseSettings, densify

__all__ = ["METHODS", "DenseMap", "DenseSettings", "densify"]
