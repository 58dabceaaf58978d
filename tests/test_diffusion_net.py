"""DiffusionNet layers, functional maps and the learned extractor on tiny synthetic meshes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from features.diffusion_net import (
    DiffusionNet,
    LearnedTimeDiffusion,
    ModelConfig,
    SpatialGradientFeatures,
    TorchOperators,
    prepare_shape,
)
from features.fmap import regularised_fmap, resolvent_mask, soft_point_map
from features.learned import CheckpointError, LearnedExtractor, read_checkpoint
from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.operators import compute_operators

SMALL = ModelConfig(in_channels=16, out_channels=8, width=16, n_blocks=2, n_eig=30)


pytestmark = pytest.mark.usefixtures("isolated_torch")


@pytest.fixture(scope="module")
def creature() -> Mesh:
    return make_creature(n_verts=300, seed=3).mesh


def _network(config: ModelConfig = SMALL, seed: int = 0) -> DiffusionNet:
    torch.manual_seed(seed)
    network = DiffusionNet.from_config(config)
    with torch.no_grad():  # non-trivial diffusion times, as after training
        for block in network.blocks:
            block.diffusion.diffusion_time.uniform_(1e-4, 1e-2)
    return network.eval()


def test_output_shape(creature):
    shape = prepare_shape(creature, SMALL, use_cache=False)
    out = _network()(shape.features, shape.ops)
    assert shape.features.shape == (creature.n_verts, 16)
    assert out.shape == (creature.n_verts, 8)
    assert torch.isfinite(out).all()


def test_invariant_to_rigid_motion(creature):
    rotation = Rotation.random(random_state=7).as_matrix()
    moved = Mesh(creature.verts @ rotation.T + np.array([0.3, -2.0, 5.0]), creature.faces, "moved")
    network = _network()
    with torch.no_grad():
        outs = [
            network(s.features, s.ops)
            for s in (prepare_shape(m, SMALL, use_cache=False) for m in (creature, moved))
        ]
    assert torch.allclose(outs[0], outs[1], atol=1e-4, rtol=0)


def test_invariant_to_uniform_scale(creature):
    scaled = Mesh(creature.verts * 3.0, creature.faces, "scaled")
    network = _network()
    with torch.no_grad():
        outs = [
            network(s.features, s.ops)
            for s in (prepare_shape(m, SMALL, use_cache=False) for m in (creature, scaled))
        ]
    assert torch.allclose(outs[0], outs[1], atol=1e-4, rtol=0)


def test_channel_mismatch_names_expected_and_actual(creature):
    shape = prepare_shape(creature, SMALL, use_cache=False)
    with pytest.raises(ValueError, match="expected 16 channels, got 15"):
        _network()(shape.features[:, :15], shape.ops)
    with pytest.raises(ValueError, match="300|vertices"):
        _network()(shape.features[:-1], shape.ops)
    with pytest.raises(ValueError, match="expected 4 channels, got 16"):
        LearnedTimeDiffusion(4)(shape.features, shape.ops)


def test_operators_need_gradients(creature):
    ops = compute_operators(creature, k=10, gradients=False)
    with pytest.raises(ValueError, match="gradient"):
        TorchOperators.from_operators(ops, creature.area)
    with pytest.raises(ValueError, match="area"):
        TorchOperators.from_operators(compute_operators(creature, k=10, gradients=True), 0.0)


@pytest.mark.parametrize(
    "bad",
    [
        dict(input="normals"),
        dict(input="xyz", in_channels=16),
        dict(input="wks_xyz", in_channels=3),
        dict(width=0),
        dict(dropout=1.0),
    ],
)
def test_model_config_rejects_bad_values(bad):
    with pytest.raises(ValueError):
        ModelConfig(**bad)


def test_wks_xyz_input_is_wks_beside_coordinates(creature):
    """wks_xyz = the WKS input of the same dimension, then the centred unit-area coordinates."""
    both = prepare_shape(creature, ModelConfig(input="wks_xyz", in_channels=19, n_eig=30), use_cache=False)
    wks = prepare_shape(creature, ModelConfig(input="wks", in_channels=16, n_eig=30), use_cache=False)
    xyz = prepare_shape(creature, ModelConfig(input="xyz", in_channels=3, n_eig=30), use_cache=False)
    assert both.features.shape == (creature.n_verts, 19)
    assert torch.allclose(both.features[:, :16], wks.features)
    assert torch.allclose(both.features[:, 16:], xyz.features)
    mirrored = Mesh(creature.verts * np.array([-1.0, 1.0, 1.0]), creature.faces[:, ::-1], "mirrored")
    flipped = prepare_shape(mirrored, ModelConfig(input="wks_xyz", in_channels=19, n_eig=30), use_cache=False)
    assert torch.allclose(flipped.features[:, :16], both.features[:, :16], atol=1e-5)  # WKS: same
    assert torch.allclose(flipped.features[:, 16], -both.features[:, 16], atol=1e-6)  # x tells sides


def test_diffusion_keeps_constants_and_mass(creature):
    shape = prepare_shape(creature, SMALL, use_cache=False)
    diffusion = LearnedTimeDiffusion(2)
    with torch.no_grad():
        diffusion.diffusion_time.fill_(0.05)
        x = torch.stack([torch.ones(creature.n_verts), torch.randn(creature.n_verts)], 1)
        out = diffusion(x, shape.ops)
    assert torch.allclose(out[:, 0], torch.ones(creature.n_verts), atol=1e-4)
    mass = shape.ops.mass
    # the constant mode is untouched, so the mass-weighted mean of the projection is kept
    projected = shape.ops.evecs @ (shape.ops.evecs_trans @ x[:, 1])
    assert torch.allclose(mass @ out[:, 1], mass @ projected, atol=1e-4)


def test_gradient_features_ignore_tangent_frame_rotation():
    torch.manual_seed(0)
    layer = SpatialGradientFeatures(5)
    gx, gy = torch.randn(40, 5), torch.randn(40, 5)
    angle = torch.rand(40, 1) * 6.28
    rx = torch.cos(angle) * gx - torch.sin(angle) * gy
    ry = torch.sin(angle) * gx + torch.cos(angle) * gy
    assert torch.allclose(layer(gx, gy), layer(rx, ry), atol=1e-5)


def test_regularised_fmap_matches_row_by_row_solve():
    gen = torch.Generator().manual_seed(0)
    a, b = (
        torch.randn(6, 20, generator=gen, dtype=torch.float64),
        torch.randn(5, 20, generator=gen, dtype=torch.float64),
    )
    mask = torch.rand(5, 6, generator=gen, dtype=torch.float64)
    c = regularised_fmap(a, b, mask, 2.0)
    for i in range(5):
        row = torch.linalg.solve(a @ a.T + 2.0 * torch.diag(mask[i]), a @ b[i])
        assert torch.allclose(c[i], row)
    least_squares = torch.linalg.lstsq(a.T, b.T).solution.T
    assert torch.allclose(regularised_fmap(a, b, torch.zeros(5, 6, dtype=torch.float64), 0.0), least_squares)


def test_resolvent_mask_and_soft_map():
    evals = torch.tensor([0.0, 1.0, 4.0, 9.0])
    mask = resolvent_mask(evals, evals)
    assert mask.shape == (4, 4)
    assert torch.allclose(torch.diagonal(mask), torch.zeros(4))
    assert (mask >= 0).all() and mask[0, 3] > mask[0, 1]
    p = soft_point_map(torch.randn(7, 3), torch.randn(9, 3), 0.07)
    assert p.shape == (7, 9) and torch.allclose(p.sum(1), torch.ones(7))
    with pytest.raises(ValueError, match="channels"):
        regularised_fmap(torch.randn(4, 3), torch.randn(4, 2), mask, 1.0)


def _save_checkpoint(path, model: ModelConfig = SMALL, **changes):
    from train.config import TrainConfig
    from train.loop import new_state, save_checkpoint
    from train.losses import LossConfig

    train_config = TrainConfig(model=model, loss=LossConfig(n_fmap=20))
    state = new_state(train_config)
    save_checkpoint(path, state, train_config)
    data = torch.load(path, weights_only=True)
    data.update(changes)
    torch.save(data, path)
    return state


def test_learned_extractor_features(tmp_path, creature):
    _save_checkpoint(tmp_path / "a.pt")
    extractor = LearnedExtractor(str(tmp_path / "a.pt"), n_eig=30)
    assert LearnedExtractor(str(tmp_path / "a.pt")).n_eig == 30  # by default, the checkpoint's
    features = extractor(creature)
    assert extractor.name == "learned"
    assert features.shape == (creature.n_verts, 8)
    assert np.allclose(np.linalg.norm(features, axis=1), 1.0)


def test_a_large_mesh_is_announced_before_its_learned_features(tmp_path, creature, monkeypatch, caplog):
    import features.learned as learned

    _save_checkpoint(tmp_path / "a.pt")
    extractor = LearnedExtractor(str(tmp_path / "a.pt"), n_eig=30, use_cache=False)
    with caplog.at_level("INFO", logger="features.learned"):
        extractor(creature)
        assert "learned features of its" not in caplog.text  # a small mesh: nothing to wait for
        monkeypatch.setattr(learned, "ANNOUNCED_VERTICES", creature.n_verts)
        extractor(creature)
    assert f"learned features of its {creature.n_verts} vertices" in caplog.text


def test_learned_extractor_adaptation_leaves_network_unchanged(tmp_path, creature):
    _save_checkpoint(tmp_path / "a.pt")
    other = make_creature(n_verts=300, seed=4).mesh
    extractor = LearnedExtractor(str(tmp_path / "a.pt"), n_eig=30, adapt_steps=2)
    before = {k: v.clone() for k, v in extractor.network.state_dict().items()}
    fx, fy = extractor.pair_features(creature, other)
    assert fx.shape == (creature.n_verts, 8) and fy.shape == (other.n_verts, 8)
    assert not np.allclose(fx, extractor(creature))
    assert all(torch.equal(before[k], v) for k, v in extractor.network.state_dict().items())


def test_learned_extractor_bad_checkpoints(tmp_path):
    with pytest.raises(CheckpointError, match="missing.pt: no such checkpoint"):
        LearnedExtractor(str(tmp_path / "missing.pt"))
    (tmp_path / "corrupt.pt").write_bytes(b"not a checkpoint at all")
    with pytest.raises(CheckpointError, match="corrupt.pt: corrupt"):
        LearnedExtractor(str(tmp_path / "corrupt.pt"))
    torch.save({"weights": 1}, tmp_path / "foreign.pt")
    with pytest.raises(CheckpointError, match="not a spidermatch training checkpoint"):
        read_checkpoint(tmp_path / "foreign.pt")
    _save_checkpoint(tmp_path / "ok.pt")
    with pytest.raises(CheckpointError, match="n_eig = 30.*n_eig = 128"):
        LearnedExtractor(str(tmp_path / "ok.pt"), n_eig=128)
    good = torch.load(tmp_path / "ok.pt", weights_only=True)
    _save_checkpoint(
        tmp_path / "unknown.pt", config={**good["config"], "model": {**good["config"]["model"], "depth": 3}}
    )
    with pytest.raises(CheckpointError, match="unknown.pt: incompatible model config"):
        LearnedExtractor(str(tmp_path / "unknown.pt"), n_eig=30)
    _save_checkpoint(
        tmp_path / "wide.pt", config={**good["config"], "model": {**good["config"]["model"], "width": 32}}
    )
    with pytest.raises(CheckpointError, match="wide.pt: network weights do not match"):
        LearnedExtractor(str(tmp_path / "wide.pt"), n_eig=30)
    _save_checkpoint(tmp_path / "future.pt", version=99)
    with pytest.raises(CheckpointError, match="version 99"):
        LearnedExtractor(str(tmp_path / "future.pt"), n_eig=30)
