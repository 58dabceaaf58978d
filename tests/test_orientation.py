"""The label-free orientation search: turned shapes are turned back, in validation and inference."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from features.diffusion_net import DiffusionNet, ModelConfig, prepare_shape
from features.learned import CheckpointError, LearnedExtractor, read_checkpoint
from features.orientation import OrientationSearch, reference_payload, turn_about_vertical
from spidermatch.data.synthetic import make_creature
from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.partial import plane_cut
from spidermatch.geometry.remesh import decimate
from train.losses import LossConfig

XYZ = ModelConfig(input="wks_xyz", in_channels=19, out_channels=8, width=16, n_blocks=2, n_eig=30)

pytestmark = pytest.mark.usefixtures("isolated_torch")


@pytest.fixture(scope="module")
def creature() -> Mesh:
    return make_creature(n_verts=300, seed=3).mesh


def turned_mesh(mesh: Mesh, degrees: float) -> Mesh:
    """``mesh`` turned by ``degrees`` about the vertical (y) axis, and moved."""
    rotation = turn_about_vertical(math.radians(degrees)).double().numpy()
    return Mesh(mesh.verts @ rotation.T + np.array([0.5, 0.0, -1.0]), mesh.faces, "turned")


def network(seed: int = 0) -> DiffusionNet:
    torch.manual_seed(seed)
    net = DiffusionNet.from_config(XYZ)
    with torch.no_grad():
        for block in net.blocks:
            block.diffusion.diffusion_time.uniform_(1e-4, 1e-2)
    return net.eval()


def test_search_turns_a_turned_shape_back(creature):
    reference = prepare_shape(creature, XYZ, use_cache=False)
    search = OrientationSearch(reference, 4, LossConfig(n_fmap=20))
    net = network()
    shapes = [reference, prepare_shape(turned_mesh(creature, 90.0), XYZ, use_cache=False)]
    (angle_same, out_same), (angle_turned, out_turned) = search.search(net, shapes)
    with torch.no_grad():
        expected = net(reference.features, reference.ops)
    assert angle_same.degrees == 0.0 and angle_turned.degrees == 270.0
    assert torch.allclose(out_same, expected, atol=1e-5)
    assert torch.allclose(out_turned, expected, atol=1e-3)  # the turned shape, turned back


def _checkpoint_with_reference(
    path, reference: Mesh | None, turns: int = 4, train_faces: int | None = None, up_axis: str | None = None
):
    from train.config import DataConfig, TrainConfig
    from train.loop import new_state, save_checkpoint

    config = TrainConfig(model=XYZ, loss=LossConfig(n_fmap=20), data=DataConfig(target_faces=train_faces))
    state = new_state(config)
    with torch.no_grad():
        for block in state.network.blocks:
            block.diffusion.diffusion_time.uniform_(1e-4, 1e-2)
    state.average = None
    if reference is not None:
        state.orientation = reference_payload(reference, turns, up_axis or "y")
        if up_axis is None:  # as checkpoints written before the up axis was stored
            del state.orientation["up_axis"]
    save_checkpoint(path, state, config)


def test_turns_are_right_handed_about_the_up_axis():
    quarter = math.radians(90.0)
    about_z = turn_about_vertical(quarter, "z")
    assert torch.allclose(about_z @ torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 1.0, 0.0]), atol=1e-6)
    assert torch.allclose(about_z @ torch.tensor([0.0, 0.0, 1.0]), torch.tensor([0.0, 0.0, 1.0]))
    about_y = turn_about_vertical(0.3, "y")  # the turn every earlier checkpoint was searched with
    expected = torch.tensor(
        [[math.cos(0.3), 0.0, math.sin(0.3)], [0.0, 1.0, 0.0], [-math.sin(0.3), 0.0, math.cos(0.3)]]
    )
    assert torch.allclose(about_y, expected)
    with pytest.raises(ValueError, match="up axis"):
        turn_about_vertical(quarter, "w")


def test_extractor_turns_about_the_up_axis_its_checkpoint_stores(tmp_path, creature):
    standing_on_z = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # carries y (up) onto z
    animal = Mesh(creature.verts @ standing_on_z.T, creature.faces, "animal")
    quarter_about_z = turn_about_vertical(math.radians(90.0), "z").double().numpy()
    turned = Mesh(animal.verts @ quarter_about_z.T, animal.faces, "turned")
    _checkpoint_with_reference(tmp_path / "z.pt", animal, up_axis="z")
    extractor = LearnedExtractor(str(tmp_path / "z.pt"), use_cache=False, orientation_frames=False)
    as_is, seen = extractor(animal), extractor(turned)
    assert extractor.turns == {"animal": 0.0, "turned": 270.0}
    assert np.abs(seen - as_is).max() < 1e-3
    _checkpoint_with_reference(tmp_path / "old.pt", animal)  # no up axis stored: y, as before
    about_y = LearnedExtractor(str(tmp_path / "old.pt"), use_cache=False, orientation_frames=False)
    assert about_y.orientation.up_axis == "y"
    assert np.abs(about_y(turned) - as_is).max() > 0.05


@pytest.mark.parametrize("train_faces", [None, 300])  # search at full resolution / on a coarser probe
def test_extractor_turns_a_turned_mesh_back(tmp_path, creature, train_faces):
    reference = (
        creature if train_faces is None else decimate(creature, train_faces).mesh
    )  # as training stores it
    _checkpoint_with_reference(tmp_path / "a.pt", reference, train_faces=train_faces)
    extractor = LearnedExtractor(str(tmp_path / "a.pt"), use_cache=False)
    as_is = extractor(creature)
    turned = extractor(turned_mesh(creature, 90.0))
    assert extractor.turns == {creature.name: 0.0, "turned": 270.0}
    assert np.abs(turned - as_is).max() < 1e-3
    without = LearnedExtractor(str(tmp_path / "a.pt"), use_cache=False, orientation_turns=0)
    assert np.abs(without(turned_mesh(creature, 90.0)) - as_is).max() > 0.05
    assert np.abs(without(creature) - as_is).max() < 1e-6


@pytest.mark.parametrize("kind", ["lying", "random"])
def test_extractor_presents_a_mesh_in_any_rotation_as_the_upright_one(tmp_path, creature, kind):
    from spidermatch.data.synthetic import random_rotation

    _checkpoint_with_reference(tmp_path / "a.pt", creature)
    rotation = (
        np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
        if kind == "lying"
        else random_rotation(np.random.default_rng(7))
    )
    rotated = Mesh(1000.0 * creature.verts @ rotation.T + 40.0, creature.faces, "rotated")
    extractor = LearnedExtractor(str(tmp_path / "a.pt"), use_cache=False)
    as_is, seen = extractor(creature), extractor(rotated)
    assert np.abs(seen - as_is).max() < 1e-3
    assert "principal axes" in extractor.orientations["rotated"].describe()
    only_turns = LearnedExtractor(str(tmp_path / "a.pt"), use_cache=False, orientation_frames=False)
    assert np.abs(only_turns(rotated) - as_is).max() > 0.05


def test_extractor_needs_a_reference_to_search(tmp_path, creature):
    _checkpoint_with_reference(tmp_path / "old.pt", None)
    assert LearnedExtractor(str(tmp_path / "old.pt"), use_cache=False).orientation is None
    with pytest.raises(CheckpointError, match="old.pt: the checkpoint has no orientation reference"):
        LearnedExtractor(str(tmp_path / "old.pt"), orientation_turns=8)


def test_training_stores_the_reference_and_validates_with_the_search(tmp_path):
    from train.config import DataConfig, RunConfig, TrainConfig
    from train.loop import train

    config = TrainConfig(
        seed=1,
        model=XYZ,
        loss=LossConfig(n_fmap=20),
        data=DataConfig(
            synthetic_shapes=4, synthetic_verts=250, val_points=30, use_cache=False, orientation_turns=4
        ),
        run=RunConfig(n_steps=2, val_every=1, progress=False),
    )
    result = train(config, tmp_path)
    stored = read_checkpoint(tmp_path / "last.pt")["orientation"]
    assert result.step == 2 and 0 <= result.best_val < 1
    assert stored["turns"] == 4 and stored["name"] == "creature_000" and stored["up_axis"] == "y"
    assert stored["verts"].shape[1] == 3 and stored["faces"].shape[1] == 3
    assert LearnedExtractor(str(tmp_path / "best.pt"), use_cache=False).orientation.turns == 4


# --- where a part lies on its whole: the placement search of best_for_part ---------------------


def test_placements_start_centred_and_cover_the_middle_of_the_whole_on_every_axis():
    from features.orientation import PLACEMENT_REACH, PLACEMENT_STEP, placement_offsets

    whole = np.array([[-0.2, -0.6, -0.1], [0.2, 0.6, 0.1]])  # a standing body's box, its unit
    offsets = placement_offsets(whole)
    assert np.all(offsets[0] == 0.0)
    for axis, half in enumerate((0.2, 0.6, 0.1)):
        values = np.unique(offsets[:, axis])
        assert values.min() == pytest.approx(-PLACEMENT_REACH * half)
        assert values.max() == pytest.approx(PLACEMENT_REACH * half)
        assert len(values) >= 3 and len(values) % 2 == 1  # at least one step either side, and the centre
        assert np.diff(values).max() <= 1.5 * PLACEMENT_STEP
    assert len(offsets) == len(np.unique(offsets, axis=0))


def test_a_placed_input_is_rotated_then_moved_and_keeps_its_other_channels():
    from features.diffusion_net import ShapeInput
    from features.orientation import Orientation, presented_input, rotated_input

    features = torch.randn(10, 5)
    shape = ShapeInput(features, None)
    turn = turn_about_vertical(math.radians(90.0))
    shown = presented_input(shape, Orientation(turn, 90.0, (0.1, -0.2, 0.3)))
    expected = rotated_input(shape, turn).features[:, -3:] + torch.tensor([0.1, -0.2, 0.3])
    torch.testing.assert_close(shown.features[:, -3:], expected)
    torch.testing.assert_close(shown.features[:, :2], features[:, :2])
    torch.testing.assert_close(
        presented_input(shape, Orientation(turn, 90.0)).features, rotated_input(shape, turn).features
    )
    assert "placed at (0.10, -0.20, 0.30)" in Orientation(turn, 90.0, (0.1, -0.2, 0.3)).describe()


class _PositionNetwork:
    """A stand-in network whose descriptors encode where a vertex is shown (random Fourier features)."""

    def __init__(self):
        self.frequencies = torch.randn(3, 64, generator=torch.Generator().manual_seed(0)) * 4.0

    def __call__(self, features, ops):
        phase = features[:, -3:].float() @ self.frequencies
        return torch.cat([phase.sin(), phase.cos()], dim=1)


def test_a_part_centred_on_itself_is_placed_where_it_lies_on_its_whole(creature):
    """Descriptors that depend on absolute position find the part's place: the upper third of a
    creature, centred on itself, is shown at (about) its true offset from the whole's centre."""
    from features.diffusion_net import ShapeInput
    from features.orientation import PLACEMENT_STEP

    whole_points = creature.verts - creature.verts.mean(axis=0)
    whole_points = whole_points / np.sqrt(creature.area)
    upper = whole_points[:, 1] > np.quantile(whole_points[:, 1], 0.66)
    part_points = whole_points[upper]
    true_offset = part_points.mean(axis=0)
    part = ShapeInput(torch.from_numpy(part_points - true_offset).float(), None)
    net = _PositionNetwork()
    whole = torch.nn.functional.normalize(net(torch.from_numpy(whole_points).float(), None), dim=-1)
    search = OrientationSearch(reference=None, turns=1, loss=None)
    chosen = search.best_for_part(net, part, whole, whole_points)
    assert chosen.degrees == 0.0
    assert np.abs(np.array(chosen.offset) - true_offset).max() <= PLACEMENT_STEP
    assert abs(chosen.offset[1] - true_offset[1]) < abs(true_offset[1])  # closer than centred on itself


