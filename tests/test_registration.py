import numpy as np

from spidermatch.data.synthetic import make_creature
from spidermatch.dense.registration import arap_system, best_rotations, fit


def _turn(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_a_rigidly_moved_copy_is_fitted_exactly():
    """Goals on a turned and moved copy: the rigid motion has zero energy, so the fit goes there."""
    mesh = make_creature(800, seed=5).mesh
    moved = mesh.verts @ _turn(0.7).T + np.array([0.3, -0.2, 0.5])
    start = moved + np.random.default_rng(1).normal(scale=0.01 * np.ptp(mesh.verts), size=moved.shape)
    system = arap_system(mesh.verts, mesh.faces, np.full(mesh.n_verts, 0.1))
    fitted = fit(system, moved, start, rounds=30)
    assert np.abs(fitted - moved).max() < 1e-3 * np.ptp(mesh.verts)


def test_rotations_of_a_turned_copy_are_the_turn():
    mesh = make_creature(400, seed=6).mesh
    turn = _turn(-1.1)
    system = arap_system(mesh.verts, mesh.faces, np.ones(mesh.n_verts))
    unturned = np.broadcast_to(np.eye(3), (mesh.n_verts, 3, 3))  # the prior pulls the other way
    off = np.abs(best_rotations(system, mesh.verts @ turn.T, unturned) - turn).max(axis=(1, 2))
    assert np.median(off) < 5e-3 and np.mean(off < 1e-2) > 0.95
    assert np.allclose(
        best_rotations(system, mesh.verts @ turn.T, np.broadcast_to(turn, unturned.shape)), turn
    )


def test_the_fit_turns_with_its_goals_even_from_a_collapsed_start():
    """Goals and start turned: the fit is the turned fit, also where the start has collapsed rings."""
    rng = np.random.default_rng(2)
    mesh = make_creature(900, seed=8).mesh
    goals = mesh.verts + rng.normal(scale=0.05, size=mesh.verts.shape)
    start = np.round(goals / 0.2) * 0.2  # many vertices on one point: rings without a rotation
    system = arap_system(mesh.verts, mesh.faces, np.full(mesh.n_verts, 0.1))
    turn = _turn(0.9) @ np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    plain = fit(system, goals, start, rounds=5)
    turned = fit(system, goals @ turn.T, start @ turn.T, rounds=5)
    np.testing.assert_allclose(turned, plain @ turn.T, atol=1e-8)


def test_the_fit_keeps_the_shape_where_goals_are_noisy():
    """Noisy goals around a moved copy: the fit lands nearer the copy than the goals (noise averages out)."""
    rng = np.random.default_rng(0)
    mesh = make_creature(1500, seed=7).mesh
    moved = mesh.verts @ _turn(0.3).T
    scale = 0.02 * np.sqrt(mesh.area)
    goals = moved + rng.normal(scale=scale, size=moved.shape)
    system = arap_system(mesh.verts, mesh.faces, np.full(mesh.n_verts, 0.1))
    fitted = fit(system, goals, goals, rounds=10)
    assert np.linalg.norm(fitted - moved, axis=1).mean() < 0.3 * np.linalg.norm(goals - moved, axis=1).mean()
