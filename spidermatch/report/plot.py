"""Headless PNGs of a match (matplotlib, imported lazily).

Correspondence, texture, error and SpiderCurve panels with their titles, drawn by
:mod:`spidermatch.report.render` in the colours of :mod:`spidermatch.report.colours`.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from spidermatch.geometry.mesh import Mesh
from spidermatch.report.colours import (
    checker_colours,
    error_colormap,
    error_colours,
    greyed_uncovered,
    position_colours,
    spread_to_vertices,
    transfer_colours,
)
from spidermatch.report.render import View, bbox_centre, draw_curve, draw_mesh, mesh_views, project

PANEL_HEIGHT_IN = 4.2


TITLE_FONT_SIZE = 10


PANEL_PAD = 0.02


MAX_PANEL_ASPECT = 1.6


ERROR_UNITS = "geodesic error (fraction of sqrt(area))"


def short_label(text: str, max_chars: int) -> str:
    """``text`` with every path shortened to its file name and, if still too long, cut in the middle."""
    text = re.sub(r"\S*[/\\](\S+)", lambda match: re.split(r"[/\\]", match.group(0))[-1], text)
    if len(text) <= max_chars:
        return text
    keep = max(max_chars - 1, 2)
    return text[: (keep + 1) // 2] + "\u2026" + text[len(text) - keep // 2 :]


def title_lines(title: str, status: str, max_chars: int) -> list[str]:
    """The lines of a figure title: the title shortened to one line, the status wrapped, never cut.

    The status is broken only at its `` | `` separators, so status and gap (which come
    first) always stay whole and on their own line.
    """
    lines = [short_label(title, max_chars)] if title else []
    current = ""
    for part in status.split(" | ") if status else []:
        candidate = f"{current} | {part}" if current else part
        if current and len(candidate) > max_chars:
            lines.append(current)
            candidate = part
        current = candidate
    return lines + ([current] if current else [])


def _title_chars(figure_width_in: float) -> int:
    return int(figure_width_in * 72 / (0.6 * TITLE_FONT_SIZE))


def _panel_figure(
    extents: list[np.ndarray], labels: list[str], title: str, status: str, colourbar: bool = False
):
    """A figure with one axes per panel, each as wide as its content's aspect ratio needs.

    Parameters
    ----------
    extents : list of np.ndarray, shape (2, 2)
        Per panel, [[x_min, y_min], [x_max, y_max]] of what it shows.
    labels : list of str
        Panel captions (drawn under each panel).
    title, status : str
        The title lines (see :func:`title_lines`), drawn above the panels.
    """
    import matplotlib.pyplot as plt

    boxes = [_panel_box(low, high) for low, high in extents]
    gap, bottom = 0.15, 0.3
    bar = 0.9 if colourbar else 0.0
    content_width = sum(width for width, _ in boxes) + gap * (len(boxes) - 1)
    figure_width = max(content_width + 2 * gap + bar, 4.5)
    lines = title_lines(title, status, _title_chars(figure_width))
    top = 0.2 + 0.22 * len(lines)
    figure_height = PANEL_HEIGHT_IN + top + bottom
    figure = plt.figure(figsize=(figure_width, figure_height))
    left = (figure_width - bar - content_width) / 2
    axes = []
    for (low, high), (width, height), label in zip(extents, boxes, labels):
        lower = bottom + (PANEL_HEIGHT_IN - height) / 2
        ax = figure.add_axes(
            [left / figure_width, lower / figure_height, width / figure_width, height / figure_height]
        )
        centre, half = (low + high) / 2, np.maximum(high - low, 1e-12) * (0.5 + PANEL_PAD)
        ax.set_xlim(centre[0] - half[0], centre[0] + half[0])
        ax.set_ylim(centre[1] - half[1], centre[1] + half[1])
        ax.set_aspect("equal")
        ax.set_axis_off()
        figure.text((left + width / 2) / figure_width, 0.1 / figure_height, label, ha="center", fontsize=8)
        axes.append(ax)
        left += width + gap
    if lines:
        figure.suptitle("\n".join(lines), fontsize=TITLE_FONT_SIZE, y=0.995, va="top")
    return figure, axes


def _panel_box(low: np.ndarray, high: np.ndarray) -> tuple[float, float]:
    """Width and height in inches of a panel showing [low, high] (2,) at the largest scale that fits."""
    aspect = float(np.maximum(high - low, 1e-12)[0] / np.maximum(high - low, 1e-12)[1])
    width = min(PANEL_HEIGHT_IN * aspect, MAX_PANEL_ASPECT * PANEL_HEIGHT_IN)
    return width, width / aspect


def _extent(mesh: Mesh, view: View, centre: np.ndarray) -> np.ndarray:
    camera = project(mesh.verts, view, centre)[:, :2]
    return np.stack([camera.min(axis=0), camera.max(axis=0)])


def _render_panels(panels, title: str, status: str, path, colourbar=None) -> Path:
    """Draw (mesh, vertex colours, view, label) panels side by side and save the PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    centres = [bbox_centre(mesh) for mesh, _, _, _ in panels]
    extents = [_extent(mesh, view, centre) for (mesh, _, view, _), centre in zip(panels, centres)]
    labels = [label for *_, label in panels]
    figure, axes = _panel_figure(extents, labels, title, status, colourbar is not None)
    for ax, (mesh, colours, view, _), centre in zip(axes, panels, centres):
        draw_mesh(ax, mesh, colours, view, centre)
    if colourbar is not None:
        colourbar(figure)
    path = Path(path)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def save_correspondence_png(
    source: Mesh,
    target: Mesh,
    matches: np.ndarray,
    path: str | os.PathLike,
    title: str = "",
    status: str = "",
    target_covered: np.ndarray | None = None,
) -> Path:
    """Render source and target from both sides, the target coloured through the map.

    The source is coloured by :func:`position_colours` (hue around the vertical axis,
    lightness by height), so that left-right and front-back flips change the colours.

    Parameters
    ----------
    source, target : Mesh
        Full-resolution meshes.
    matches : np.ndarray, shape (V_src,) or (N, 2)
        A dense ``src_to_tgt`` map (target vertex of every source vertex), or sparse
        (source vertex, target vertex) pairs; see :func:`transfer_colours`.
    path : str or PathLike
        PNG file to write.
    title, status : str
        First title line (paths are shortened to file names) and the status line below it.
    target_covered : np.ndarray, shape (V_tgt,) bool, optional
        The region a partial source covers; the rest of the target is greyed out.
    """
    dense = np.asarray(matches).ndim == 1
    what = "dense map" if dense else f"{len(np.asarray(matches))} matches, nearest-match fill"
    colours = position_colours(source.verts)
    return _save_transfer_png(source, target, matches, colours, path, title, status, what, target_covered)


