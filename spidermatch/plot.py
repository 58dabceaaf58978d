"""Headless figures (matplotlib, imported lazily): correspondence renders."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from spidermatch.mesh import Mesh

logger = logging.getLogger(__name__)

VIEWS = ((15.0, -60.0), (15.0, 120.0))


def position_colours(verts: np.ndarray) -> np.ndarray:
    """RGB in [0, 1] from normalised vertex positions, shape (V, 3)."""
    low, high = verts.min(axis=0), verts.max(axis=0)
    return 0.15 + 0.85 * (verts - low) / np.maximum(high - low, 1e-12)


def transferred_colours(
    source_colours: np.ndarray, src_vertices: np.ndarray, tgt_vertices: np.ndarray, target: Mesh
) -> np.ndarray:
    """Colour every target vertex like the source vertex matched to its nearest matched target vertex.

    Parameters
    ----------
    source_colours : np.ndarray, shape (V_X, 3)
    src_vertices, tgt_vertices : np.ndarray, shape (N,)
        Matched pairs (source vertex, target vertex).
    target : Mesh

    Returns
    -------
    np.ndarray, shape (V_Y, 3)
    """
    _, nearest = cKDTree(target.verts[tgt_vertices]).query(target.verts)
    return source_colours[src_vertices[nearest]]


def _draw(ax, mesh: Mesh, colours: np.ndarray, view: tuple[float, float], alpha: float = 1.0) -> None:
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    triangles = mesh.verts[mesh.faces]
    collection = Poly3DCollection(
        triangles, facecolors=colours[mesh.faces].mean(axis=1), linewidths=0, alpha=alpha
    )
    ax.add_collection3d(collection)
    low, high = mesh.verts.min(axis=0), mesh.verts.max(axis=0)
    centre, half = (low + high) / 2, (high - low).max() / 2
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        setter(c - half, c + half)
    ax.view_init(elev=view[0], azim=view[1], vertical_axis="y")
    ax.set_axis_off()


def save_correspondence_png(
    source: Mesh,
    target: Mesh,
    src_vertices: np.ndarray,
    tgt_vertices: np.ndarray,
    path: str | os.PathLike,
    title: str = "",
) -> Path:
    """Render source and target side by side, the target coloured through the map.

    Parameters
    ----------
    source, target : Mesh
        Full-resolution meshes.
    src_vertices, tgt_vertices : np.ndarray, shape (N,)
        Matched full-resolution vertex pairs.
    path : str or PathLike
        PNG file to write.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours_x = position_colours(source.verts)
    colours_y = transferred_colours(colours_x, np.asarray(src_vertices), np.asarray(tgt_vertices), target)
    figure = plt.figure(figsize=(4 * len(VIEWS), 8))
    for row, (mesh, colours, label) in enumerate(
        ((source, colours_x, "source"), (target, colours_y, "target"))
    ):
        for column, view in enumerate(VIEWS):
            ax = figure.add_subplot(2, len(VIEWS), row * len(VIEWS) + column + 1, projection="3d")
            _draw(ax, mesh, colours, view)
            ax.set_title(label, fontsize=9)
    if title:
        figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    path = Path(path)
    figure.savefig(path, dpi=90)
    plt.close(figure)
    return path


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

    from spidermatch.evaluate import DEFAULT_THRESHOLDS, cumulative_curve

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


def save_curve_png(mesh: Mesh, curve_vertices: np.ndarray, path: str | os.PathLike, title: str = "") -> Path:
    """Draw a SpiderCurve (L,) on its (low-resolution) mesh from two sides; repeated vertices marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    counts = np.bincount(curve_vertices, minlength=mesh.n_verts)
    loop = np.append(curve_vertices, curve_vertices[0])
    figure = plt.figure(figsize=(4 * len(VIEWS), 4.5))
    for column, view in enumerate(VIEWS):
        ax = figure.add_subplot(1, len(VIEWS), column + 1, projection="3d")
        ax.computed_zorder = False  # the curve over the see-through surface, not behind it
        _draw(ax, mesh, np.full((mesh.n_verts, 3), 0.6), view, alpha=0.25)
        points = mesh.verts[loop]
        ax.plot(points[:, 0], points[:, 1], points[:, 2], color="tab:red", linewidth=1.2)
        repeated = mesh.verts[counts > 1]
        ax.scatter(repeated[:, 0], repeated[:, 1], repeated[:, 2], color="black", s=14)
    figure.suptitle(
        title
        or f"SpiderCurve: {len(curve_vertices)} positions, {int((counts > 1).sum())} "
        "self-intersections (dots)",
        fontsize=10,
    )
    figure.tight_layout()
    path = Path(path)
    figure.savefig(path, dpi=90)
    plt.close(figure)
    return path
