"""Intrinsic descriptors in pure numpy: the Wave Kernel Signature (Aubry, Schlickewei and Cremers, 2011).

Part of the core package so that matching with WKS needs no PyTorch; ``features.wks`` and
``features.extractor`` re-export what is defined here.
"""

from __future__ import annotations

import numpy as np

from spidermatch.geometry.mesh import Mesh, MeshError
from spidermatch.geometry.operators import cached_operators


def wave_kernel_signature(
    evals: np.ndarray, evecs: np.ndarray, n_descr: int = 128, variance: float = 6.0
) -> np.ndarray:
    """Wave Kernel Signature from Laplace-Beltrami eigenpairs, rows L2-normalised.

    Energies are spread evenly in log-eigenvalue between the first non-zero
    eigenvalue and the largest one; each descriptor is a band-pass filter of
    the squared eigenfunctions, normalised by its filter's total weight.

    Parameters
    ----------
    evals : np.ndarray, shape (K,)
        Eigenvalues in ascending order; zero (constant) modes are ignored.
    evecs : np.ndarray, shape (V, K)
        Mass-orthonormal eigenvectors.
    n_descr : int
        Number of energies D.
    variance : float
        Filter width in units of the energy spacing.

    Returns
    -------
    np.ndarray, shape (V, D)

    """
    if evals.ndim != 1 or evecs.ndim != 2 or evecs.shape[1] != evals.shape[0]:
        raise ValueError(f"evals (K,) and evecs (V, K) expected, got {evals.shape} and {evecs.shape}")
    positive = evals > 1e-9 * max(float(evals.max()), 1e-300)
    if positive.sum() < 2:
        raise ValueError("WKS needs at least two non-zero eigenvalues")
    log_evals = np.log(evals[positive])
    squared = evecs[:, positive] ** 2
    energies = np.linspace(log_evals[0], log_evals[-1] / 1.02, n_descr)
    sigma = variance * (energies[1] - energies[0]) if n_descr > 1 else 1.0
    filters = np.exp(-((energies[:, None] - log_evals[None, :]) ** 2) / (2 * sigma**2))  # (D, K)
    descriptors = squared @ filters.T / filters.sum(axis=1)[None, :]
    return normalise_rows(descriptors)


def normalise_rows(features: np.ndarray) -> np.ndarray:
    """L2-normalise each row of a (V, D) array (zero rows stay zero)."""
    norms = np.linalg.norm(features, axis=1, keepdims=True)
    return features / np.maximum(norms, 1e-12)


class WKSExtractor:
    """Wave Kernel Signature descriptors on the mesh's own Laplacian eigenpairs.

    Calling it on a :class:`~spidermatch.geometry.mesh.Mesh` with V vertices returns an array of
    shape (V, n_descr) with L2-normalised rows.

    Parameters
    ----------
    n_descr : int
        Descriptor dimension D.
    n_eig : int
        Number of Laplacian eigenpairs K used.
    use_cache : bool
        Whether cached eigenpairs (``~/.cache/spidermatch``) may be reused and stored.

    """

    name = "wks"

    def __init__(self, n_descr: int = 128, n_eig: int = 128, use_cache: bool = True) -> None:
        self.n_descr = n_descr
        self.n_eig = n_eig
        self.use_cache = use_cache

    def __call__(self, mesh: Mesh) -> np.ndarray:
        """Return WKS descriptors of shape (V, n_descr), the same for the mesh in any unit.

        The eigenpairs are those of the mesh scaled to unit area: WKS's energy scale is
        fixed in the eigenvalues' logarithms, so without this a mesh in millimetres would get
        other descriptors than the same mesh in metres.
        """
        unit = Mesh(mesh.verts / np.sqrt(mesh.area), mesh.faces, mesh.name)
        ops = cached_operators(unit, k=self.n_eig, use_cache=self.use_cache)
        try:
            return wave_kernel_signature(ops.evals, ops.evecs, self.n_descr)
        except ValueError as error:
            raise MeshError(f"{mesh.name}: no WKS descriptors ({error})") from error
