"""Scan noise: features of a rough mesh come from a smoothed copy of the same vertices."""

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from spidermatch.data.synthetic import make_creature
from spidermatch.feature_transfer import mesh_features
from spidermatch.geometry.descriptors import WKSExtractor
from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.smoothing import ROUGH, SMOOTH, roughness, smoothed_if_rough


@pytest.fixture(scope="module")
def body() -> Mesh:
    return make_creature(n_verts=800, seed=3).mesh


@pytest.fixture(scope="module")
def fine(body) -> Mesh:
    """``body`` subdivided at its edges' midpoints (its own vertices first), as a finer scan."""
    verts, faces = trimesh.remesh.subdivide(body.verts, body.faces)
    return Mesh(verts, faces, "fine")


def noisy(mesh: Mesh, share_of_edge: float) -> Mesh:
    """``mesh`` with Gaussian noise of ``share_of_edge`` mean edges in every direction (seeded)."""
    edge = np.linalg.norm(mesh.verts[mesh.faces[:, 0]] - mesh.verts[mesh.faces[:, 1]], axis=1).mean()
    moved = mesh.verts + np.random.default_rng(0).normal(scale=share_of_edge * edge, size=mesh.verts.shape)
    return Mesh(moved, mesh.faces, "noisy.ply")


def test_roughness_tells_scan_noise_from_the_shape(fine):
    assert np.median(roughness(fine)) < SMOOTH
    assert np.median(roughness(noisy(fine, 0.4))) > ROUGH


def test_a_smooth_mesh_is_shown_to_the_extractor_as_it_is(fine):
    shown, steps, _ = smoothed_if_rough(fine)
    assert shown is fine and steps == 0


@pytest.mark.parametrize("subdivisions", [1, 2])
def test_a_coarse_mesh_of_a_curved_surface_is_not_taken_for_noise(subdivisions):
    """An icosphere of 42 or 162 vertices: its umbrella vectors are as long against its edges as
    noise makes them on a fine scan (curvature), but they change smoothly from vertex to vertex.
    The first measure (the umbrella vectors alone) smoothed it in 40 steps."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    coarse = Mesh(sphere.vertices, sphere.faces, "sphere")
    shown, steps, rough = smoothed_if_rough(coarse)
    assert shown is coarse and steps == 0 and rough < SMOOTH


def test_a_noisy_mesh_is_smoothed_keeping_its_vertices(fine):
    scan = noisy(fine, 0.4)
    shown, steps, before = smoothed_if_rough(scan)
    assert before > ROUGH and steps > 0
    assert np.array_equal(shown.faces, scan.faces) and shown.name == scan.name
    assert np.median(roughness(shown)) <= SMOOTH
    # closer to the surface the noise was added to, and as large (Taubin steps do not shrink it)
    assert (
        np.linalg.norm(shown.verts - fine.verts, axis=1).mean()
        < np.linalg.norm(scan.verts - fine.verts, axis=1).mean()
    )
    assert np.sqrt(shown.area) == pytest.approx(np.sqrt(fine.area), rel=0.05)


def test_the_features_of_a_noisy_scan_come_from_its_smoothed_copy(body, fine):
    """WKS of a fine scan with noise of 0.4 edges, matched to the clean body by nearest features:
    0.23 mean error (sqrt(area) units) on the scan itself, 0.13 on the smoothed copy."""
    extractor = WKSExtractor(n_eig=64, use_cache=False)
    body_features = extractor(body)
    scan = noisy(fine, 0.4)
    record = {}
    features = mesh_features(extractor, scan, record=record)

    def error(scan_features: np.ndarray) -> float:
        nearest = cKDTree(scan_features).query(body_features)[1]
        return float(np.linalg.norm(fine.verts[nearest] - body.verts, axis=1).mean() / np.sqrt(body.area))

    assert error(features) < 0.6 * error(extractor(scan.centred()))
    assert record["smoothed_for_features"]["noisy.ply"]["taubin_steps"] > 0
