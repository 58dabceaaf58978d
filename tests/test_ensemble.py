"""Several trained networks joined: their similarities averaged, every feature interface kept."""

import numpy as np
import pytest
import torch
from conftest import TINY_TRAINING, composed

from features.learned import EnsembleExtractor, LearnedExtractor
from features.orientation import Orientation
from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.partial import plane_cut


@pytest.fixture(scope="module")
def second_checkpoint(tmp_path_factory):
    """A tiny network trained like ``tiny_checkpoint`` but from another seed."""
    import train.cli  # noqa: F401  (registers the training schema)
    from train.cli import to_train_config
    from train.loop import train

    overrides = [*TINY_TRAINING, "run.n_steps=2", "run.val_every=2", "run.progress=false", "seed=1"]
    cfg = composed("train", overrides)
    folder = tmp_path_factory.mktemp("train_seed1")
    train(to_train_config(cfg), folder)
    return folder / "best.pt"


@pytest.fixture(scope="module")
def creatures():
    return make_creature(n_verts=400, seed=0).mesh, make_creature(n_verts=450, seed=1).mesh


def test_the_ensemble_averages_its_members_similarities(tiny_checkpoint, second_checkpoint, creatures):
    mesh_x, mesh_y = creatures
    members = [LearnedExtractor(path) for path in (tiny_checkpoint, second_checkpoint)]
    ensemble = EnsembleExtractor([tiny_checkpoint, second_checkpoint])
    joined_x, joined_y = ensemble.pair_features(mesh_x, mesh_y)
    alone = [member.pair_features(mesh_x, mesh_y) for member in members]
    assert joined_x.shape == (mesh_x.n_verts, sum(x.shape[1] for x, _ in alone))
    assert np.allclose(np.linalg.norm(joined_x, axis=1), 1.0)
    mean_similarity = np.mean([x @ y.T for x, y in alone], axis=0)
    assert np.allclose(joined_x @ joined_y.T, mean_similarity)
    assert not np.allclose(*(x @ y.T for x, y in alone))  # two different networks, not one twice
    assert np.allclose(ensemble(mesh_x), joined_x)


def test_a_part_gets_every_members_search_and_the_choices_are_reported_per_network(
    tiny_checkpoint, second_checkpoint, creatures
):
    whole = creatures[0]
    part = plane_cut(whole, np.array([0.0, 1.0, 0.0]), 0.5, "half").mesh
    ensemble = EnsembleExtractor([tiny_checkpoint, second_checkpoint])
    feat_part, feat_whole = ensemble.part_features(part, whole)
    assert feat_part.shape[0] == part.n_verts and feat_whole.shape[0] == whole.n_verts
    assert np.allclose(np.linalg.norm(feat_part, axis=1), 1.0)
    for number, member in enumerate(ensemble.members):  # as a search over coordinates records them
        member.orientations["half"] = Orientation(torch.eye(3, dtype=torch.float64), 90.0 * number)
    named = dict(ensemble.orientations.items())
    assert set(named) == {"half (network 1)", "half (network 2)"}
    assert named["half (network 2)"].degrees == 90.0
    assert ensemble.orientations.get("half") is named["half (network 1)"]
    ensemble.orientations.clear()
    assert len(ensemble.orientations) == 0 and not ensemble.members[1].orientations


def test_an_ensemble_of_one_is_refused(tiny_checkpoint):
    with pytest.raises(ValueError, match="at least two checkpoints, got 1"):
        EnsembleExtractor([tiny_checkpoint])


def test_a_parts_presentations_start_with_the_one_part_features_gives(
    tiny_checkpoint, second_checkpoint, creatures
):
    """``part_feature_options`` (for bench_presentations.py): its first option is ``part_features``'s."""
    from spidermatch.feature_transfer import part_feature_options

    whole = creatures[0]
    part = plane_cut(whole, np.array([0.0, 1.0, 0.0]), 0.5, "half").mesh
    for extractor in (
        LearnedExtractor(tiny_checkpoint),
        EnsembleExtractor([tiny_checkpoint, second_checkpoint]),
    ):
        options, feat_whole = part_feature_options(extractor, part, whole, 3)
        feat_part, expected_whole = extractor.part_features(part.centred(), whole.centred())
        assert 1 <= len(options) <= 3 and all(features.shape == feat_part.shape for _, features in options)
        assert np.allclose(options[0][1], feat_part) and np.allclose(feat_whole, expected_whole)