def save_texture_png(
    source: Mesh,
    target: Mesh,
    matches: np.ndarray,
    path: str | os.PathLike,
    title: str = "",
    status: str = "",
    target_covered: np.ndarray | None = None,
) -> Path:
    """Texture transfer: a checkerboard on the source (:func:`checker_colours`) carried to the target.

    Parameters as :func:`save_correspondence_png`, with a dense map (V_src,): each target
    vertex takes the mean colour of the source vertices mapped to it.
    """
    what = "texture transfer: a checkerboard carried through the dense map"
    colours = checker_colours(source.verts)
    return _save_transfer_png(source, target, matches, colours, path, title, status, what, target_covered)


def _save_transfer_png(source, target, matches, colours_x, path, title, status, what, target_covered) -> Path:
    """Source and target from both sides: the source in ``colours_x`` (V_src, 3), the target mapped."""
    colours_y = greyed_uncovered(transfer_colours(colours_x, target, matches), target_covered)
    views_x, views_y = mesh_views(source), mesh_views(target)
    panels = [
        (source, colours_x, views_x[0], f"source, {views_x[0].label}"),
        (target, colours_y, views_y[0], f"target, {views_y[0].label}"),
        (source, colours_x, views_x[1], f"source, {views_x[1].label}"),
        (target, colours_y, views_y[1], f"target, {views_y[1].label}"),
    ]
    if target_covered is not None:
        what += ", grey: target not covered"
    return _render_panels(panels, title, f"{status} | {what}" if status else what, path)


