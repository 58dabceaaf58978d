"""Headless figures (matplotlib, imported lazily): correspondence, error and SpiderCurve renders.

Meshes are drawn by a small orthographic renderer of our own (rotate, project, sort the
triangles back to front, Lambert shading) into flat 2-D axes: this keeps each mesh tight
in its panel and lets the SpiderCurve picture know which of its segments lie behind the
surface. The y axis is taken as "up"; each mesh is seen along its thinner horizontal
axis, from both sides.
"""

from __future__ import annotations

import logging
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.surface import occluded

logger = logging.getLogger(__name__)

UP_AXIS = 1
PANEL_HEIGHT_IN = 4.2
TITLE_FONT_SIZE = 10
PANEL_PAD = 0.02
MAX_PANEL_ASPECT = 1.6
ERROR_UNITS = "geodesic error (fraction of sqrt(area))"


# ----------------------------------------------------------------------------- colours


def position_colours(verts: np.ndarray) -> np.ndarray:
    """Colours that change under a left-right (or front-back) mirror of the shape, shape (V, 3).

    Hue is the angle around the vertical (y) axis through the centre of the bounding box,
    lightness grows with height. A mirror in any vertical plane through that axis reverses
    the hue wheel, so a flipped map swaps e.g. red and cyan limbs instead of keeping them.

    Parameters
    ----------
    verts : np.ndarray, shape (V, 3)

    Returns
    -------
    np.ndarray, shape (V, 3)
        RGB in [0, 1].
    """
    verts = np.asarray(verts, dtype=np.float64)
    low, high = verts.min(axis=0), verts.max(axis=0)
    relative = verts - (low + high) / 2
    horizontal = [axis for axis in range(3) if axis != UP_AXIS]
    hue = np.arctan2(relative[:, horizontal[1]], relative[:, horizontal[0]]) / (2 * np.pi) % 1.0
    height = (verts[:, UP_AXIS] - low[UP_AXIS]) / max(high[UP_AXIS] - low[UP_AXIS], 1e-12)
    return hsl_to_rgb(hue, np.full_like(hue, 0.85), 0.3 + 0.42 * height)


CHECKER_CELLS = 14
"""Checkerboard cells along the longest side of a shape's bounding box (texture pictures)."""

CHECKER_DARK = 0.25
"""Brightness of the dark checkerboard cells relative to the light ones."""


def checker_colours(verts: np.ndarray, cells: int = CHECKER_CELLS) -> np.ndarray:
    """A 3-D checkerboard over :func:`position_colours`, shape (V, 3): a texture to carry through a map.

    Cells are cubes of the bounding box's longest side over ``cells``; a vertex is in a dark
    cell when the sum of its three cell indices is odd. A smooth map carries the squares
    across whole; a fold or tear breaks them into speckle. The position colours underneath
    still show a left-right swap.
    """
    verts = np.asarray(verts, dtype=np.float64)
    low = verts.min(axis=0)
    size = max(float(np.ptp(verts, axis=0).max()), 1e-12) / cells
    odd = np.floor((verts - low) / size).astype(np.int64).sum(axis=1) % 2 == 1
    return position_colours(verts) * np.where(odd, CHECKER_DARK, 1.0)[:, None]


def hsl_to_rgb(hue: np.ndarray, saturation: np.ndarray, lightness: np.ndarray) -> np.ndarray:
    """Convert HSL (each (V,), in [0, 1]) to RGB, shape (V, 3)."""
    amplitude = saturation * np.minimum(lightness, 1 - lightness)
    channels = []
    for offset in (0.0, 8.0, 4.0):
        k = (offset + hue * 12.0) % 12.0
        channels.append(lightness - amplitude * np.clip(np.minimum(k - 3, 9 - k), -1, 1))
    return np.stack(channels, axis=1)


