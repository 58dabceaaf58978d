"""Spectral operators of a triangle mesh: cotangent Laplacian, lumped mass, eigenpairs, gradients.

All operators are computed in float64 by pure functions and bundled in the frozen
:class:`Operators`. :func:`cached_operators` adds an on-disk cache keyed by a content
hash of the mesh and the parameters.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from spidermatch.geometry.mesh import Mesh, triangle_areas, vertex_normals

logger = logging.getLogger(__name__)

CACHE_VERSION = 2
# Eigenpairs computed beyond the requested number, then dropped (see laplacian_eigenpairs).
EXTRA_MODES = 8
CACHE_ENV = "SPIDERMATCH_CACHE_DIR"


@dataclass(frozen=True, eq=False)
class Operators:
    """Spectral operators of one mesh (V vertices, K eigenpairs).

    Attributes
    ----------
    laplacian : scipy.sparse.csr_matrix, shape (V, V)
        Positive semi-definite cotangent Laplacian (stiffness), symmetric, zero row sums.
    mass : np.ndarray, shape (V,)
        Lumped (barycentric) vertex areas; they sum to the surface area.
    evals : np.ndarray, shape (K,)
        Eigenvalues of ``L phi = lambda M phi`` in ascending order (the first is 0).
    evecs : np.ndarray, shape (V, K)
        M-orthonormal eigenvectors: ``evecs.T @ diag(mass) @ evecs = I``.
    grad_x, grad_y : scipy.sparse.csr_matrix, shape (V, V), or None
        Per-vertex gradient in the tangent basis (``frames``), if requested.
    frames : np.ndarray, shape (V, 3, 3), or None
        Per-vertex tangent basis rows (e1, e2, normal), if gradients were requested.

    """

    laplacian: sp.csr_matrix
    mass: np.ndarray
    evals: np.ndarray
    evecs: np.ndarray
    grad_x: sp.csr_matrix | None = None
    grad_y: sp.csr_matrix | None = None
    frames: np.ndarray | None = None

    @property
    def k(self) -> int:
        """Number of eigenpairs K."""
        return int(self.evals.shape[0])


def cotangent_weights(verts: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """Edge weights ``W_ij = (cot a_ij + cot b_ij) / 2`` (a, b the angles opposite edge ij).

    Parameters
    ----------
    verts : np.ndarray, shape (V, 3)
    faces : np.ndarray, shape (F, 3)

    Returns
    -------
    scipy.sparse.csr_matrix, shape (V, V)
        Symmetric, zero diagonal; negative at edges opposite obtuse angles.

    """
    n = verts.shape[0]
    rows, cols, weights = [], [], []
    for k in range(3):
        i, j, o = faces[:, (k + 1) % 3], faces[:, (k + 2) % 3], faces[:, k]
        u, v = verts[i] - verts[o], verts[j] - verts[o]
        cross = np.linalg.norm(np.cross(u, v), axis=1)
        cot = np.einsum("ij,ij->i", u, v) / np.maximum(cross, 1e-12)
        rows += [i, j]
        cols += [j, i]
        weights += [0.5 * cot, 0.5 * cot]
    return sp.coo_matrix(
        (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
    ).tocsr()


def cotangent_laplacian(verts: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """Cotangent Laplacian ``L = D - W`` with ``W`` the :func:`cotangent_weights`.

    Parameters
    ----------
    verts : np.ndarray, shape (V, 3)
    faces : np.ndarray, shape (F, 3)

    Returns
    -------
    scipy.sparse.csr_matrix, shape (V, V)
        Symmetric, zero row sums, positive semi-definite for Delaunay meshes.

    """
    off_diag = cotangent_weights(verts, faces)
    degree = np.asarray(off_diag.sum(axis=1)).ravel()
    return (sp.diags(degree) - off_diag).tocsr()


def lumped_mass(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Barycentric lumped mass: a third of each incident face's area, shape (V,)."""
    areas = triangle_areas(verts, faces)
    mass = np.zeros(verts.shape[0])
    np.add.at(mass, faces.reshape(-1), np.repeat(areas / 3.0, 3))
    return mass


