"""Cumulative geodesic-error curves of several runs in one 2-D chart."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def save_error_curves(runs: dict[str, np.ndarray], path: str | os.PathLike, title: str = "") -> Path:
    """Cumulative geodesic-error curves (% correct vs threshold 0-0.25), one line per run.

    Parameters
    ----------
    runs : dict
        Label -> per-point normalised geodesic errors (N,). The legend shows each mean.
    path : str or PathLike
        PNG file to write.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from spidermatch.eval.errors import DEFAULT_THRESHOLDS, cumulative_curve

    figure, ax = plt.subplots(figsize=(5, 4))
    for label, errors in runs.items():
        errors = np.asarray(errors, dtype=np.float64)
        curve = 100.0 * cumulative_curve(errors, DEFAULT_THRESHOLDS)
        ax.plot(DEFAULT_THRESHOLDS, curve, label=f"{label}: {errors.mean():.3f}", linewidth=2)
    ax.set_xlim(0, 0.25)
    ax.set_ylim(0, 100)
    ax.set_xlabel("geodesic error threshold")
    ax.set_ylabel("% correct matches")
    ax.grid(alpha=0.3)
    ax.legend(title="mean geodesic error", fontsize=8, loc="lower right")
    ax.set_title(title or "% of correct points", fontsize=10)
    figure.tight_layout()
    path = Path(path)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path
