"""A verdict on a matching without ground truth: is it plausible, or suspect and why.

The certificate says that no matching is cheaper for the chosen costs; it cannot say that
the costs picked the right correspondence. Three symptoms of a wrong one are visible
without ground truth, on the certified low-resolution map itself:

Mirror image (symmetric flip)
    A map that swaps left and right reverses orientation: the images of the source
    triangles face against the target surface. On a correct map few do (decimation
    noise); on a mirrored one most. ``flipped`` and ``degenerate`` are the shares of
    low-resolution source triangles whose image faces against the target or has no area
    (``spidermatch.eval.metrics`` definitions); ``mirror`` is the flipped share of those whose
    image has an area, the figure judged (degenerate images, two corners on one target
    vertex, say nothing about orientation and are many where the map collapses).
Collapse
    A matching that sends many source vertices onto few target vertices (the trivial
    stay path, or costs that do not discriminate): ``distinct`` is the share of distinct
    target vertices among the matches.
Not proven
    A time-limited run whose gap stays large: ``gap``.

The thresholds were calibrated on pairs with ground truth (``bench/bench_quality.py``,
``bench/results/quality_verdict_calibration*``): each separates the correct maps (mean error
below 0.1) from the wrong ones in its figure, mirror images in ``mirror``, collapsed maps in
``distinct`` and ``gap`` (measurements: bench/README.md, solver constants).
"""

from __future__ import annotations

import math

import numpy as np

from spidermatch.eval.metrics import vertex_map_consistency
from spidermatch.geometry.mesh import Mesh

MIRROR_SUSPECT = 0.3
"""Flipped share of the non-degenerate image triangles above which the map is called a mirror image."""

DISTINCT_SUSPECT = 0.45
"""Share of distinct matched target vertices below which the matching is called collapsed."""

GAP_SUSPECT = 0.2
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
        ``mirror``, ``flipped``, ``degenerate``, ``tears``, ``distinct``, ``gap``.

    """
    low_map = np.asarray(low_map, dtype=np.int64)
    consistency = vertex_map_consistency(low_source, low_target, low_map)
    proper = 1.0 - consistency.degenerate
    figures = {
        "mirror": round(consistency.flipped / proper, 4) if proper > 0 else 1.0,
        "flipped": round(consistency.flipped, 4),
        "degenerate": round(consistency.degenerate, 4),
        "tears": round(consistency.tears, 4),
        "distinct": round(np.unique(low_map).size / max(low_map.size, 1), 4),
        "gap": gap if gap is None or math.isfinite(gap) else None,
    }
    return {**judge(figures), **figures}


def judge(figures) -> dict:
    """``verdict`` and ``reasons`` from the figures ``mirror``, ``distinct`` and ``gap`` (a mapping)."""
    reasons = []
    if figures["mirror"] > MIRROR_SUSPECT:
        reasons.append(
            f"{figures['mirror']:.0%} of the image triangles face against the target: "
            "likely a mirror image (left and right swapped) of the right map, at least in part"
        )
    if figures["distinct"] < DISTINCT_SUSPECT:
        reasons.append(
            f"only {figures['distinct']:.0%} of the matched target vertices are distinct: the matching "
            "collapses (e.g. the trivial stay path)"
        )
    gap = figures.get("gap")
    if gap is not None and math.isfinite(gap) and gap > GAP_SUSPECT:
        reasons.append(f"the solver's gap {gap:.1%} is large: a much better matching may exist")
    return {"verdict": "suspect" if reasons else "plausible", "reasons": reasons}
