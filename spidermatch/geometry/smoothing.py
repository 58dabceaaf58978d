"""Scan noise: how rough a surface is at its own resolution, and a smoothed copy for the features.

A scanner's noise is a fixed distance (a millimetre or a few), so the finer a scan is
triangulated, the larger the noise is against its edges, and the Laplacian that spectral
descriptors and DiffusionNet are built on follows the noise, not the body: FAUST_r tr_reg_071
subdivided once (20 000 vertices) with Gaussian noise of 0.2 % of its diagonal doubled the dense
map's error (0.020 to 0.041) while the same noise on the 5 000-vertex mesh cost nothing.

The roughness of a vertex is how much the normal part of its umbrella vector (the mean of
its neighbours minus itself) differs from its neighbours' own, over its mean edge. The
umbrella vector alone also measures curvature, which a coarse mesh of a curved body has
against its edges as much as a fine one has noise (a FAUST_r body decimated to 1000
vertices, an icosphere of 162); its change from vertex to vertex is noise alone: 0.026 on
FAUST_r tr_reg_070, 0.038 and 0.047 on it decimated to 1000 and 500 vertices, 0.038 on TOSCA
dog3, at most 0.061 on smooth subdivided or generated bodies, 0.17-0.27 on the noisy copies
above. A mesh whose median roughness exceeds :data:`ROUGH` gets its features on a copy
smoothed by Taubin steps (a shrinking step and an inflating one, so the body keeps its size)
until its median is down to :data:`SMOOTH`; the copy has the same vertices and faces, so the
features are the mesh's own rows. Meshes below :data:`ROUGH` are left exactly as they are.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from spidermatch.geometry.mesh import Mesh, mean_incident_edge_length, vertex_normals
from spidermatch.geometry.partial import edge_adjacency

ROUGH = 0.12
"""Median roughness above which a mesh's features are computed on a smoothed copy."""

SMOOTH = 0.05
"""Median roughness the smoothing stops at (clean bodies' level)."""

MAX_STEPS = 40
"""Taubin steps (each a shrinking and an inflating pass) at most."""

SHRINK, INFLATE = 0.5, -0.53
"""Taubin's two factors (lambda and mu)."""


def neighbour_average(mesh: Mesh) -> sp.csr_matrix:
    """Row-normalised edge graph (V, V): row i averages vertex i's neighbours."""
    adjacency = edge_adjacency(mesh)
    degree = np.asarray(adjacency.sum(axis=1)).reshape(-1)
    return sp.diags(1.0 / np.maximum(degree, 1.0)) @ adjacency


def roughness(mesh: Mesh, average: sp.csr_matrix | None = None) -> np.ndarray:
    """Each vertex's roughness (V,): its umbrella offset's change from its neighbours', over its mean edge.

    The umbrella offset is the normal part of the mean of a vertex's neighbours minus itself;
    a smooth surface, however coarse, changes it slowly from vertex to vertex, noise does not.
    ``average``: :func:`neighbour_average` of the mesh (or of one with its faces), if at hand.
    """
    average = neighbour_average(mesh) if average is None else average
    verts = mesh.verts
    offset = np.einsum("vd,vd->v", average @ verts - verts, vertex_normals(verts, mesh.faces))
    return np.abs(offset - average @ offset) / np.maximum(mean_incident_edge_length(mesh), 1e-300)


def smoothed_if_rough(mesh: Mesh) -> tuple[Mesh, int, float]:
    """``mesh`` as its features should see it, the Taubin steps taken and its median roughness before.

    A mesh at most :data:`ROUGH` rough is returned as it is (0 steps); a rougher one is smoothed
    in Taubin steps until its median roughness is at most :data:`SMOOTH` (or after
    :data:`MAX_STEPS`). The copy keeps the vertex order, faces, name and notes.
    """
    average = neighbour_average(mesh)
    before = float(np.median(roughness(mesh, average)))
    if before <= ROUGH:
        return mesh, 0, before
    verts = np.array(mesh.verts, dtype=np.float64)
    steps = 0
    while steps < MAX_STEPS:
        for factor in (SHRINK, INFLATE):
            verts += factor * (average @ verts - verts)
        steps += 1
        if steps % 2 == 0 and np.median(roughness(mesh.with_positions(verts), average)) <= SMOOTH:
            break
    return mesh.with_positions(verts), steps, before
