"""The training objective: unsupervised functional-map terms plus an optional supervised term.

The unsupervised terms live in :mod:`features.fmap` (test-time adaptation uses them
too); this module adds the supervised cross-entropy on known correspondences and
combines everything with the weights of :class:`LossConfig`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from features.diffusion_net import TorchOperators
from features.fmap import FmapLossConfig, fmap_terms


@dataclass
class LossConfig(FmapLossConfig):
    """Unsupervised settings (see :class:`features.fmap.FmapLossConfig`) and ``w_sup``.

    Attributes
    ----------
    w_sup : float
        Weight of the supervised loss on ground-truth reference points (0: unsupervised).
    w_partial : float
        Weight of the cut-consistency term (:func:`cut_consistency_loss`; 0: off).
    partial_points : int
        Kept vertices of a partial copy scored by that term at each step.
    """

    w_sup: float = 0.0
    w_partial: float = 0.0
    partial_points: int = 512


def supervised_loss(p_xy: torch.Tensor, corr_x: torch.Tensor, corr_y: torch.Tensor) -> torch.Tensor:
    """Mean negative log-probability the soft map gives to the true matches.

    Parameters
    ----------
    p_xy : torch.Tensor, shape (V_x, V_y)
        Row-stochastic soft point map.
    corr_x, corr_y : torch.Tensor, shape (N,), int64
        Corresponding vertices: ``corr_x[n]`` on X matches ``corr_y[n]`` on Y.

    Returns
    -------
    torch.Tensor, scalar
    """
    if corr_x.shape != corr_y.shape:
        raise ValueError(f"correspondences differ in length: {tuple(corr_x.shape)} vs {tuple(corr_y.shape)}")
    return -torch.log(p_xy[corr_x, corr_y].clamp(min=1e-12)).mean()


def cut_consistency_loss(
    feat_part: torch.Tensor,
    feat_whole: torch.Tensor,
    to_whole: torch.Tensor,
    temperature: float,
    points: torch.Tensor | None = None,
) -> torch.Tensor:
    """Cross-entropy of finding each vertex of a cut copy at its own vertex of the whole shape.

    A partial copy knows exactly where each of its vertices came from, so this term needs
    no labels: it asks the features of a part to be those of the whole, which makes them
    survive cuts, holes and single views.

    Parameters
    ----------
    feat_part : torch.Tensor, shape (V_p, C)
        Features of the partial copy.
    feat_whole : torch.Tensor, shape (V, C)
        Features of the whole shape.
    to_whole : torch.Tensor, shape (V_p,), int64
        Vertex of the whole each vertex of the part is.
    temperature : float
        Softmax temperature over cosine similarities.
    points : torch.Tensor, shape (P,), int64, optional
        The part's vertices to score (default: all).

    Returns
    -------
    torch.Tensor, scalar
    """
    if points is not None:
        feat_part, to_whole = feat_part[points], to_whole[points]
    part = torch.nn.functional.normalize(feat_part, dim=-1)
    whole = torch.nn.functional.normalize(feat_whole, dim=-1)
    logits = part @ whole.T / temperature
    return torch.nn.functional.cross_entropy(logits, to_whole)


def pair_loss(
    feat_x: torch.Tensor,
    feat_y: torch.Tensor,
    ops_x: TorchOperators,
    ops_y: TorchOperators,
    config: LossConfig,
    corr: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> tuple[torch.Tensor, dict[str, float]]:
    """Weighted training loss of one pair and its unweighted terms.

    Parameters
    ----------
    feat_x : torch.Tensor, shape (V_x, C)
    feat_y : torch.Tensor, shape (V_y, C)
    ops_x, ops_y : TorchOperators
    config : LossConfig
    corr : (torch.Tensor, torch.Tensor), optional
        Ground-truth vertex pairs, each (N,); used only when ``config.w_sup > 0``.

    Returns
    -------
    total : torch.Tensor, scalar
    terms : dict of str to float
        ``bij``, ``orth``, ``couple`` (and ``sup``) before weighting.
    """
    terms = fmap_terms(feat_x, feat_y, ops_x, ops_y, config)
    total = terms.weighted(config)
    values = {"bij": terms.bij.item(), "orth": terms.orth.item(), "couple": terms.couple.item()}
    if config.w_sup > 0:
        if corr is None:
            raise ValueError("w_sup > 0 needs ground-truth correspondences for every training shape")
        sup = supervised_loss(terms.p_xy, corr[0], corr[1])
        total = total + config.w_sup * sup
        values["sup"] = sup.item()
    return total, values
