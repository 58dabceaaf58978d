"""Reading and writing meshes (.off, .obj, .ply) and correspondence files (.vts)."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from spidermatch.mesh import Mesh, MeshError, make_mesh

logger = logging.getLogger(__name__)

MESH_SUFFIXES = (".off", ".obj", ".ply")


def load_mesh(path: str | os.PathLike, validate: bool = True) -> Mesh:
    """Read a triangle mesh without reordering or merging its vertices.

    Parameters
    ----------
    path : str or PathLike
        A ``.off``, ``.obj`` or ``.ply`` file.
    validate : bool
        Run :func:`spidermatch.mesh.validate_mesh` (recommended).

    Returns
    -------
    Mesh
        ``verts`` (V, 3) float64 and ``faces`` (F, 3) int64 in file order.

    Raises
    ------
    MeshError
        The file is missing, has an unsupported type, cannot be parsed or fails validation.

    """
    path = Path(path)
    name = str(path)
    if not path.is_file():
        raise MeshError(f"{name}: no such file")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise MeshError(
            f"{name}: unsupported mesh type '{path.suffix}' (expected one of {', '.join(MESH_SUFFIXES)})"
        )
    if path.stat().st_size == 0:
        raise MeshError(f"{name}: empty mesh (the file is empty)")
    verts, faces = _read_with_trimesh(path)
    if validate:
        return make_mesh(verts, faces, name)
    return Mesh(verts, faces, name)


def _read_with_trimesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    try:
        loaded = trimesh.load(
            str(path), process=False, maintain_order=True, force="mesh", skip_materials=True
        )
    except Exception as error:  # trimesh raises many unrelated types on bad files
        raise MeshError(f"{path}: could not be read as a mesh ({type(error).__name__}: {error})") from error
    verts = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    return verts, faces.reshape(-1, 3) if faces.size else np.zeros((0, 3), dtype=np.int64)


def save_mesh(mesh: Mesh, path: str | os.PathLike) -> None:
    """Write a mesh; the type follows the suffix (.off, .obj, .ply). Vertex order is kept."""
    import trimesh

    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise MeshError(f"{path}: unsupported mesh type '{path.suffix}'")
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.Trimesh(mesh.verts, mesh.faces, process=False).export(str(path))


def read_vts(path: str | os.PathLike, n_verts: int | None = None) -> np.ndarray:
    """Read a ``.vts`` correspondence file (1-based vertex indices, one per line).

    Parameters
    ----------
    path : str or PathLike
    n_verts : int, optional
        Number of vertices of the mesh the file refers to; indices are checked against it.

    Returns
    -------
    np.ndarray, shape (K,), int64
        0-based vertex indices; row k of two shapes' files correspond.

    """
    path = Path(path)
    if not path.is_file():
        raise MeshError(f"{path}: no such correspondence file")
    tokens = path.read_text().split()
    if not tokens:
        raise MeshError(f"{path}: empty correspondence file")
    try:
        one_based = np.array([int(float(t)) for t in tokens], dtype=np.int64)
    except ValueError as error:
        raise MeshError(f"{path}: correspondence file must hold integer vertex indices ({error})") from error
    if one_based.min() < 1:
        raise MeshError(f"{path}: .vts indices are 1-based, found {int(one_based.min())}")
    if n_verts is not None and one_based.max() > n_verts:
        raise MeshError(f"{path}: index {int(one_based.max())} exceeds the mesh's {n_verts} vertices")
    return one_based - 1


def write_vts(indices: np.ndarray, path: str | os.PathLike) -> None:
    """Write 0-based vertex indices as a 1-based ``.vts`` file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, np.asarray(indices, dtype=np.int64) + 1, fmt="%d")
