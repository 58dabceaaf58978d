"""Options shared by the benchmark scripts: ``--features`` / ``--checkpoint``, their checks, pair loading."""

from __future__ import annotations

import argparse

import numpy as np


def add_feature_options(parser: argparse.ArgumentParser, adaptation: bool = False) -> None:
    """Add ``--features {wks,learned}``, ``--checkpoint PATH`` (and ``--adapt-steps N`` if ``adaptation``)."""
    parser.add_argument("--features", default="wks", choices=("wks", "learned"))
    parser.add_argument("--checkpoint", default=None, help="trained network for --features learned")
    if not adaptation:
        return
    parser.add_argument(
        "--adapt-steps",
        type=int,
        default=0,
        help="test-time adaptation steps on each pair (features.adapt_steps of spidermatch-match)",
    )


def parse_checked(parser: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """Parse ``argv`` and check what would otherwise fail later as a traceback from a worker.

    Learned features need a checkpoint, ``--data`` must open as a dataset, and every
    ``--pairs`` entry must be ``SOURCE:TARGET`` with both shapes in it.
    """
    args = parser.parse_args(argv)
    if args.features == "learned" and args.checkpoint is None:
        parser.error("--features learned needs --checkpoint PATH (a spidermatch-train best.pt)")
    adapt_steps = getattr(args, "adapt_steps", 0)
    if adapt_steps < 0 or (adapt_steps and args.features != "learned"):
        parser.error("--adapt-steps must be >= 0, and adapts learned features only")
    problem = pair_problem(args.data, args.pairs)
    if problem:
        parser.error(problem)
    return args


def pair_problem(data: str, pairs: list[str]) -> str | None:
    """Why ``pairs`` (``SOURCE:TARGET`` texts) cannot be loaded from ``data``, or None if they can."""
    from spidermatch.data.datasets import DatasetError, checked_pair, open_dataset

    try:
        dataset = open_dataset(data)
    except DatasetError as error:
        return f"--data: {error}"
    known = set(dataset.names)
    for text in pairs:
        try:
            checked_pair(text.split(":"), known, f"--pairs {text}")
        except DatasetError as error:
            shown = ", ".join(dataset.names[:4]) + (", ..." if len(dataset.names) > 4 else "")
            return f"{error} ({data} has {shown})"
    return None


def load_pair_with_features(
    data: str, pair: tuple[str, str], features: str, checkpoint: str | None, adapt_steps: int = 0
):
    """Both shapes of a dataset pair and their per-vertex features (V_X, D), (V_Y, D).

    With ``adapt_steps`` > 0 the network is first adapted to the pair, as ``spidermatch-match
    features.adapt_steps=N`` does.
    """
    from features.extractor import extractor_by_name
    from spidermatch.data.datasets import open_dataset

    dataset = open_dataset(data)
    x, y = dataset.load(pair[0]), dataset.load(pair[1])
    if adapt_steps:
        from features.learned import LearnedExtractor

        adapted = LearnedExtractor(checkpoint, adapt_steps=adapt_steps)
        feat_x, feat_y = adapted.pair_features(x.mesh.centred(), y.mesh.centred())
        return x, y, feat_x, feat_y
    extractor = extractor_by_name(features, checkpoint)
    feat_x: np.ndarray = extractor(x.mesh.centred())
    feat_y: np.ndarray = extractor(y.mesh.centred())
    return x, y, feat_x, feat_y
