"""One interface for per-vertex descriptors: ``extractor(mesh) -> (V, D)`` with L2-normalised rows."""

from __future__ import annotations

import logging
from typing import Protocol

import numpy as np

from features.wks import wave_kernel_signature
from spidermatch.mesh import Mesh
from spidermatch.operators import cached_operators

logger = logging.getLogger(__name__)


class FeatureExtractor(Protocol):
    """Anything that maps a mesh to per-vertex descriptors."""

    name: str

    def __call__(self, mesh: Mesh) -> np.ndarray:
        """Return descriptors of shape (V, D), rows L2-normalised."""
        ...


class WKSExtractor:
    """Wave Kernel Signature descriptors on the mesh's own Laplacian eigenpairs.

    Parameters
    ----------
    n_descr : int
        Descriptor dimension D.
    n_eig : int
        Number of Laplacian eigenpairs K used.

    """

    name = "wks"

    def __init__(self, n_descr: int = 128, n_eig: int = 128, use_cache: bool = True) -> None:
        self.n_descr = n_descr
        self.n_eig = n_eig
        self.use_cache = use_cache

    def __call__(self, mesh: Mesh) -> np.ndarray:
        """Return WKS descriptors of shape (V, n_descr)."""
        ops = cached_operators(mesh, k=self.n_eig, use_cache=self.use_cache)
        return wave_kernel_signature(ops.evals, ops.evecs, self.n_descr)


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