def spread_to_vertices(mesh: Mesh, vertices: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Per-vertex values from values known at some vertices.

    A vertex that carries values takes their mean; every other vertex takes the value of
    the nearest such vertex (Euclidean distance).

    Parameters
    ----------
    mesh : Mesh
    vertices : np.ndarray, shape (N,)
        Vertex indices of ``mesh`` (repeats allowed).
    values : np.ndarray, shape (N, C)

    Returns
    -------
    np.ndarray, shape (V, C)
    """
    vertices = np.asarray(vertices, dtype=np.int64)
    values = np.asarray(values, dtype=np.float64).reshape(len(vertices), -1)
    if vertices.size == 0:
        raise ValueError(f"no values to spread over {mesh.name}")
    if vertices.min() < 0 or vertices.max() >= mesh.n_verts:
        raise ValueError(f"vertex index out of range for {mesh.name} ({mesh.n_verts} vertices)")
    sums = np.zeros((mesh.n_verts, values.shape[1]))
    np.add.at(sums, vertices, values)
    counts = np.bincount(vertices, minlength=mesh.n_verts)
    hit = counts > 0
    result = np.empty_like(sums)
    result[hit] = sums[hit] / counts[hit, None]
    if not hit.all():
        hit_index = np.flatnonzero(hit)
        _, nearest = cKDTree(mesh.verts[hit_index]).query(mesh.verts[~hit])
        result[~hit] = result[hit_index[nearest]]
    return result


def map_pairs(matches: np.ndarray, n_source_verts: int) -> np.ndarray:
    """(source, target) vertex pairs (N, 2) from a dense map (V_src,) or from pairs (N, 2)."""
    matches = np.asarray(matches)
    if matches.ndim == 1:
        if matches.size != n_source_verts:
            raise ValueError(
                f"a dense map needs one target vertex per source vertex: got {matches.size} "
                f"entries for {n_source_verts} source vertices"
            )
        return np.stack([np.arange(n_source_verts), matches.astype(np.int64)], axis=1)
    if matches.ndim == 2 and matches.shape[1] == 2:
        return matches.astype(np.int64)
    raise ValueError(f"a map is src_to_tgt (V_src,) or (source, target) pairs (N, 2); got {matches.shape}")


def transfer_colours(source_colours: np.ndarray, target: Mesh, matches: np.ndarray) -> np.ndarray:
    """Colour the target through a map: the mean colour of the source vertices sent to each vertex.

    Target vertices that no source vertex is sent to take the colour of the nearest target
    vertex that one is sent to (so a sparse map still colours the whole target).

    Parameters
    ----------
    source_colours : np.ndarray, shape (V_src, 3)
    target : Mesh
    matches : np.ndarray, shape (V_src,) or (N, 2)
        Dense ``src_to_tgt`` map, or (source vertex, target vertex) pairs.

    Returns
    -------
    np.ndarray, shape (V_tgt, 3)
    """
    pairs = map_pairs(matches, len(source_colours))
    if pairs.size and (pairs[:, 0].min() < 0 or pairs[:, 0].max() >= len(source_colours)):
        raise ValueError(f"source vertex out of range ({len(source_colours)} source vertices)")
    return spread_to_vertices(target, pairs[:, 1], source_colours[pairs[:, 0]])


UNCOVERED_GREY = 0.8
"""Lightness of the grey an uncovered target region is drawn in."""


def greyed_uncovered(colours: np.ndarray, covered: np.ndarray | None) -> np.ndarray:
    """Vertex colours (V, 3) with the vertices outside ``covered`` (V,) bool turned pale grey.

    The region a partial source does not cover keeps a faint trace of the colours the map
    spread onto it (a fifth), so its shape still reads against the covered part.
    """
    if covered is None:
        return colours
    shaded = np.array(colours, dtype=np.float64, copy=True)
    outside = ~np.asarray(covered, dtype=bool)
    shaded[outside] = 0.2 * shaded[outside] + 0.8 * UNCOVERED_GREY
    return shaded


def error_colormap():
    """Error heat map colours: pale yellow (0), orange, dark purple (not black, so the shape shows)."""
    from matplotlib import colormaps
    from matplotlib.colors import ListedColormap

    return ListedColormap(colormaps["inferno_r"](np.linspace(0.0, 0.85, 256)), name="spidermatch_error")


def error_colours(errors: np.ndarray, vmax: float) -> np.ndarray:
    """RGB (V, 3) of per-vertex errors (V,) on :func:`error_colormap` from 0 to ``vmax``."""
    return error_colormap()(np.clip(np.asarray(errors) / vmax, 0.0, 1.0))[:, :3]


# ----------------------------------------------------------------------------- titles


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


# ----------------------------------------------------------------------------- projection


@dataclass(frozen=True)
class View:
    """An orthographic camera looking at the origin.

    Attributes
    ----------
    azimuth : float
        Degrees around the vertical axis; 0 puts the camera on the +z side.
    elevation : float
        Degrees above the horizontal plane.
    label : str
    """

    azimuth: float
    elevation: float
    label: str

    def rotation(self) -> np.ndarray:
        """(3, 3) matrix whose rows are the camera's right, up and towards-camera directions."""
        azimuth, elevation = np.radians(self.azimuth), np.radians(self.elevation)
        towards = np.array(
            [np.sin(azimuth) * np.cos(elevation), np.sin(elevation), np.cos(azimuth) * np.cos(elevation)]
        )
        right = np.cross([0.0, 1.0, 0.0], towards)
        right /= np.linalg.norm(right)
        return np.stack([right, np.cross(towards, right), towards])


def mesh_views(mesh: Mesh, elevation: float = 12.0) -> tuple[View, View]:
    """Two opposite views along the mesh's thinner horizontal axis (x or z), so its broad side shows."""
    extent = np.ptp(mesh.verts, axis=0)
    if extent[0] >= extent[2]:
        return View(0.0, elevation, "seen from +z"), View(180.0, elevation, "seen from -z")
    return View(90.0, elevation, "seen from +x"), View(270.0, elevation, "seen from -x")


def project(points: np.ndarray, view: View, centre: np.ndarray) -> np.ndarray:
    """Camera coordinates (P, 3) of ``points`` (P, 3): x right, y up, z towards the camera."""
    return (np.asarray(points) - centre) @ view.rotation().T


def _bbox_centre(mesh: Mesh) -> np.ndarray:
    return (mesh.verts.min(axis=0) + mesh.verts.max(axis=0)) / 2


def _shaded_faces(camera: np.ndarray, faces: np.ndarray, face_colours: np.ndarray):
    """Triangles (F, 3, 2) back to front, with headlight-shaded colours (F, 3)."""
    triangles = camera[faces]
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    facing = np.abs(normals[:, 2]) / np.maximum(np.linalg.norm(normals, axis=1), 1e-30)
    shade = 0.45 + 0.55 * facing
    order = np.argsort(triangles[:, :, 2].mean(axis=1))
    return triangles[order, :, :2], np.clip(face_colours[order] * shade[order, None], 0, 1)


def draw_mesh(ax, mesh: Mesh, vertex_colours: np.ndarray, view: View, centre: np.ndarray) -> np.ndarray:
    """Draw ``mesh`` shaded into the 2-D axes ``ax``; return its camera coordinates (V, 3)."""
    from matplotlib.collections import PolyCollection

    camera = project(mesh.verts, view, centre)
    triangles, colours = _shaded_faces(camera, mesh.faces, vertex_colours[mesh.faces].mean(axis=1))
    ax.add_collection(PolyCollection(triangles, facecolors=colours, edgecolors=colours, linewidths=0.25))
    return camera


# ----------------------------------------------------------------------------- figures


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

    centres = [_bbox_centre(mesh) for mesh, _, _, _ in panels]
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


# ----------------------------------------------------------------------------- SpiderCurve

CURVE_COLOUR = "#c4161c"
CURVE_PIECES_PER_EDGE = 4


def _curve_pieces(mesh: Mesh, curve_vertices: np.ndarray) -> np.ndarray:
    """The closed curve cut into short straight pieces, shape (L * K, 2, 3)."""
    loop = mesh.verts[np.append(curve_vertices, curve_vertices[0])]
    steps = np.linspace(0.0, 1.0, CURVE_PIECES_PER_EDGE + 1)
    delta = loop[1:] - loop[:-1]
    ends = loop[:-1, None, :] + steps[None, :, None] * delta[:, None, :]
    return np.stack([ends[:, :-1], ends[:, 1:]], axis=2).reshape(-1, 2, 3)


def _draw_curve(ax, mesh: Mesh, curve_vertices: np.ndarray, view: View, centre: np.ndarray, camera) -> None:
    """The curve over the drawn surface: solid in front, thin, faded and dashed behind it."""
    from matplotlib.collections import LineCollection

    tolerance = 0.01 * float(np.linalg.norm(np.ptp(mesh.verts, axis=0)))
    pieces = project(_curve_pieces(mesh, curve_vertices).reshape(-1, 3), view, centre).reshape(-1, 2, 3)
    hidden = occluded(pieces.mean(axis=1), camera, mesh.faces, tolerance)
    ax.add_collection(
        LineCollection(
            pieces[hidden][:, :, :2], colors=CURVE_COLOUR, linewidths=0.7, alpha=0.35, linestyles=(0, (2, 2))
        )
    )
    ax.add_collection(LineCollection(pieces[~hidden][:, :, :2], colors=CURVE_COLOUR, linewidths=1.8))
    counts = np.bincount(curve_vertices, minlength=mesh.n_verts)
    repeated = camera[counts > 1]
    behind = occluded(repeated, camera, mesh.faces, tolerance)
    ax.scatter(*repeated[~behind, :2].T, color="black", s=16, zorder=4)
    ax.scatter(*repeated[behind, :2].T, color="black", s=10, alpha=0.25, zorder=4)


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
    views, centre = mesh_views(mesh), _bbox_centre(mesh)
    extents = [_extent(mesh, view, centre) for view in views]
    figure, axes = _panel_figure(extents, [view.label for view in views], title, status)
    grey = np.full((mesh.n_verts, 3), 0.82)
    for ax, view in zip(axes, views):
        camera = draw_mesh(ax, mesh, grey, view, centre)
        _draw_curve(ax, mesh, curve_vertices, view, centre, camera)
    path = Path(path)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


# ----------------------------------------------------------------------------- evaluation curves


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
