"""A self-contained interactive HTML viewer of a match (no network needed to open it).

The page (``viewer_template.html``, hand-written JavaScript) shows the source and the
target side by side with one shared camera: drag rotates both, the wheel zooms, a
double-click resets. It renders with WebGL, or with a 2-D canvas where WebGL is not
available. Meshes and colours are embedded as base64 arrays (float32 positions, uint16 or
uint32 triangle indices, uint8 RGB per vertex): about 0.4 MB for two 5000-vertex meshes.
"""

from __future__ import annotations

import base64
import html
import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spidermatch.geometry.mesh import Mesh
from spidermatch.report.colours import (
    checker_colours,
    error_colours,
    greyed_uncovered,
    position_colours,
    spread_to_vertices,
    transfer_colours,
)
from spidermatch.report.plot import ERROR_UNITS
from spidermatch.report.render import mesh_views

logger = logging.getLogger(__name__)

TEMPLATE = Path(__file__).with_name("viewer_template.html")
TRANSFER_LAYER = "colour transfer"
TEXTURE_LAYER = "texture"
ERROR_LAYER = "error"


@dataclass(frozen=True)
class ViewerMesh:
    """One panel of the viewer.

    Attributes
    ----------
    label : str
        Caption shown above the panel.
    mesh : Mesh
    layers : dict
        Colour layer name -> RGB in [0, 1], shape (V, 3). The page offers one button per
        layer name; a mesh without the chosen layer shows its first one.
    """

    label: str
    mesh: Mesh
    layers: dict = field(default_factory=dict)


def _base64(array: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(array).tobytes()).decode("ascii")


def encode_mesh(item: ViewerMesh) -> dict:
    """JSON-ready description of a panel: label, base64 positions, faces and colour layers."""
    if not item.layers:
        raise ValueError(f"viewer mesh {item.label!r} has no colour layer")
    index_type = np.uint16 if item.mesh.n_verts < 2**16 else np.uint32
    layers = {}
    for name, colours in item.layers.items():
        colours = np.asarray(colours, dtype=np.float64)
        if colours.shape != (item.mesh.n_verts, 3):
            raise ValueError(
                f"colour layer {name!r} of {item.label!r} has shape {colours.shape}, "
                f"expected ({item.mesh.n_verts}, 3)"
            )
        layers[name] = _base64(np.round(np.clip(colours, 0, 1) * 255).astype(np.uint8))
    return {
        "label": item.label,
        "positions": _base64(item.mesh.verts.astype("<f4")),
        "faces": _base64(item.mesh.faces.astype(index_type).astype(np.dtype(index_type).newbyteorder("<"))),
        "index_bytes": int(np.dtype(index_type).itemsize),
        "layers": layers,
    }


def save_viewer_html(
    panels: tuple[ViewerMesh, ViewerMesh],
    path: str | os.PathLike,
    title: str = "",
    status: str = "",
    layer_notes: dict | None = None,
) -> Path:
    """Write the viewer page for two panels (left, right).

    Parameters
    ----------
    panels : tuple of ViewerMesh
        Exactly two panels; the first decides the initial camera
        (see :func:`spidermatch.report.render.mesh_views`).
    path : str or PathLike
        HTML file to write.
    title, status : str
        Shown at the top of the page.
    layer_notes : dict, optional
        Layer name -> a line explaining it, shown while that layer is on.
    """
    if len(panels) != 2:
        raise ValueError(f"the viewer shows two meshes, got {len(panels)}")
    names = list(dict.fromkeys(name for panel in panels for name in panel.layers))
    view = mesh_views(panels[0].mesh)[0]
    data = {
        "title": title,
        "status": status,
        "meshes": [encode_mesh(panel) for panel in panels],
        "layer_names": names,
        "layer_notes": dict(layer_notes or {}),
        "yaw": float(np.radians(view.azimuth)),
        "pitch": float(-np.radians(view.elevation)),
    }
    # No "<" in the embedded JSON: "</script>" or "<!--" in a title must not end or change the element.
    payload = json.dumps(data, separators=(",", ":")).replace("<", "\\u003c")
    page = TEMPLATE.read_text(encoding="utf-8")
    page = page.replace("__PAGE_TITLE__", html.escape(title or "spidermatch viewer")).replace(
        "__DATA__", payload
    )
    path = Path(path)
    path.write_text(page, encoding="utf-8")
    return path


def save_match_viewer(
    source: Mesh,
    target: Mesh,
    matches: np.ndarray,
    path: str | os.PathLike,
    title: str = "",
    status: str = "",
    errors: tuple[np.ndarray, np.ndarray] | None = None,
    target_covered: np.ndarray | None = None,
    vmax: float = 0.2,
) -> Path:
    """The viewer page of a match: source coloured by position, target coloured through the map.

    Parameters
    ----------
    source, target : Mesh
        Full-resolution meshes.
    matches : np.ndarray, shape (V_src,) or (N, 2)
        Dense ``src_to_tgt`` map or sparse (source, target) pairs (see
        :func:`spidermatch.report.colours.transfer_colours`).
    path : str or PathLike
    title, status : str
    errors : tuple of np.ndarray, optional
        (source vertices (N,), geodesic errors (N,)): adds an error layer, the heat map on
        the source and the same colours carried to the target through the map.
    target_covered : np.ndarray, shape (V_tgt,) bool, optional
        The region a partial source covers; the rest of the target is greyed out in every layer.
    vmax : float
        Error drawn with the darkest colour.
    """
    colours_x = position_colours(source.verts)
    layers_x = {TRANSFER_LAYER: colours_x}
    transferred = transfer_colours(colours_x, target, matches)
    layers_y = {TRANSFER_LAYER: greyed_uncovered(transferred, target_covered)}
    notes = {TRANSFER_LAYER: "source coloured by position (hue: around the vertical axis, light: height)"}
    if np.asarray(matches).ndim == 1:  # a dense map: a checkerboard carried across
        layers_x[TEXTURE_LAYER] = checker_colours(source.verts)
        layers_y[TEXTURE_LAYER] = greyed_uncovered(
            transfer_colours(layers_x[TEXTURE_LAYER], target, matches), target_covered
        )
        notes[TEXTURE_LAYER] = "texture transfer: a checkerboard on the source carried through the dense map"
    if errors is not None:
        per_vertex = spread_to_vertices(source, errors[0], np.asarray(errors[1], dtype=np.float64))[:, 0]
        layers_x[ERROR_LAYER] = error_colours(per_vertex, vmax)
        layers_y[ERROR_LAYER] = greyed_uncovered(
            transfer_colours(layers_x[ERROR_LAYER], target, matches), target_covered
        )
        notes[ERROR_LAYER] = (
            f"{ERROR_UNITS}: pale 0, dark >= {vmax:g}; mean {np.mean(errors[1]):.4f}; "
            "on the target, carried through the map"
        )
    if target_covered is not None:
        notes = {layer: f"{note}; grey on the target: not covered" for layer, note in notes.items()}
    panels = (ViewerMesh("source", source, layers_x), ViewerMesh("target", target, layers_y))
    return save_viewer_html(panels, path, title, status, notes)
