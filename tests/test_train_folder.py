"""Training on a user's folder of meshes: no labels, no split file, label-free validation, bad folders."""

from __future__ import annotations

import math

import pytest
import torch

from features.diffusion_net import ModelConfig
from spidermatch.data.datasets import DatasetError, SyntheticShapes
from spidermatch.geometry.io import save_mesh
from train.config import DataConfig, OptimConfig, RunConfig, TrainConfig
from train.data import prepare_train_shape, validation_pairs
from train.loop import new_state, random_rotation, train, train_step
from train.losses import LossConfig
from train.report import read_rows, write_figure
from train.validation import LossValidator

pytestmark = pytest.mark.usefixtures("isolated_torch")


def folder_config(root, **run) -> TrainConfig:
    return TrainConfig(
        seed=1,
        model=ModelConfig(in_channels=8, out_channels=16, width=16, n_blocks=1, n_eig=24),
        loss=LossConfig(n_fmap=8),  # fewer eigenpairs than channels: C can be full rank
        optim=OptimConfig(lr=5e-3),
        data=DataConfig(root=str(root), target_faces=None, use_cache=False, val_points=30),
        run=RunConfig(**{"n_steps": 3, "val_every": 2, "checkpoint_every": 100, "progress": False, **run}),
    )


def write_meshes(folder, counts: list[int], suffixes=(".off", ".ply", ".obj")) -> list[str]:
    """Creatures with the given vertex counts, straight into ``folder`` (no off/, no corres/)."""
    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for i, count in enumerate(counts):
        shape = SyntheticShapes(n_shapes=1, n_verts=count, seed=i).load(f"creature_{i:03d}")
        save_mesh(shape.mesh, folder / f"{shape.name}{suffixes[i % len(suffixes)]}")
        names.append(shape.name)
    return names


def test_a_folder_without_labels_trains_end_to_end(tmp_path):
    names = write_meshes(tmp_path / "mine", [200, 260, 230, 300])  # mixed vertex counts are fine
    result = train(folder_config(tmp_path / "mine"), tmp_path / "run")
    assert result.step == 3 and result.criterion == "val_unsup"
    assert math.isfinite(result.best_val) and result.best_val > 0
    assert (tmp_path / "run" / "best.pt").is_file() and (tmp_path / "run" / "last.pt").is_file()
    rows = read_rows(tmp_path / "run" / "validation.csv")
    assert [row["step"] for row in rows] == ["2", "3"]
    assert all(row["val_error"] == "nan" and float(row["val_unsup"]) > 0 for row in rows)
    losses = read_rows(tmp_path / "run" / "losses.csv")
    assert [row["step"] for row in losses] == ["1", "2", "3"]
    assert all(float(row["bij"]) >= 0 and float(row["couple"]) >= 0 and row["sup"] == "" for row in losses)
    assert write_figure(tmp_path / "run").stat().st_size > 0
    checkpoint = torch.load(tmp_path / "run" / "best.pt", weights_only=True)
    assert checkpoint["metrics"]["best_val"] == pytest.approx(result.best_val)
    assert sorted(names) == names  # the automatic split held out creature_001 and creature_003
    assert validation_pairs(["creature_001", "creature_003"], [], "all") == [
        ("creature_001", "creature_003"),
        ("creature_003", "creature_001"),
    ]


def test_label_free_figure_decreases_when_training_on_the_pair():
    config = folder_config(None)
    config.optim.lr = 1e-3
    dataset = SyntheticShapes(n_shapes=2, n_verts=250, seed=4)
    shapes = [prepare_train_shape(dataset.load(name), config.model, config.data) for name in dataset.names]
    validator = LossValidator(shapes, [(0, 1), (1, 0)], config.loss)
    state = new_state(config)
    figures = [validator(state.network)["val_unsup"]]
    for _ in range(2):
        for _ in range(4):
            train_step(state, shapes, config)
        figures.append(validator(state.network)["val_unsup"])
    assert figures[2] < figures[1] < 0.8 * figures[0]


