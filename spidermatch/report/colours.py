"""Per-vertex colours of a match's pictures.

Positions, checkerboards and errors, and their transfer through a map (plain numpy;
matplotlib's colour map is imported lazily).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from spidermatch.geometry.mesh import Mesh
from spidermatch.report.render import UP_AXIS


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
