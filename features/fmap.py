"""Differentiable functional maps and the unsupervised matching objective.

The objective follows Cao, Roetzer and Bernard, "Unsupervised Learning of Robust
Spectral Shape Matching" (SIGGRAPH 2023): functional maps C_xy and C_yx are solved
from the learned features with a Laplacian-commutativity (resolvent) regulariser,
pushed towards bijectivity and orthogonality, and coupled to the functional map
induced by a soft point map (a softmax over feature similarities).

Names: V_x, V_y vertices, C channels, K eigenpairs of the functional map basis.
A functional map C_xy has shape (K, K) and maps spectral coefficients on X to
coefficients on Y.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from features.diffusion_net import TorchOperators


@dataclass
class FmapLossConfig:
    """Settings of the unsupervised functional-map objective.

    Attributes
    ----------
    n_fmap : int
        Eigenpairs K of the functional map basis.
    lambda_reg : float
        Weight of the resolvent (Laplacian-commutativity) regulariser.
    resolvent_gamma : float
        Exponent gamma of the resolvent mask.
    temperature : float
        Softmax temperature of the soft point map (features are L2-normalised).
    w_bij, w_orth, w_couple : float
        Weights of the bijectivity, orthogonality and coupling terms.

    """

    n_fmap: int = 50
    lambda_reg: float = 100.0
    resolvent_gamma: float = 0.5
    temperature: float = 0.07
    w_bij: float = 1.0
    w_orth: float = 1.0
    w_couple: float = 1.0


def resolvent_mask(evals_x: torch.Tensor, evals_y: torch.Tensor, gamma: float = 0.5) -> torch.Tensor:
    """Resolvent mask of Ren et al. ("Structured regularization of functional maps").

    With eigenvalues scaled by the largest of both shapes and
    ``r(l) = (l^g + i) / (l^(2g) + 1)``, the mask is ``M_ij = |r(ly_i) - r(lx_j)|^2``;
    it penalises entries of C_xy that break commutativity with the Laplacians.

    Parameters
    ----------
    evals_x : torch.Tensor, shape (K_x,)
    evals_y : torch.Tensor, shape (K_y,)
    gamma : float

    Returns
    -------
    torch.Tensor, shape (K_y, K_x)

    """
    scale = torch.maximum(evals_x.max(), evals_y.max()).clamp(min=1e-12)
    power_x = (evals_x.clamp(min=0) / scale) ** gamma
    power_y = (evals_y.clamp(min=0) / scale) ** gamma
    real = power_y[:, None] / (power_y[:, None] ** 2 + 1) - power_x[None, :] / (power_x[None, :] ** 2 + 1)
    imag = 1 / (power_y[:, None] ** 2 + 1) - 1 / (power_x[None, :] ** 2 + 1)
    return real**2 + imag**2


def regularised_fmap(
    coef_x: torch.Tensor, coef_y: torch.Tensor, mask: torch.Tensor, lambda_reg: float
) -> torch.Tensor:
    """Functional map minimising ``|C A - B|^2 + lambda sum_ij M_ij C_ij^2``.

    Row i of C solves ``(A A^T + lambda diag(M_i)) c_i = A b_i``; all K_y rows are
    solved in one batched call.

    Parameters
    ----------
    coef_x : torch.Tensor, shape (K_x, C)
        Spectral coefficients A of the features on X.
    coef_y : torch.Tensor, shape (K_y, C)
        Spectral coefficients B of the features on Y.
    mask : torch.Tensor, shape (K_y, K_x)
    lambda_reg : float

    Returns
    -------
    torch.Tensor, shape (K_y, K_x)

    """
    if coef_x.shape[1] != coef_y.shape[1]:
        raise ValueError(f"feature channels differ: {coef_x.shape[1]} on X, {coef_y.shape[1]} on Y")
    if mask.shape != (coef_y.shape[0], coef_x.shape[0]):
        raise ValueError(
            f"mask must have shape {(coef_y.shape[0], coef_x.shape[0])}, got {tuple(mask.shape)}"
        )
    gram = coef_x @ coef_x.T  # (K_x, K_x)
    systems = gram[None, :, :] + lambda_reg * torch.diag_embed(mask)  # (K_y, K_x, K_x)
    rhs = coef_y @ coef_x.T  # (K_y, K_x)
    return torch.linalg.solve(systems, rhs[:, :, None])[:, :, 0]


def soft_point_map(feat_a: torch.Tensor, feat_b: torch.Tensor, temperature: float) -> torch.Tensor:
    """Row-stochastic soft map from A to B: softmax over B of cosine similarity / temperature.

    Parameters
    ----------
    feat_a : torch.Tensor, shape (V_a, C)
    feat_b : torch.Tensor, shape (V_b, C)
    temperature : float

    Returns
    -------
    torch.Tensor, shape (V_a, V_b)
        Entry (i, j) is the probability that vertex i of A corresponds to vertex j of B.

    """
    similarity = F.normalize(feat_a, dim=1) @ F.normalize(feat_b, dim=1).T
    return torch.softmax(similarity / temperature, dim=1)


def pointmap_to_fmap(
    p_yx: torch.Tensor, ops_x: TorchOperators, ops_y: TorchOperators, k: int
) -> torch.Tensor:
    """Functional map C_xy induced by a soft point map from Y to X.

    A function f on X pulls back to ``P_yx f`` on Y, so
    ``C_xy = evecs_trans_y[:k] @ P_yx @ evecs_x[:, :k]``.

    Parameters
    ----------
    p_yx : torch.Tensor, shape (V_y, V_x)
    ops_x, ops_y : TorchOperators
    k : int

    Returns
    -------
    torch.Tensor, shape (K, K)

    """
    return ops_y.evecs_trans[:k] @ (p_yx @ ops_x.evecs[:, :k])


def _squared_frobenius(matrix: torch.Tensor) -> torch.Tensor:
    return (matrix**2).sum()


@dataclass
class PairTerms:
    """Loss terms of one pair (scalars) and the soft point maps they used.

    Attributes
    ----------
    bij, orth, couple : torch.Tensor, scalar
        Unweighted bijectivity, orthogonality and coupling losses.
    p_xy : torch.Tensor, shape (V_x, V_y)
    p_yx : torch.Tensor, shape (V_y, V_x)

    """

    bij: torch.Tensor
    orth: torch.Tensor
    couple: torch.Tensor
    p_xy: torch.Tensor
    p_yx: torch.Tensor

    def weighted(self, config: FmapLossConfig) -> torch.Tensor:
        """``w_bij bij + w_orth orth + w_couple couple``."""
        return config.w_bij * self.bij + config.w_orth * self.orth + config.w_couple * self.couple


def fmap_terms(
    feat_x: torch.Tensor,
    feat_y: torch.Tensor,
    ops_x: TorchOperators,
    ops_y: TorchOperators,
    config: FmapLossConfig,
) -> PairTerms:
    """Unsupervised loss terms of a shape pair.

    Parameters
    ----------
    feat_x : torch.Tensor, shape (V_x, C)
    feat_y : torch.Tensor, shape (V_y, C)
    ops_x, ops_y : TorchOperators
        With at least K = ``config.n_fmap`` eigenpairs.
    config : FmapLossConfig

    Returns
    -------
    PairTerms

    """
    k = config.n_fmap
    if ops_x.k < k or ops_y.k < k:
        raise ValueError(f"n_fmap = {k} eigenpairs requested but the shapes have {ops_x.k} and {ops_y.k}")
    coef_x = ops_x.evecs_trans[:k] @ feat_x
    coef_y = ops_y.evecs_trans[:k] @ feat_y
    mask_xy = resolvent_mask(ops_x.evals[:k], ops_y.evals[:k], config.resolvent_gamma)
    c_xy = regularised_fmap(coef_x, coef_y, mask_xy, config.lambda_reg)
    c_yx = regularised_fmap(coef_y, coef_x, mask_xy.T, config.lambda_reg)
    eye = torch.eye(k, dtype=c_xy.dtype)
    bij = _squared_frobenius(c_xy @ c_yx - eye) + _squared_frobenius(c_yx @ c_xy - eye)
    orth = _squared_frobenius(c_xy.T @ c_xy - eye) + _squared_frobenius(c_yx.T @ c_yx - eye)
    p_xy = soft_point_map(feat_x, feat_y, config.temperature)
    p_yx = soft_point_map(feat_y, feat_x, config.temperature)
    couple = _squared_frobenius(c_xy - pointmap_to_fmap(p_yx, ops_x, ops_y, k)) + _squared_frobenius(
        c_yx - pointmap_to_fmap(p_xy, ops_y, ops_x, k)
    )
    return PairTerms(bij, orth, couple, p_xy, p_yx)