def test_bad_folders_are_refused_naming_the_problem(tmp_path):
    write_meshes(tmp_path / "one", [200])
    with pytest.raises(DatasetError, match=r"one: training needs at least 2 shapes, found 1 \(creature_0"):
        train(folder_config(tmp_path / "one"), tmp_path / "run1")
    write_meshes(tmp_path / "broken", [200, 220, 240])
    (tmp_path / "broken" / "zz_bad.off").write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n")
    listing = "1 of 4 shapes cannot be used:\n  .*zz_bad.off: the header promises"
    with pytest.raises(DatasetError, match=listing):
        train(folder_config(tmp_path / "broken"), tmp_path / "run2")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="empty: no mesh files"):
        train(folder_config(tmp_path / "empty"), tmp_path / "run3")


def test_a_shape_too_small_for_the_loss_is_refused_before_training_naming_its_file(tmp_path):
    """A tetrahedron in the folder passed the preparation and ended the run at whichever later step
    first drew it ("n_fmap = 8 eigenpairs requested but the shapes have 24 and 4"), naming no file."""
    write_meshes(tmp_path / "mine", [200, 220, 240])
    (tmp_path / "mine" / "aa_tiny.off").write_text(
        "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n"
    )
    with pytest.raises(
        DatasetError, match=r"aa_tiny.off: 4 vertices .* give 4 eigenpairs, fewer .*n_fmap = 8"
    ):
        train(folder_config(tmp_path / "mine"), tmp_path / "run")
    assert not (tmp_path / "run" / "last.pt").exists()
    (tmp_path / "mine" / "aa_tiny.off").rename(tmp_path / "mine" / "creature_002b.off")  # now held out
    with pytest.raises(DatasetError, match=r"creature_002b.off: 4 vertices .* give 4 eigenpairs"):
        train(folder_config(tmp_path / "mine"), tmp_path / "run")


def test_class_pairs_and_rotations():
    pairs = validation_pairs(["cat1", "dog0"], ["cat0", "cat2", "dog1", "horse0"], "class")
    assert ("cat1", "cat0") in pairs and ("cat2", "cat1") in pairs and ("dog1", "dog0") in pairs
    assert not any("horse0" in pair for pair in pairs) and ("cat1", "dog0") not in pairs
    assert len(pairs) == 2 * (2 + 1)
    generator = torch.Generator().manual_seed(0)
    for mode in ("y", "all"):
        rotation = random_rotation(mode, generator)
        torch.testing.assert_close(rotation @ rotation.T, torch.eye(3), atol=1e-5, rtol=0)
        assert torch.linalg.det(rotation) == pytest.approx(1.0, abs=1e-5)
    assert random_rotation("y", generator)[1].tolist() == [0.0, 1.0, 0.0]


def test_class_validation_on_a_labelled_folder(tmp_path):
    from spidermatch.geometry.io import write_vts

    root = tmp_path / "animals"
    for i, name in enumerate(["a0", "a1", "a2", "b0", "b1", "b2"]):
        shape = SyntheticShapes(n_shapes=1, n_verts=200 + 10 * i, seed=i, n_refs=60).load(f"creature_{i:03d}")
        save_mesh(shape.mesh, root / "off" / f"{name}.off")
        write_vts(shape.corr, root / "corres" / f"{name}.vts")
    config = folder_config(root, n_steps=2, val_every=2)
    config.data.val, config.data.val_pairs, config.data.label_free_pairs = ["a1", "b1"], "class", 3
    result = train(config, tmp_path / "run")
    assert result.criterion == "val_error" and 0 < result.best_val < 1
    row = read_rows(tmp_path / "run" / "validation.csv")[0]
    assert float(row["wks_error"]) > 0 and float(row["val_unsup"]) > 0
    log = (tmp_path / "run" / "losses.csv").read_text()
    assert log.count("\n") == 3