def save_error_png(
    source: Mesh,
    vertices: np.ndarray,
    errors: np.ndarray,
    path: str | os.PathLike,
    title: str = "",
    status: str = "",
    vmax: float = 0.2,
) -> Path:
    """Heat map of geodesic errors on the source mesh, both sides, with a colour bar.

    Parameters
    ----------
    source : Mesh
        Full-resolution source mesh.
    vertices : np.ndarray, shape (N,)
        Source vertices where the error is known (e.g. the reference points).
    errors : np.ndarray, shape (N,)
        Geodesic error at each, as a fraction of sqrt(target area). Other vertices show
        the error of the nearest evaluated vertex.
    path : str or PathLike
    title, status : str
        Title lines; the mean error is added to the status line.
    vmax : float
        Errors at or above this value get the darkest colour.
    """
    errors = np.asarray(errors, dtype=np.float64)
    per_vertex = spread_to_vertices(source, vertices, errors)[:, 0]
    colours = error_colours(per_vertex, vmax)
    views = mesh_views(source)
    panels = [(source, colours, view, f"source, {view.label}") for view in views]
    mean_line = f"mean geodesic error {errors.mean():.4f} over {errors.size} points"

    def colourbar(figure) -> None:
        from matplotlib.cm import ScalarMappable
        from matplotlib.colors import Normalize

        bar_ax = figure.add_axes([1 - 0.75 / figure.get_figwidth(), 0.12, 0.15 / figure.get_figwidth(), 0.7])
        mappable = ScalarMappable(Normalize(0, vmax), error_colormap())
        bar = figure.colorbar(mappable, cax=bar_ax, extend="max")
        bar.set_label(ERROR_UNITS, fontsize=8)
        bar.ax.tick_params(labelsize=7)

    status_line = f"{status} | {mean_line}" if status else mean_line
    return _render_panels(panels, title, status_line, path, colourbar)


def save_curve_png(
    mesh: Mesh, curve_vertices: np.ndarray, path: str | os.PathLike, title: str = "", status: str = ""
) -> Path:
    """Draw a SpiderCurve on its (low-resolution) mesh from both sides.

    Segments in front of the surface are solid; segments behind it are thin, faded and
    dashed. Repeated vertices (self-intersections) are dots, faded when hidden.

    Parameters
    ----------
    mesh : Mesh
        The mesh the curve runs on.
    curve_vertices : np.ndarray, shape (L,)
        Vertex of each curve position (closed: the last connects to the first).
    path : str or PathLike
    title, status : str
        Title lines (a default describing the curve when ``title`` is empty).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curve_vertices = np.asarray(curve_vertices, dtype=np.int64)
    n_repeated = int((np.bincount(curve_vertices, minlength=mesh.n_verts) > 1).sum())
    title = title or f"SpiderCurve: {len(curve_vertices)} positions, {n_repeated} self-intersections (dots)"
    key = "solid: in front of the surface, dashed: behind it"
    status = f"{status} | {key}" if status else key
    views, centre = mesh_views(mesh), bbox_centre(mesh)
    extents = [_extent(mesh, view, centre) for view in views]
    figure, axes = _panel_figure(extents, [view.label for view in views], title, status)
    grey = np.full((mesh.n_verts, 3), 0.82)
    for ax, view in zip(axes, views):
        camera = draw_mesh(ax, mesh, grey, view, centre)
        draw_curve(ax, mesh, curve_vertices, view, centre, camera)
    path = Path(path)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path
