"""Geodesic distances on a triangle mesh (heat method, factorisation reused across queries)."""

from __future__ import annotations

import logging

import numpy as np
from tqdm.auto import tqdm

from spidermatch.geometry.mesh import Mesh

logger = logging.getLogger(__name__)


class GeodesicDistances:
    """Distances from vertices of one mesh, with the heat-method factorisation built once.

    Parameters
    ----------
    mesh : Mesh
        The surface (V vertices).
    t_coef : float
        Heat-method time step factor; 1.0 is the usual choice, smaller is sharper.

    """

    def __init__(self, mesh: Mesh, t_coef: float = 1.0) -> None:
        import potpourri3d as pp3d

        self.mesh = mesh
        self._solver = pp3d.MeshHeatMethodDistanceSolver(mesh.verts, mesh.faces, t_coef=t_coef)

    def from_vertex(self, vertex: int) -> np.ndarray:
        """Distances from one vertex to all vertices, shape (V,); zero at the source."""
        distances = np.asarray(self._solver.compute_distance(int(vertex)), dtype=np.float64)
        distances[int(vertex)] = 0.0
        return np.maximum(distances, 0.0)

    def from_set(self, vertices: np.ndarray) -> np.ndarray:
        """Distance of every vertex to the nearest of ``vertices`` (S,), shape (V,); zero on them."""
        vertices = np.unique(np.asarray(vertices, dtype=np.int64).reshape(-1))
        distances = np.asarray(self._solver.compute_distance_multisource(vertices.tolist()), dtype=np.float64)
        distances[vertices] = 0.0
        return np.maximum(distances, 0.0)

    def from_vertices(self, vertices: np.ndarray, progress: bool = False) -> np.ndarray:
        """Distances from each of S vertices to all vertices.

        Parameters
        ----------
        vertices : np.ndarray, shape (S,)

        Returns
        -------
        np.ndarray, shape (S, V)

        """
        vertices = np.asarray(vertices, dtype=np.int64).reshape(-1)
        out = np.empty((vertices.size, self.mesh.n_verts))
        rows = tqdm(vertices, desc="geodesics", disable=not progress or vertices.size < 200, leave=False)
        for row, vertex in enumerate(rows):
            out[row] = self.from_vertex(vertex)
        return out

    def between(self, sources: np.ndarray, targets: np.ndarray, progress: bool = False) -> np.ndarray:
        """Distance between ``sources[i]`` and ``targets[i]`` for each i, shape (N,).

        One distance field is solved per distinct source vertex, and only the entries asked
        for are kept: memory O(N + V), not one (V,) field per source (3570 sources on a
        320 000-vertex mesh held 9 GB).
        """
        sources = np.asarray(sources, dtype=np.int64).reshape(-1)
        targets = np.asarray(targets, dtype=np.int64).reshape(-1)
        order = np.argsort(sources, kind="stable")
        starts = np.flatnonzero(np.r_[True, sources[order][1:] != sources[order][:-1]])
        groups = np.split(order, starts[1:])
        out = np.empty(sources.size)
        quiet = not progress or len(groups) < 200
        for group in tqdm(groups, desc="geodesics", disable=quiet, leave=False):
            out[group] = self.from_vertex(sources[group[0]])[targets[group]]
        return out
