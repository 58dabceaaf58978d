import numpy as np
import pytest
import trimesh
from hydra import compose, initialize_config_module

from spidermatch.geometry.mesh import Mesh


def composed(config_name: str, overrides: list[str]):
    """The Hydra config ``conf/<config_name>.yaml`` with ``overrides``, as the command line composes it."""
    with initialize_config_module(config_module="conf", version_base="1.3"):
        return compose(config_name=config_name, overrides=overrides)


def result_of(folder) -> dict:
    """A run folder's ``result.json``."""
    import json
    from pathlib import Path

    return json.loads((Path(folder) / "result.json").read_text())


@pytest.fixture(autouse=True)
def _private_cache(tmp_path_factory, monkeypatch):
    """Every test session writes operator caches to its own folder, never ~/.cache."""
    monkeypatch.setenv("SPIDERMATCH_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "cache"))


@pytest.fixture
def isolated_torch(tmp_path, monkeypatch):
    """A private operator cache per test and one torch thread (tiny tensors; the CPU is shared)."""
    import torch

    monkeypatch.setenv("SPIDERMATCH_CACHE_DIR", str(tmp_path / "cache"))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def icosphere(subdivisions: int = 3, radius: float = 1.0) -> Mesh:
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return Mesh(np.asarray(sphere.vertices), np.asarray(sphere.faces), f"icosphere({subdivisions})")


def random_rotation(rng) -> np.ndarray:
    from spidermatch.data.synthetic import random_rotation as rotation

    return rotation(rng)


TINY_TRAINING = [
    "data.synthetic_shapes=4",
    "data.synthetic_verts=300",
    "data.val_points=30",
    "model.width=8",
    "model.n_blocks=1",
    "model.out_channels=16",
    "loss.n_fmap=12",
]
"""Overrides of a training run that takes seconds (synthetic shapes, a tiny network)."""


@pytest.fixture(scope="session")
def tiny_checkpoint(tmp_path_factory):
    import train.cli  # noqa: F401  (registers the training schema)
    from train.cli import to_train_config
    from train.loop import train

    overrides = [
        *TINY_TRAINING,
        "run.n_steps=2",
        "run.val_every=2",
        "run.progress=false",
    ]
    with initialize_config_module(config_module="conf", version_base="1.3"):
        cfg = compose(config_name="train", overrides=overrides)
    folder = tmp_path_factory.mktemp("train")
    train(to_train_config(cfg), folder)
    return folder / "best.pt"


def judged_suspect_once(monkeypatch, module) -> list:
    """``module.needs_second_opinion`` says yes to the first map only (a plausible map asked anyway);
    the maps it was asked about."""
    calls = []

    def once(result):
        calls.append(result)
        return len(calls) == 1

    monkeypatch.setattr(module, "needs_second_opinion", once)
    return calls