def test_the_ranked_presentations_of_a_part_start_with_the_best_one(creature):
    """``ranked_for_part`` gives one presentation per placed orientation, best first."""
    from features.diffusion_net import ShapeInput
    from features.orientation import PLACED_ORIENTATIONS

    whole_points = (creature.verts - creature.verts.mean(axis=0)) / np.sqrt(creature.area)
    lower = whole_points[:, 1] < np.quantile(whole_points[:, 1], 0.4)
    part = ShapeInput(torch.from_numpy(whole_points[lower] - whole_points[lower].mean(axis=0)).float(), None)
    net = _PositionNetwork()
    whole = torch.nn.functional.normalize(net(torch.from_numpy(whole_points).float(), None), dim=-1)
    search = OrientationSearch(reference=None, turns=4, loss=None)
    ranked = search.ranked_for_part(net, part, whole, whole_points)
    assert len(ranked) == PLACED_ORIENTATIONS
    assert len({presentation.degrees for presentation in ranked}) == PLACED_ORIENTATIONS  # one per turn
    best = search.best_for_part(net, part, whole, whole_points)
    assert best.degrees == ranked[0].degrees == 0.0 and best.offset == ranked[0].offset


def test_a_part_with_more_area_than_its_whole_is_shown_at_its_size_read_from_the_features(tmp_path, creature):
    """A part cannot have more area than its whole: it comes from a larger body, and is shown to the
    network at the size its feature partners say (never above the whole's area); a part of
    plausible area is shown as given."""
    whole = creature
    part = plane_cut(whole, np.array([0.0, 1.0, 0.0]), 0.85, "tall").mesh
    _checkpoint_with_reference(tmp_path / "a.pt", whole)
    extractor = LearnedExtractor(str(tmp_path / "a.pt"), use_cache=False)
    assert extractor.orientation is not None
    extractor.part_features(part, whole)
    assert extractor.orientations["tall"].size == 1.0
    larger = Mesh(part.verts * 1.3, part.faces, "tall")
    feat_part, _ = extractor.part_features(larger, whole)
    size = extractor.orientations["tall"].size
    assert size <= np.sqrt(whole.area / larger.area) + 1e-12 and size != 1.0
    assert "times its given size" in extractor.orientations["tall"].describe()
    assert feat_part.shape[0] == larger.n_verts


