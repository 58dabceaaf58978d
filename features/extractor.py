"""One interface for per-vertex descriptors: ``extractor(mesh) -> (V, D)`` with L2-normalised rows."""

from __future__ import annotations

import logging
from typing import Protocol

import numpy as np

from spidermatch.geometry.descriptors import WKSExtractor
from spidermatch.geometry.mesh import Mesh

logger = logging.getLogger(__name__)

__all__ = ["FeatureExtractor", "WKSExtractor", "extractor_by_name"]


class FeatureExtractor(Protocol):
    """Anything that maps a mesh to per-vertex descriptors."""

    name: str

    def __call__(self, mesh: Mesh) -> np.ndarray:
        """Return descriptors of shape (V, D), rows L2-normalised."""
        ...


def extractor_by_name(kind: str, checkpoint: str | None = None, use_cache: bool = True) -> FeatureExtractor:
    """The extractor benchmarks and scripts ask for by name: ``"wks"`` or ``"learned"``.

    Parameters
    ----------
    kind : str
        "wks" (no checkpoint needed) or "learned" (needs ``checkpoint``).
    checkpoint : str, optional
        Path of a trained network (``spidermatch-train``'s ``best.pt``).
    use_cache : bool
        Whether WKS may reuse cached Laplacian eigenpairs.

    """
    if kind == "wks":
        return WKSExtractor(use_cache=use_cache)
    if kind != "learned":
        raise ValueError(f"unknown features {kind!r}; choose 'wks' or 'learned'")
    if checkpoint is None:
        raise ValueError("learned features need a checkpoint: give --checkpoint PATH (see spidermatch-train)")
    from features.learned import LearnedExtractor  # torch only when asked for

    return LearnedExtractor(checkpoint)
