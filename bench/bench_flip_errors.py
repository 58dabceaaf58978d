"""How much of a feature map's error is left-right flips: NN error, large errors, mirrored matches.

    .venv/bin/python bench/bench_flip_errors.py --data ../shared/data/FAUST_r \
        --shapes tr_reg_070..tr_reg_079 --wks \
        --checkpoint wks_only=runs/a/best.pt --checkpoint wks_xyz=runs/b/best.pt \
        --out bench/results/faust_val_flip_errors.json

For every ordered pair of the chosen shapes, at full resolution, on evenly spaced
reference points (``--points``) of the ground truth: the mean normalised geodesic error
of the nearest-neighbour feature map (as in training validation), the fraction of points
whose error exceeds 0.2 (``large``), and the fraction of points with such an error whose
match lies near the mirror image of the true point (``mirrored``: within 0.1 sqrt(area)
of the true point reflected in the plane through the shape's bounding-box centre normal
to ``--mirror-axis``, and at most half as far from it as from the true point). The
mirror test assumes consistently aligned shapes with a left-right symmetry plane
(FAUST_r: x). ``--leave-out NAME`` adds the same figures over the pairs without that shape.
The JSON also records each shape's turn about the vertical axis relative to the first
shape (degrees; the best rigid rotation between their ground-truth reference points),
which tells whether the shapes share one orientation. ``--orientation-search N`` presents
each shape's coordinates (``wks_xyz``/``xyz`` inputs) in N turns about the vertical axis and
keeps, without labels, the one with the lowest unsupervised loss against the first shape.
Prints one line per feature kind and writes them all as JSON.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

import numpy as np

from features.extractor import WKSExtractor
from features.learned import load_network
from features.wks import normalise_rows
from spidermatch.data.datasets import open_dataset
from train.config import DataConfig, TrainConfig
from train.data import Validator, ValShape, prepare_val_shape, select_names

LARGE_ERROR = 0.2
MIRROR_RADIUS = 0.1


def mirrored_matches(shape: ValShape, rows: np.ndarray, predicted: np.ndarray, axis: int) -> np.ndarray:
    """Whether each predicted vertex lies near the mirror image of its true vertex, (K,) bool.

    Parameters
    ----------
    shape : ValShape
        The target shape (V vertices).
    rows : np.ndarray, shape (K,)
        Reference points evaluated (rows of ``shape.corr``).
    predicted : np.ndarray, shape (K,)
        Predicted target vertex of each reference point.
    axis : int
        Coordinate normal to the symmetry plane.
    """
    verts = shape.mesh.verts
    true = verts[shape.corr[rows]]
    centre = 0.5 * (verts[:, axis].min() + verts[:, axis].max())
    mirror = true.copy()
    mirror[:, axis] = 2 * centre - true[:, axis]
    to_true = np.linalg.norm(verts[predicted] - true, axis=1)
    to_mirror = np.linalg.norm(verts[predicted] - mirror, axis=1)
    return (to_mirror < MIRROR_RADIUS * np.sqrt(shape.mesh.area)) & (to_mirror <= 0.5 * to_true)


def flip_figures(validator: Validator, feats: list[np.ndarray], axis: int) -> dict[str, float]:
    """NN error, large-error fraction and mirrored fraction over the validator's pairs.

    Parameters
    ----------
    validator : Validator
    feats : list of np.ndarray, each (V, C)
        L2-normalised descriptors of ``validator.shapes``.
    axis : int
    """
    errors, mirrored, pair_means = [], [], []
    for i, j in validator.pairs:
        source_refs = validator.shapes[i].corr[validator.rows]
        predicted = np.argmax(feats[i][source_refs] @ feats[j].T, axis=1)
        pair_errors = validator.pair_errors(feats, i, j)
        errors.append(pair_errors)
        pair_means.append(pair_errors.mean())
        mirrored.append(mirrored_matches(validator.shapes[j], validator.rows, predicted, axis))
    errors, mirrored = np.concatenate(errors), np.concatenate(mirrored)
    large = errors > LARGE_ERROR
    return {
        "nn_error": round(float(np.mean(pair_means)), 4),
        "large": round(float(large.mean()), 4),
        "mirrored": round(float((large & mirrored).mean()), 4),
        "error_of_the_rest": round(float(errors[~large].mean()), 4),
    }


def turn_about_vertical(reference: ValShape, shape: ValShape, axis: int = 1) -> float:
    """Angle (degrees) of the best rigid rotation from ``reference`` to ``shape`` about ``axis``.

    The rotation (Kabsch, no reflection) aligns the shapes' centred ground-truth reference
    points; its component about ``axis`` is returned.
    """
    from scipy.spatial.transform import Rotation

    a = reference.mesh.verts[reference.corr]
    b = shape.mesh.verts[shape.corr]
    a, b = a - a.mean(axis=0), b - b.mean(axis=0)
    u, _, vt = np.linalg.svd(b.T @ a)
    sign = np.sign(np.linalg.det(u @ vt))
    rotation = u @ np.diag([1.0, 1.0, sign]) @ vt
    return float(np.degrees(Rotation.from_matrix(rotation).as_rotvec()[axis]))


def learned_features(
    path: str, dataset, names: list[str], turns: int = 0, frames: bool = False
) -> tuple[list[np.ndarray], dict[str, str]]:
    """Descriptors of a checkpoint's network on the named shapes, L2-normalised rows.

    With ``turns`` > 1 and an input with coordinates (``wks_xyz``, ``xyz``), every shape is
    presented in ``turns`` orientations about the vertical axis and keeps the one whose
    unsupervised loss (the checkpoint's settings) against the first shape is lowest: the
    orientation search of :mod:`features.orientation`, with the first shape as reference; the
    turns are chosen at the checkpoint's training resolution, as in training and matching.
    ``frames`` adds the principal-axis alignments to the candidates, as matching does.
    Returns the descriptors and the chosen orientations.
    """
    from features.learned import fmap_config_of, training_faces_of
    from features.orientation import OrientationSearch, oriented_outputs, probe_input, searches_orientation

    network, model_config, checkpoint = load_network(path)
    network.eval()
    shapes = [prepare_val_shape(dataset.load(name), model_config, DataConfig()) for name in names]
    search, probes = None, None
    if searches_orientation(
        model_config, turns
    ):  # turns chosen at the training resolution, as in the product
        faces = training_faces_of(checkpoint)
        probes = [probe_input(shape.mesh, model_config, faces) for shape in shapes]
        search = OrientationSearch(probes[0], turns, fmap_config_of(checkpoint), frames)
    found = oriented_outputs(network, [shape.input for shape in shapes], search, probes)
    chosen = {shape.name: orientation.describe() for shape, (orientation, _) in zip(shapes, found)}
    feats = [normalise_rows(out.double().numpy()) for _, out in found]
    return feats, chosen


def main(argv: list[str] | None = None) -> None:
    formatter = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=formatter)
    parser.add_argument("--data", required=True, help="a dataset folder with off/ and corres/")
    parser.add_argument("--shapes", required=True, help="names: 'first..last' or a comma-separated list")
    parser.add_argument("--checkpoint", action="append", default=[], help="LABEL=PATH of a best.pt")
    parser.add_argument("--wks", action="store_true", help="also evaluate WKS")
    parser.add_argument("--points", type=int, default=1000, help="reference points per pair")
    parser.add_argument("--mirror-axis", type=int, default=0, choices=(0, 1, 2))
    parser.add_argument(
        "--orientation-search", type=int, default=0, help="turns to try per shape (coordinate inputs)"
    )
    parser.add_argument("--frames", action="store_true", help="search principal-axis alignments too")
    parser.add_argument("--leave-out", action="append", default=[], help="a shape name (repeatable)")
    parser.add_argument("--out", default="bench/results/flip_errors.json")
    args = parser.parse_args(argv)
    labelled = [item.partition("=") for item in args.checkpoint]
    for label, sep, path in labelled:
        if not sep or not Path(path).is_file():
            parser.error(f"--checkpoint {label}{sep}{path}: expected LABEL=PATH of an existing file")
    dataset = open_dataset(args.data)
    spec = args.shapes if ".." in args.shapes else args.shapes.split(",")
    try:
        names = select_names(dataset.names, spec, "--shapes")
    except ValueError as error:
        parser.error(str(error))
    model = TrainConfig().model
    shapes = [prepare_val_shape(dataset.load(name), model, DataConfig()) for name in names]
    pairs = list(itertools.permutations(range(len(shapes)), 2))
    validator = Validator(shapes, args.points, True, pairs)
    kinds = {}
    if args.wks:
        extractor = WKSExtractor()
        kinds["wks"] = [extractor(shape.mesh) for shape in shapes]
    chosen_turns = {}
    for label, _, path in labelled:
        kinds[label], chosen_turns[label] = learned_features(
            path, dataset, names, args.orientation_search, args.frames
        )
    unknown = [name for name in args.leave_out if name not in names]
    if unknown:
        parser.error(f"--leave-out {unknown[0]}: not among --shapes")
    results = {}
    for label, feats in kinds.items():
        results[label] = flip_figures(validator, feats, args.mirror_axis)
        for name in args.leave_out:
            validator.pairs = [(i, j) for i, j in pairs if name not in (names[i], names[j])]
            results[label][f"without_{name}"] = flip_figures(validator, feats, args.mirror_axis)
        validator.pairs = pairs
        print(label, json.dumps(results[label]), flush=True)
    turns = {name: round(turn_about_vertical(shapes[0], shape), 1) for name, shape in zip(names, shapes)}
    print("turn about the vertical axis (degrees):", json.dumps(turns))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    record = {
        "argv": sys.argv,
        "pairs": len(pairs),
        "points": int(validator.rows.size),
        "turn_about_vertical_deg": turns,
        "orientation_search_turns": args.orientation_search,
        "chosen_input_turns_deg": chosen_turns,
        "results": results,
    }
    out.write_text(json.dumps(record, indent=2) + "\n")


if __name__ == "__main__":
    main()
