"""ZoomOut spectral upsampling of a point map (after Melzi et al., SIGGRAPH Asia 2019).

Given a point map T: X -> Y (source vertex -> target vertex) and M-orthonormal
Laplacian eigenfunctions Phi_X (V_X, K), Phi_Y (V_Y, K), one step with k functions is

    C = Phi_X[:, :k]^T diag(mass_X) Phi_Y[T, :k]        (k, k)   least-squares fit of Phi_Y[T] ~ Phi_X C
    T(x) = argmin_y | (Phi_X[:, :k] C)[x] - Phi_Y[y, :k] |          nearest neighbour in the embedding

with k growing from a few to many functions. Optionally each x may only choose among
given candidate vertices, and unit descriptors (scaled by a weight) are appended to
both embeddings (the feature term of Ren et al. 2021, "Discrete optimization for shape
matching").
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import cKDTree

from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.operators import cache_dir, cached_operators, operator_cache_key

logger = logging.getLogger(__name__)

# Rows per block of the brute-force nearest-neighbour search (memory: block x V_Y floats).
BLOCK = 1024


def spectral_basis(mesh: Mesh, k: int) -> tuple[np.ndarray, np.ndarray]:
    """First ``k`` eigenfunctions (V, k) and the lumped mass (V,), from the operator cache.

    Reuses the entry DiffusionNet features leave behind (k=128 with gradients) when it is
    there, so that matching with learned features does not solve the eigenproblem twice.
    """
    for n_eig, gradients in ((128, True), (max(k, 128), False)):
        if n_eig < k:
            continue
        if gradients and not (cache_dir() / f"{operator_cache_key(mesh, n_eig, True)}.npz").is_file():
            continue
        ops = cached_operators(mesh, k=n_eig, gradients=gradients)
        return ops.evecs[:, :k], ops.mass
    raise AssertionError("unreachable")  # pragma: no cover


def zoomout(
    evecs_x: np.ndarray,
    mass_x: np.ndarray,
    evecs_y: np.ndarray,
    initial: np.ndarray,
    schedule: range,
    candidates: np.ndarray | None = None,
    extra: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Refine the point map ``initial`` (V_X,) by ZoomOut over the eigenfunction counts ``schedule``.

    Parameters
    ----------
    evecs_x : np.ndarray, shape (V_X, K)
    mass_x : np.ndarray, shape (V_X,)
    evecs_y : np.ndarray, shape (V_Y, K)
    initial : np.ndarray, shape (V_X,)
        Target vertex of each source vertex.
    schedule : range
        Numbers of eigenfunctions, increasing, each at most K.
    candidates : np.ndarray, shape (V_X, C), optional
        Allowed target vertices of each source vertex (default: all).
    extra : (np.ndarray (V_X, D), np.ndarray (V_Y, D)), optional
        Columns appended to the source and target embeddings (e.g. weighted descriptors).

    Returns
    -------
    np.ndarray, shape (V_X,), int64

    """
    mapping = np.asarray(initial, dtype=np.int64)
    for k in schedule:
        fitted = evecs_x[:, :k].T @ (mass_x[:, None] * evecs_y[mapping, :k])
        embed_x, embed_y = evecs_x[:, :k] @ fitted, evecs_y[:, :k]
        if extra is not None:
            embed_x, embed_y = np.hstack([embed_x, extra[0]]), np.hstack([embed_y, extra[1]])
        if candidates is None:
            mapping = nearest_rows(embed_x, embed_y)
        else:
            mapping = nearest_candidates(embed_x, embed_y, candidates)
    return mapping


def nearest_rows(queries: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Index of the nearest row of ``points`` (M, D) for each row of ``queries`` (N, D), (N,)."""
    if points.shape[1] <= 8:
        return np.asarray(cKDTree(points).query(queries)[1], dtype=np.int64)
    # Single precision halves the time of the products; ties at that precision do not matter.
    points32 = np.ascontiguousarray(points, dtype=np.float32)
    squared = np.einsum("md,md->m", points32, points32)
    out = np.empty(len(queries), dtype=np.int64)
    for start in range(0, len(queries), BLOCK):
        block = np.asarray(queries[start : start + BLOCK], dtype=np.float32)
        out[start : start + BLOCK] = np.argmin(squared[None, :] - 2.0 * block @ points32.T, axis=1)
    return out


def nearest_candidates(queries: np.ndarray, points: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """For each query row, the candidate (row of ``candidates`` (N, C)) nearest in ``points``, (N,)."""
    out = np.empty(len(queries), dtype=np.int64)
    for start in range(0, len(queries), BLOCK):
        rows = candidates[start : start + BLOCK]
        difference = points[rows] - queries[start : start + BLOCK, None, :]
        best = np.argmin(np.einsum("ncd,ncd->nc", difference, difference), axis=1)
        out[start : start + BLOCK] = rows[np.arange(len(rows)), best]
    return out