def test_two_parts_are_read_on_the_checkpoint_reference_shape(tmp_path, creature):
    """The reference stored in a checkpoint is the whole two parts are read on (each placed on it as a
    part); a checkpoint without one, and WKS, give no reading."""
    from spidermatch.feature_transfer import reference_images
    from spidermatch.geometry.descriptors import WKSExtractor

    _checkpoint_with_reference(tmp_path / "a.pt", creature)
    extractor = LearnedExtractor(str(tmp_path / "a.pt"), use_cache=False)
    assert np.array_equal(extractor.reference_mesh.verts, creature.verts)
    assert np.array_equal(extractor.reference_mesh.faces, creature.faces)
    lower = plane_cut(creature, np.array([0.0, 1.0, 0.0]), 0.6, "lower").mesh
    upper = plane_cut(creature, np.array([0.0, -1.0, 0.0]), 0.6, "upper").mesh
    images = reference_images(extractor, lower, upper)
    assert images.reference is extractor.reference_mesh
    assert images.source.shape == (lower.n_verts,) and images.target.shape == (upper.n_verts,)
    assert images.source.max() < creature.n_verts and images.target.min() >= 0
    assert {"lower", "upper"} <= set(extractor.orientations)  # each placed by the part search
    unturned = LearnedExtractor(str(tmp_path / "a.pt"), use_cache=False, orientation_turns=0)
    assert unturned.reference_mesh is None and reference_images(unturned, lower, upper) is None
    assert reference_images(WKSExtractor(), lower, upper) is None


