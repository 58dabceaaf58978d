"""A small orthographic renderer of triangle meshes into flat 2-D matplotlib axes.

Rotate, project, sort the triangles back to front, Lambert shading: this keeps each mesh
tight in its panel and lets the SpiderCurve picture know which of its segments lie behind
the surface. The y axis is taken as "up"; each mesh is seen along its thinner horizontal
axis, from both sides.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.surface import occluded

UP_AXIS = 1


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


def bbox_centre(mesh: Mesh) -> np.ndarray:
    """The centre of the mesh's bounding box, shape (3,): what the views turn about."""
    return (mesh.verts.min(axis=0) + mesh.verts.max(axis=0)) / 2


def shaded_faces(camera: np.ndarray, faces: np.ndarray, face_colours: np.ndarray):
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
    triangles, colours = shaded_faces(camera, mesh.faces, vertex_colours[mesh.faces].mean(axis=1))
    ax.add_collection(PolyCollection(triangles, facecolors=colours, edgecolors=colours, linewidths=0.25))
    return camera


CURVE_COLOUR = "#c4161c"


CURVE_PIECES_PER_EDGE = 4


def curve_pieces(mesh: Mesh, curve_vertices: np.ndarray) -> np.ndarray:
    """The closed curve cut into short straight pieces, shape (L * K, 2, 3)."""
    loop = mesh.verts[np.append(curve_vertices, curve_vertices[0])]
    steps = np.linspace(0.0, 1.0, CURVE_PIECES_PER_EDGE + 1)
    delta = loop[1:] - loop[:-1]
    ends = loop[:-1, None, :] + steps[None, :, None] * delta[:, None, :]
    return np.stack([ends[:, :-1], ends[:, 1:]], axis=2).reshape(-1, 2, 3)


def draw_curve(ax, mesh: Mesh, curve_vertices: np.ndarray, view: View, centre: np.ndarray, camera) -> None:
    """The curve over the drawn surface: solid in front, thin, faded and dashed behind it."""
    from matplotlib.collections import LineCollection

    tolerance = 0.01 * float(np.linalg.norm(np.ptp(mesh.verts, axis=0)))
    pieces = project(curve_pieces(mesh, curve_vertices).reshape(-1, 3), view, centre).reshape(-1, 2, 3)
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
