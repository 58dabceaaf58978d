import numpy as np
import pytest

from features.extractor import WKSExtractor, extractor_by_name
from features.wks import wave_kernel_signature
from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.geodesics import GeodesicDistances
from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.operators import (
    cache_dir,
    cached_operators,
    compute_operators,
    cotangent_laplacian,
    lumped_mass,
)
from tests.conftest import icosphere, random_rotation


def test_laplacian_symmetric_zero_rows_mass_is_area():
    mesh = make_creature(800, seed=3).mesh
    laplacian = cotangent_laplacian(mesh.verts, mesh.faces)
    assert abs(laplacian - laplacian.T).max() < 1e-12
    np.testing.assert_allclose(np.asarray(laplacian.sum(axis=1)).ravel(), 0.0, atol=1e-10)
    mass = lumped_mass(mesh.verts, mesh.faces)
    assert (mass > 0).all()
    np.testing.assert_allclose(mass.sum(), mesh.area, rtol=1e-12)


def test_sphere_spectrum_multiplicities():
    ops = compute_operators(icosphere(3), k=16)
    evals = ops.evals
    assert abs(evals[0]) < 1e-8
    # unit sphere: eigenvalue l(l+1) with multiplicity 2l+1 -> 1, 3, 5, 7
    for l, block in ((1, slice(1, 4)), (2, slice(4, 9)), (3, slice(9, 16))):
        np.testing.assert_allclose(evals[block], l * (l + 1), rtol=0.03)
    gaps = np.diff(evals)
    assert gaps[3] > 1.0 and gaps[8] > 1.0  # clusters are separated
    assert np.ptp(evals[1:4]) < 0.05 and np.ptp(evals[4:9]) < 0.1


def test_eigenvectors_mass_orthonormal():
    ops = compute_operators(make_creature(600, seed=1).mesh, k=20)
    gram = ops.evecs.T @ (ops.mass[:, None] * ops.evecs)
    np.testing.assert_allclose(gram, np.eye(20), atol=1e-8)


def test_operator_cache_round_trip_and_corruption(tmp_path, monkeypatch):
    monkeypatch.setenv("SPIDERMATCH_CACHE_DIR", str(tmp_path))
    mesh = make_creature(500, seed=2).mesh
    first = cached_operators(mesh, k=10, gradients=True)
    files = list(cache_dir().glob("*.npz"))
    assert len(files) == 1
    again = cached_operators(mesh, k=10, gradients=True)
    np.testing.assert_array_equal(first.evecs, again.evecs)
    assert abs(first.grad_x - again.grad_x).max() == 0
    files[0].write_bytes(b"not an npz")
    recomputed = cached_operators(mesh, k=10, gradients=True)
    np.testing.assert_allclose(np.abs(recomputed.evecs), np.abs(first.evecs), atol=1e-8)
    cached_operators(mesh, k=12)
    assert len(list(cache_dir().glob("*.npz"))) == 2  # parameters are part of the key


def test_gradient_of_linear_function_is_exact_on_sphere():
    mesh = icosphere(3)
    ops = compute_operators(mesh, k=4, gradients=True)
    f = mesh.verts[:, 0]
    grad = np.stack([ops.grad_x @ f, ops.grad_y @ f], axis=1)
    tangent_true = np.stack(
        [ops.frames[:, 0, 0], ops.frames[:, 1, 0]], axis=1
    )  # e1.x, e2.x = projection of the x axis
    np.testing.assert_allclose(grad, tangent_true, atol=0.05)


def test_wks_invariant_to_rigid_motion_and_vertex_order(rng):
    mesh = make_creature(900, seed=4).mesh
    wks = wave_kernel_signature(*_eig(mesh), n_descr=64)
    assert wks.shape == (mesh.n_verts, 64)
    np.testing.assert_allclose(np.linalg.norm(wks, axis=1), 1.0)
    perm = rng.permutation(mesh.n_verts)
    inverse = np.argsort(perm)
    moved = Mesh(mesh.verts[perm] @ random_rotation(rng).T + [3.0, -1.0, 2.0], inverse[mesh.faces])
    wks_moved = wave_kernel_signature(*_eig(moved), n_descr=64)
    np.testing.assert_allclose(wks_moved, wks[perm], atol=1e-6)


def _eig(mesh):
    ops = compute_operators(mesh, k=40)
    return ops.evals, ops.evecs


def test_geodesics_on_sphere_match_great_circles(rng):
    sphere = icosphere(4)
    solver = GeodesicDistances(sphere)
    sources = rng.choice(sphere.n_verts, size=5, replace=False)
    distances = solver.from_vertices(sources)
    unit = sphere.verts / np.linalg.norm(sphere.verts, axis=1, keepdims=True)
    exact = np.arccos(np.clip(unit[sources] @ unit.T, -1, 1))
    assert np.all(distances[np.arange(5), sources] == 0)
    # heat method on a 2562-vertex icosphere: mean error under 2 %, worst under 6 % of pi
    assert np.mean(np.abs(distances - exact)) < 0.02 * np.pi
    assert np.max(np.abs(distances - exact)) < 0.06 * np.pi


def test_extractor_by_name_builds_wks_and_names_what_is_missing():
    assert isinstance(extractor_by_name("wks"), WKSExtractor)
    with pytest.raises(ValueError, match="checkpoint"):
        extractor_by_name("learned")
    with pytest.raises(ValueError, match="unknown features 'shot'"):
        extractor_by_name("shot")