def test_the_part_search_samples_a_large_surface_evenly_by_area_and_the_same_every_time():
    """A raw scan's thousands of vertices are sampled down, by area (a densely scanned region is
    not favoured), the same sample on every call; a template's vertices are all kept."""
    from features.orientation import search_points

    assert np.array_equal(search_points(np.ones(40), most=40), np.arange(40))
    areas = np.concatenate([np.ones(9000), np.full(1000, 9.0)])  # a dense half and a coarse half
    sample = search_points(areas, most=2000)
    assert sample.size == 2000 and np.array_equal(sample, np.unique(sample))
    assert np.array_equal(sample, search_points(areas, most=2000))
    coarse_share = np.mean(sample >= 9000)
    assert 0.4 < coarse_share < 0.6  # half the area; 10 % of the vertices


def test_a_part_is_searched_against_a_sample_of_a_large_whole(tmp_path, creature, monkeypatch):
    """The part's orientation search compares its features with a bounded sample of the whole's
    vertices (time and memory), and still finds the part unturned on its whole."""
    import features.learned as learned
    from features.orientation import search_points

    whole = creature
    part = plane_cut(whole, np.array([0.0, 1.0, 0.0]), 0.5, "upper").mesh
    _checkpoint_with_reference(tmp_path / "a.pt", whole)
    extractor = LearnedExtractor(str(tmp_path / "a.pt"), use_cache=False)
    compared = []
    ranked = OrientationSearch.ranked_for_part

    def spy(self, net, probe, whole_features, whole_points):
        compared.append((whole_features.shape[0], whole_points.shape[0]))
        return ranked(self, net, probe, whole_features, whole_points)

    monkeypatch.setattr(OrientationSearch, "ranked_for_part", spy)
    monkeypatch.setattr(learned, "search_points", lambda areas: search_points(areas, most=120))
    feat_part, feat_whole = extractor.part_features(part, whole)
    assert compared == [(120, 120)]
    assert feat_part.shape[0] == part.n_verts and feat_whole.shape[0] == whole.n_verts
    assert extractor.orientations["upper"].degrees == 0.0


