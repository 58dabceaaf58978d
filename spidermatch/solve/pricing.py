"""Pricing every column of the full model against LP duals, one block of layers at a time.

A pass gives the Lagrangian bound L(y) over all columns and keeps the columns of reduced cost
up to a cutoff, with the least reduced cost of those it left out; path reduced costs
(:mod:`spidermatch.solve.path_costs`) can replace the reduced costs, and a pass can be cut
down to a lower threshold without pricing again.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace

import numpy as np

from spidermatch.model.lazy_model import LazyModel
from spidermatch.solve.cuts import imposes_paths
from spidermatch.solve.lp_cuts import CutDuals
from spidermatch.solve.path_costs import path_reduced_costs

logger = logging.getLogger(__name__)


BLOCK_COLUMNS = 1_000_000  # edges priced at once (~80 bytes each in flight)


@dataclass(frozen=True, eq=False)
class Pricing:
    """One pricing pass over every column of the full model for fixed row multipliers.

    Attributes
    ----------
    bound : float
        ``L(y)``, a lower bound for the full model.
    columns : np.ndarray, shape (k,)
        Sorted edge ids with reduced cost at most ``cutoff``.
    reduced : np.ndarray, shape (k,)
        Their reduced costs, or after :func:`with_path_reduced_costs` their path reduced costs: a solution
        using column j costs at least ``bound + reduced[j]`` (if positive).
    cutoff : float
    min_outside : float
        Smallest reduced cost of the columns not selected; inf if none.

    """

    bound: float
    columns: np.ndarray
    reduced: np.ndarray
    cutoff: float
    min_outside: float


def price(lazy: LazyModel, y: np.ndarray, threshold: float, cut_duals: CutDuals | None = None) -> Pricing:
    """Reduced costs of every column, block by block; keep those at most ``threshold``.

    Parameters
    ----------
    lazy : LazyModel
    y : np.ndarray, shape (n_rows,)
        Sign-corrected row multipliers.
    threshold : float
    cut_duals : CutDuals, optional
        The multipliers of connectivity cuts (rows with right-hand side 0, so they add nothing
        to the row term of the bound), as their correction of the reduced costs.

    """
    cut_duals = CutDuals.none() if cut_duals is None else cut_duals
    potentials = lazy.potentials(y)
    block = lazy.graph.block_size
    negative_sums, kept_ids, kept_reduced, min_outside = [], [], [], math.inf
    for start, stop in lazy.layer_blocks(max(1, BLOCK_COLUMNS // block)):
        reduced = lazy.block_reduced_costs(start, stop, potentials)
        cut_duals.subtract_from(reduced, start * block)
        negative_sums.append(float(np.minimum(reduced, 0.0).sum()))
        keep = reduced <= threshold
        kept_ids.append(np.flatnonzero(keep) + start * block)
        kept_reduced.append(reduced[keep])
        if not keep.all():
            min_outside = min(min_outside, float(reduced[~keep].min()))
    bound = lazy.row_term(y) + math.fsum(negative_sums)
    return Pricing(bound, np.concatenate(kept_ids), np.concatenate(kept_reduced), threshold, min_outside)


def with_path_reduced_costs(lazy: LazyModel, priced: Pricing) -> Pricing:
    """The same pass with path reduced costs (:mod:`spidermatch.solve.path_costs`) in place of ``reduced``.

    Every column of the pass keeps its id; ``min_outside`` stays valid, as a column outside has
    path reduced cost at least its reduced cost, above the cutoff.
    """
    if not imposes_paths(lazy):
        return priced  # solutions need not be closed paths: reduced costs only
    start = time.perf_counter()
    path_costs = path_reduced_costs(lazy.graph, priced.columns, priced.reduced, priced.cutoff)
    logger.info(
        "colgen: path reduced costs of %d columns (%.1f s); %d of them at most the cutoff %.3g",
        priced.columns.size, time.perf_counter() - start, int(np.sum(path_costs <= priced.cutoff)),
        priced.cutoff,
    )  # fmt: skip
    return replace(priced, reduced=path_costs)


def up_to(priced: Pricing, threshold: float) -> Pricing:
    """The part of a pricing pass at most ``threshold`` (which must not exceed its cutoff).

    Columns between ``threshold`` and the pass's cutoff move outside: ``min_outside`` is the
    smaller of their least reduced cost and the pass's own ``min_outside``.
    """
    if threshold > priced.cutoff:
        raise ValueError(f"threshold {threshold} above the pricing pass's cutoff {priced.cutoff}")
    keep = priced.reduced <= threshold
    min_outside = min(priced.min_outside, float(priced.reduced[~keep].min(initial=math.inf)))
    return Pricing(priced.bound, priced.columns[keep], priced.reduced[keep], threshold, min_outside)
