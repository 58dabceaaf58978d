"""As-rigid-as-possible fitting of a mesh to goal positions (the dense method ``deformation``).

The source mesh is bent towards goal positions on the target while each vertex's ring
of edges stays as close as it can to a rotated copy of its rest shape (Sorkine and
Alexa, "As-rigid-as-possible surface modeling", 2007, with a soft data term instead of
fixed handles). With rest positions x, positions p, goals q and per-vertex goal weights
a, the energy is

    E(p, R) = sum over edges (i, j) of w_ij |(p_i - p_j) - R_i (x_i - x_j)|^2
              + sum over vertices of a_i |p_i - q_i|^2,

w_ij the clamped cotangent weights (each edge counted from both ends). It is minimised
by alternating the best rotations R_i for fixed p (an SVD of each vertex's 3x3
covariance) with the best p for fixed R (one sparse linear system, three right-hand
sides). The system's matrix ``2 L + diag(a)`` does not change between the two steps,
so it is factorised once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from spidermatch.geometry.operators import cotangent_weights

PRIOR_WEIGHT = 1e-3
"""Pull of a vertex's previous rotation, relative to its ring's weighted squared rest edge lengths."""

MIN_EDGE_WEIGHT = 1e-3
"""Lower bound of the cotangent weights (an obtuse corner's negative weight would reward stretching)."""


@dataclass(frozen=True, eq=False)
class ArapSystem:
    """A mesh's as-rigid-as-possible fitting problem with fixed goal weights.

    Attributes
    ----------
    rest : np.ndarray, shape (V, 3)
        Rest positions.
    heads, tails : np.ndarray, shape (2E,), int64
        Both directions of every edge.
    weights : np.ndarray, shape (2E,)
        Clamped cotangent weight of each directed edge.
    gather : scipy.sparse.csr_matrix, shape (V, 2E)
        Sums weighted per-edge values into their head vertex (``weights`` at (head, edge)).
    goal_weights : np.ndarray, shape (V,)
        Weight of each vertex's goal.
    factor : scipy.sparse.linalg.SuperLU
        LU factors of ``2 L + diag(goal_weights)`` (V, V).

    """

    rest: np.ndarray
    heads: np.ndarray
    tails: np.ndarray
    weights: np.ndarray
    gather: sp.csr_matrix
    goal_weights: np.ndarray
    factor: object


def directed_cotangent_weights(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, ...]:
    """Each edge in both directions with its cotangent weight, clamped below at :data:`MIN_EDGE_WEIGHT`.

    Returns
    -------
    heads, tails : np.ndarray, shape (2E,), int64
    weights : np.ndarray, shape (2E,)

    """
    weights = cotangent_weights(verts, faces).tocoo()
    return (
        weights.row.astype(np.int64),
        weights.col.astype(np.int64),
        np.maximum(weights.data, MIN_EDGE_WEIGHT),
    )


def arap_system(rest: np.ndarray, faces: np.ndarray, goal_weights: np.ndarray) -> ArapSystem:
    """Set up (and factorise) the fitting of the mesh ``rest`` (V, 3), ``faces`` (F, 3) to goals.

    ``goal_weights`` (V,) must be positive where the mesh has a vertex on no face, and
    somewhere on every connected piece (else the system is singular).
    """
    heads, tails, weights = directed_cotangent_weights(rest, faces)
    n = len(rest)
    adjacency = sp.coo_matrix((weights, (heads, tails)), shape=(n, n)).tocsr()
    laplacian = sp.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency
    matrix = (2.0 * laplacian + sp.diags(np.asarray(goal_weights, dtype=np.float64))).tocsc()
    gather = sp.csr_matrix((weights, (heads, np.arange(len(heads)))), shape=(n, len(heads)))
    goal_weights = np.asarray(goal_weights, np.float64)
    return ArapSystem(rest, heads, tails, weights, gather, goal_weights, splu(matrix))


def best_rotations(system: ArapSystem, positions: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """The rotation of each vertex's rest ring that best matches its ring at ``positions``, (V, 3, 3).

    A ring whose edges at ``positions`` are collapsed or collinear does not decide its
    rotation; a small pull (:data:`PRIOR_WEIGHT` of the ring's rest size) towards the
    vertex's ``previous`` rotation (V, 3, 3) decides it, the same way in any frame (turning
    the positions turns the result, so the fit does not depend on the target's pose).
    """
    rest_edges = system.rest[system.heads] - system.rest[system.tails]
    edges = positions[system.heads] - positions[system.tails]
    outer = (rest_edges[:, :, None] * edges[:, None, :]).reshape(-1, 9)
    covariance = np.asarray(system.gather @ outer).reshape(-1, 3, 3)
    ring_size = np.asarray(system.gather @ np.einsum("nd,nd->n", rest_edges, rest_edges))
    covariance += PRIOR_WEIGHT * ring_size[:, None, None] * np.transpose(previous, (0, 2, 1))
    left, _, right_t = np.linalg.svd(covariance)
    # R = V U^T, with the sign of the last singular direction turned where that would reflect.
    reflect = np.linalg.det(np.einsum("nji,nkj->nik", right_t, left)) < 0
    right_t[reflect, 2, :] *= -1
    return np.einsum("nji,nkj->nik", right_t, left)


def global_rotation(rest: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """The proper rotation (3, 3) best turning the centred ``rest`` (V, 3) onto the centred ``positions``."""
    covariance = (rest - rest.mean(axis=0)).T @ (positions - positions.mean(axis=0))
    left, _, right_t = np.linalg.svd(covariance)
    if np.linalg.det(right_t.T @ left.T) < 0:
        right_t[2, :] *= -1
    return right_t.T @ left.T


def fit(system: ArapSystem, goals: np.ndarray, start: np.ndarray, rounds: int) -> np.ndarray:
    """Positions (V, 3) minimising the energy of the module docstring, from ``start`` (V, 3).

    ``rounds`` alternations of the rotations and the positions.
    """
    rest_edges = system.rest[system.heads] - system.rest[system.tails]
    pulled = system.goal_weights[:, None] * goals
    positions = np.asarray(start, dtype=np.float64)
    rotations = np.broadcast_to(global_rotation(system.rest, positions), (len(positions), 3, 3))
    for _ in range(rounds):
        rotations = best_rotations(system, positions, rotations)
        mean_rotation = 0.5 * (rotations[system.heads] + rotations[system.tails])
        turned = np.einsum("nab,nb->na", mean_rotation, rest_edges)
        rhs = 2.0 * np.asarray(system.gather @ turned) + pulled
        positions = np.column_stack([system.factor.solve(rhs[:, axis]) for axis in range(3)])
    return positions