def laplacian_eigenpairs(laplacian: sp.csr_matrix, mass: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """First ``k`` eigenpairs of ``L phi = lambda M phi`` (M = diag(mass)).

    Returns
    -------
    evals : np.ndarray, shape (K,)
    evecs : np.ndarray, shape (V, K), M-orthonormal.
    K = min(k, V).

    """
    n = laplacian.shape[0]
    k = min(k, n)
    mass_matrix = sp.diags(mass)
    if n <= max(2 * k, 200):
        from scipy.linalg import eigh

        evals, evecs = eigh(laplacian.toarray(), np.diag(mass), subset_by_index=[0, k - 1])
    else:
        # A fixed start vector makes the result reproducible; a few modes beyond k keep a
        # (near-)degenerate eigenvalue cluster at the cut from being returned incomplete.
        n_modes = min(k + EXTRA_MODES, n - 2)
        start = np.random.default_rng(0).standard_normal(n)
        evals, evecs = spla.eigsh(laplacian, k=n_modes, M=mass_matrix, sigma=-1e-8, which="LM", v0=start)
    order = np.argsort(evals)[:k]
    evals, evecs = np.clip(evals[order], 0.0, None), evecs[:, order]
    norms = np.sqrt(np.einsum("vk,v,vk->k", evecs, mass, evecs))
    return evals, evecs / norms


def tangent_frames(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Orthonormal per-vertex frames (e1, e2, normal), shape (V, 3, 3)."""
    normals = vertex_normals(verts, faces)
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = helper - np.einsum("ij,ij->i", helper, normals)[:, None] * normals
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(normals, e1)
    return np.stack([e1, e2, normals], axis=1)


def gradient_operators(
    verts: np.ndarray, faces: np.ndarray, edges: np.ndarray, regulariser: float = 1e-5
) -> tuple[sp.csr_matrix, sp.csr_matrix, np.ndarray]:
    """Per-vertex least-squares gradient in the tangent plane.

    For vertex i with neighbours j, the gradient g_i in R^2 minimises
    ``sum_j (g_i . d_ij - (f_j - f_i))^2 + eps |g_i|^2`` where d_ij is the edge
    vector projected on i's tangent frame.

    Parameters
    ----------
    verts : np.ndarray, shape (V, 3)
    faces : np.ndarray, shape (F, 3)
    edges : np.ndarray, shape (E, 2)

    Returns
    -------
    grad_x, grad_y : scipy.sparse.csr_matrix, shape (V, V)
        ``grad_x @ f`` is the e1 component of the gradient of f (V,).
    frames : np.ndarray, shape (V, 3, 3)

    """
    n = verts.shape[0]
    frames = tangent_frames(verts, faces)
    src = np.concatenate([edges[:, 0], edges[:, 1]])
    dst = np.concatenate([edges[:, 1], edges[:, 0]])
    offsets = verts[dst] - verts[src]
    d = np.stack(
        [np.einsum("ij,ij->i", offsets, frames[src, 0]), np.einsum("ij,ij->i", offsets, frames[src, 1])], 1
    )
    scale = np.mean(np.linalg.norm(d, axis=1)) ** 2
    normal_eq = np.zeros((n, 2, 2))
    np.add.at(normal_eq, src, np.einsum("ei,ej->eij", d, d))
    normal_eq += regulariser * scale * np.eye(2)
    weights = np.einsum("eij,ej->ei", np.linalg.inv(normal_eq)[src], d)  # (2E, 2)
    matrices = []
    for c in range(2):
        neighbour = sp.coo_matrix((weights[:, c], (src, dst)), shape=(n, n)).tocsr()
        centre = sp.diags(-np.asarray(neighbour.sum(axis=1)).ravel())
        matrices.append((neighbour + centre).tocsr())
    return matrices[0], matrices[1], frames


def compute_operators(mesh: Mesh, k: int = 128, gradients: bool = False) -> Operators:
    """Compute the spectral operators of ``mesh`` (pure function, float64).

    Parameters
    ----------
    mesh : Mesh
    k : int
        Number of eigenpairs (capped at V).
    gradients : bool
        Also compute tangent-plane gradient operators (used by DiffusionNet).

    """
    laplacian = cotangent_laplacian(mesh.verts, mesh.faces)
    mass = lumped_mass(mesh.verts, mesh.faces)
    evals, evecs = laplacian_eigenpairs(laplacian, mass, k)
    grad_x = grad_y = frames = None
    if gradients:
        grad_x, grad_y, frames = gradient_operators(mesh.verts, mesh.faces, mesh.edges)
    return Operators(laplacian, mass, evals, evecs, grad_x, grad_y, frames)


def cache_dir() -> Path:
    """The operator cache folder: ``$SPIDERMATCH_CACHE_DIR`` or ``~/.cache/spidermatch``."""
    root = os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "spidermatch"
    return Path(root) / "operators"


def operator_cache_key(mesh: Mesh, k: int, gradients: bool) -> str:
    """Content hash of the mesh arrays and the parameters."""
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(mesh.verts, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    digest.update(json.dumps({"k": k, "gradients": gradients, "version": CACHE_VERSION}).encode())
    return digest.hexdigest()[:32]


def cached_operators(mesh: Mesh, k: int = 128, gradients: bool = False, use_cache: bool = True) -> Operators:
    """:func:`compute_operators` with an on-disk cache keyed by :func:`operator_cache_key`."""
    if not use_cache:
        return compute_operators(mesh, k, gradients)
    path = cache_dir() / f"{operator_cache_key(mesh, k, gradients)}.npz"
    if path.is_file():
        try:
            return _load_operators(path)
        except Exception as error:  # a corrupt cache entry is recomputed, not fatal
            logger.warning("ignoring unreadable operator cache %s (%s)", path, error)
    operators = compute_operators(mesh, k, gradients)
    try:
        _save_operators(operators, path)
    except OSError as error:
        logger.warning("could not write operator cache %s (%s)", path, error)
    return operators


def _save_operators(ops: Operators, path: Path) -> None:
    arrays = {"mass": ops.mass, "evals": ops.evals, "evecs": ops.evecs}
    for name in ("laplacian", "grad_x", "grad_y"):
        matrix = getattr(ops, name)
        if matrix is not None:
            coo = matrix.tocoo()
            arrays[f"{name}_data"], arrays[f"{name}_row"], arrays[f"{name}_col"] = coo.data, coo.row, coo.col
    if ops.frames is not None:
        arrays["frames"] = ops.frames
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".npz", delete=False) as handle:
        np.savez(handle, **arrays)
    os.replace(handle.name, path)


def _load_operators(path: Path) -> Operators:
    with np.load(path) as data:
        n = data["mass"].shape[0]

        def matrix(name: str) -> sp.csr_matrix | None:
            if f"{name}_data" not in data:
                return None
            return sp.coo_matrix(
                (data[f"{name}_data"], (data[f"{name}_row"], data[f"{name}_col"])), shape=(n, n)
            ).tocsr()

        frames = data["frames"] if "frames" in data else None
        for name in data.files:
            if data[name].dtype.kind == "f" and not np.isfinite(data[name]).all():
                raise ValueError(f"{name} holds NaN or infinite values")
        return Operators(
            matrix("laplacian"),
            data["mass"],
            data["evals"],
            data["evecs"],
            matrix("grad_x"),
            matrix("grad_y"),
            frames,
        )
