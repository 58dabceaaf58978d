"""Short training probes of a recipe on FAUST_r, validated often on a fixed subset of pairs.

    taskset -c 1 .venv/bin/python bench/probe_training.py --data ../shared/data/FAUST_r \
        --out-dir runs/probes --name wks_xyz --minutes 7 -- train/model=diffusion_net_wks_xyz

Runs ``train/experiment=faust_r_unsup`` (or ``--experiment``) with the given Hydra overrides
on one thread for ``--minutes`` of training (data preparation excluded; prepared shapes and
geodesic tables are cached in ``--out-dir``), validating every ``--val-every`` steps on 20
fixed ordered pairs of tr_reg_070-079 (each shape twice as source, twice as target) at 1000
reference points: the NN feature-map error, the fraction of points with an error above 0.2,
the part of those that are mirrored matches (see ``bench_flip_errors.py``) and the mean
error of the other points. Writes ``<name>/probe.csv`` and the usual run files.
"""

from __future__ import annotations

import argparse
import csv
import pickle
import sys
import time
from pathlib import Path

import numpy as np
import torch
from bench_flip_errors import LARGE_ERROR, mirrored_matches
from hydra import compose, initialize_config_module

import train.cli  # noqa: F401  (registers the schema)
from train.cli import to_train_config
from train.config import TrainConfig
from train.data import (
    Validator,
    open_shapes,
    prepare_shapes,
    prepare_train_shape,
    prepare_val_shape,
    split_names,
)
from train.loop import run_training

N_SHAPES = 10


def probe_pairs() -> list[tuple[int, int]]:
    """20 ordered pairs of the 10 validation shapes: 10 pairs at varying offsets, both ways."""
    forward = [(i, (i + 1 + 3 * (i % 3)) % N_SHAPES) for i in range(N_SHAPES)]
    return forward + [(j, i) for i, j in forward]


def compose_config(experiment: str, data: str, overrides: list[str]) -> TrainConfig:
    """The typed config of ``train/experiment=<experiment>`` with ``overrides``, one thread."""
    base = [f"train/experiment={experiment}", f"data.root={data}", "run.threads=1", "run.progress=false"]
    with initialize_config_module(config_module="conf", version_base="1.3"):
        return to_train_config(compose("train", overrides=[*base, *overrides]))


def prepared_data(config: TrainConfig, cache: Path) -> tuple[list, Validator]:
    """Training shapes and the probe validator, from ``cache`` when prepared before."""
    key = f"{config.model.input}_{config.model.in_channels}_{config.data.target_faces}_{config.model.n_eig}"
    path = cache / f"data_{key}.pt"
    if path.exists():
        return torch.load(path, weights_only=False)
    dataset = open_shapes(config.data)
    train_names, val_names = split_names(dataset.names, config.data)
    shapes = prepare_shapes(
        dataset, train_names, prepare_train_shape, config.model, config.data, "train", False
    )
    vals = [prepare_val_shape(dataset.load(name), config.model, config.data) for name in val_names]
    validator = Validator(vals, 1000, False, probe_pairs())
    tables = cache / "tables.pkl"
    if tables.exists():
        validator._tables = pickle.loads(tables.read_bytes())
    else:
        tables.write_bytes(pickle.dumps(validator.distance_tables()))
    torch.save((shapes, validator), path, pickle_protocol=4)
    return shapes, validator


class ProbeValidation:
    """The probe's figures of a network; ``best.pt`` is selected on ``val_error``."""

    criterion = "val_error"

    def __init__(self, validator: Validator) -> None:
        self.validator = validator

    def __call__(self, network) -> dict[str, float]:
        v = self.validator
        feats = v.features(network)
        errors, mirrored, means = [], [], []
        for i, j in v.pairs:
            predicted = np.argmax(feats[i][v.shapes[i].corr[v.rows]] @ feats[j].T, axis=1)
            errors.append(v.pair_errors(feats, i, j))
            means.append(errors[-1].mean())
            mirrored.append(mirrored_matches(v.shapes[j], v.rows, predicted, axis=0))
        errors, mirrored = np.concatenate(errors), np.concatenate(mirrored)
        large = errors > LARGE_ERROR
        return {
            "val_error": float(np.mean(means)),
            "large": float(large.mean()),
            "mirrored": float((large & mirrored).mean()),
            "error_of_the_rest": float(errors[~large].mean()),
        }


def main(argv: list[str] | None = None) -> None:
    formatter = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=formatter)
    parser.add_argument("--data", required=True, help="the FAUST_r folder")
    parser.add_argument("--out-dir", required=True, help="cache and run folders")
    parser.add_argument("--name", required=True)
    parser.add_argument("--experiment", default="faust_r_unsup")
    parser.add_argument("--minutes", type=float, default=7.0)
    parser.add_argument("--val-every", type=int, default=100)
    parser.add_argument("overrides", nargs="*", help="Hydra overrides of the experiment")
    args = parser.parse_args(argv)
    overrides = [
        *args.overrides,
        "run.n_steps=100000",
        f"run.val_every={args.val_every}",
        f"run.time_limit_min={args.minutes}",
    ]
    config = compose_config(args.experiment, args.data, overrides)
    torch.set_num_threads(1)
    cache = Path(args.out_dir)
    cache.mkdir(parents=True, exist_ok=True)
    shapes, validator = prepared_data(config, cache)
    out = cache / args.name
    started = time.monotonic()
    result = run_training(config, out, shapes, ProbeValidation(validator))
    history = torch.load(out / "last.pt", weights_only=True)["metrics"]["history"]
    columns = ["step", "val_error", "large", "mirrored", "error_of_the_rest", "loss"]
    with (out / "probe.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(
            {key: f"{row[key]:.4f}" if key != "step" else row[key] for key in columns} for row in history
        )
    print(
        f"{args.name}: {result.step} steps in {time.monotonic() - started:.0f} s, best {result.best_val:.4f}"
    )


if __name__ == "__main__":
    sys.exit(main())