def test_the_target_of_two_parts_is_turned_back_onto_the_reference_when_asked(tmp_path, creature):
    """partial=both with turn_part_targets: two scans in frames of their own, so the target part,
    turned about the vertical, is turned back onto the checkpoint's reference (and shown centred on
    itself); one given in the training frame is left as it is. Without it the target is as given."""
    whole = creature
    upper = plane_cut(whole, np.array([0.0, 1.0, 0.0]), 0.6, "upper").mesh
    lower = plane_cut(whole, np.array([0.0, -1.0, 0.0]), 0.6, "lower").mesh
    _checkpoint_with_reference(tmp_path / "a.pt", whole)
    turned = Mesh(turned_mesh(upper, 90.0).verts, upper.faces, "upper")
    as_given = LearnedExtractor(str(tmp_path / "a.pt"), use_cache=False, orientation_frames=False)
    as_given.parts_features(lower, turned)
    assert "upper" not in as_given.orientations  # the default: the target's frame as given
    extractor = LearnedExtractor(
        str(tmp_path / "a.pt"), use_cache=False, orientation_frames=False, turn_part_targets=True
    )
    extractor.parts_features(lower, upper)
    assert extractor.orientations["upper"].degrees == 0.0
    feat_x, feat_y = extractor.parts_features(lower, turned)
    assert extractor.orientations["upper"].degrees == 270.0
    assert not any(extractor.orientations["upper"].offset)
    assert feat_x.shape[0] == lower.n_verts and feat_y.shape[0] == upper.n_verts
