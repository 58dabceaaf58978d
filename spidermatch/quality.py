"""A verdict on a matching without ground truth: is it plausible, or suspect and why.

The certificate says that no matching is cheaper for the chosen costs; it cannot say that
the costs picked the right correspondence. Three symptoms of a wrong one are visible
without ground truth, on the certified low-resolution map itself:

Mirror image (symmetric flip)
    A map that swaps left and right reverses orientation: the images of the source
    triangles face against the target surface. On a correct map few do (decimation
    noise); on a mirrored one most. ``flipped`` is that share of low-resolution source
    triangles (``spidermatch.metrics`` definitions; degenerate images counted apart).
Collapse
    A matching that sends many source vertices onto few target vertices (the trivial
    stay path, or costs that do not discriminate): ``distinct`` is the share of distinct
    target vertices among the matches.
Not proven
    A time-limited run whose gap stays large: ``gap``.

The thresholds were calibrated on FAUST_r and TOSCA_animals pairs with ground truth
(``bench/bench_quality.py``; the confusion table is in ``bench/results/``).
"""

from __future__ import annotations

import math

import numpy as np

from spidermatch.mesh import Mesh
from spidermatch.metrics import vertex_map_consistency

FLIPPED_SUSPECT = 0.35
"""Share of flipped low-resolution image triangles above which the map is called a mirror image."""

DISTINCT_SUSPECT = 0.5
"""Share of distinct matched target vertices below which the matching is called collapsed."""

GAP_SUSPECT = 0.05
"""Relative gap above which an unproven matching is called suspect."""


def assess(low_source: Mesh, low_target: Mesh, low_map: np.ndarray, gap: float | None) -> dict:
    """Figures and verdict of a certified low-resolution map, JSON-ready.

    Parameters
    ----------
    low_source, low_target : Mesh
        The decimated meshes the matching was solved on.
    low_map : np.ndarray, shape (V_X_low,)
        Low-resolution target vertex of each low-resolution source vertex.
    gap : float or None
        The solver's relative gap.

    Returns
    -------
    dict
        ``verdict`` ("plausible" or "suspect"), ``reasons`` (list of str) and the figures
        ``flipped``, ``degenerate``, ``tears``, ``distinct``, ``gap``.

    """
    low_map = np.asarray(low_map, dtype=np.int64)
    consistency = vertex_map_consistency(low_source, low_target, low_map)
    figures = {
        "flipped": round(consistency.flipped, 4),
        "degenerate": round(consistency.degenerate, 4),
        "tears": round(consistency.tears, 4),
        "distinct": round(np.unique(low_map).size / max(low_map.size, 1), 4),
        "gap": gap if gap is None or math.isfinite(gap) else None,
    }
    reasons = []
    if figures["flipped"] > FLIPPED_SUSPECT:
        reasons.append(
            f"{figures['flipped']:.0%} of the image triangles face against the target: "
            "likely a mirror image (left and right swapped) of the right map"
        )
    if figures["distinct"] < DISTINCT_SUSPECT:
        reasons.append(
            f"only {figures['distinct']:.0%} of the matched target vertices are distinct: the matching "
            "collapses (e.g. the trivial stay path)"
        )
    if gap is not None and math.isfinite(gap) and gap > GAP_SUSPECT:
        reasons.append(f"the solver's gap {gap:.1%} is large: a much better matching may exist")
    return {"verdict": "suspect" if reasons else "plausible", "reasons": reasons, **figures}
