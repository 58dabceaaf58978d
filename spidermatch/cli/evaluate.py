"""``spidermatch-eval``: every selected pair of a dataset, resumable, with a summary and curves."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from spidermatch import shutdown
from spidermatch.cli.inputs import INPUT_ERRORS, MatchInputs, feature_cap, feature_details, make_extractor
from spidermatch.cli.match import run_pair
from spidermatch.feature_transfer import mesh_features, pair_features
from spidermatch.geometry.mesh import Mesh
from spidermatch.validate import (
    OptionError,
    check_ground_truth,
    check_options,
)
from spidermatch.versions import software_versions

logger = logging.getLogger("spidermatch.match")


class FeatureMemo:
    """Per-shape feature cache for a dataset run: each shape's features are computed once."""

    def __init__(self, cfg) -> None:
        self.extractor = make_extractor(cfg)
        self.name = getattr(self.extractor, "name", type(self.extractor).__name__)
        self.max_vertices = feature_cap(cfg)
        self._cache: dict[str, tuple[np.ndarray, dict]] = {}

    def of(self, key: str, mesh: Mesh) -> tuple[np.ndarray, dict]:
        """Features (V, D) of ``mesh`` (centred), computed on first use of ``key``, and their details."""
        if key not in self._cache:
            record = {}
            features = mesh_features(self.extractor, mesh, self.max_vertices, record)
            self._cache[key] = (features, feature_details(self.extractor, record))
        return self._cache[key]

    def pair(self, inputs: MatchInputs, names: tuple[str, str]) -> tuple[np.ndarray, np.ndarray, str, dict]:
        """Features of a pair and how they were made; adaptive extractors and parts are never cached."""
        depends_on_pair = hasattr(self.extractor, "pair_features") or inputs.partial  # a part's: on its whole
        if depends_on_pair:
            record = {}
            features = pair_features(
                self.extractor,
                inputs.source,
                inputs.target,
                self.max_vertices,
                record,
                partial=inputs.partial,
                overlap=inputs.overlap,
            )
            return *features, self.name, feature_details(self.extractor, record)
        (feat_x, details_x), (feat_y, details_y) = (
            self.of(names[0], inputs.source),
            self.of(names[1], inputs.target),
        )
        details = {}
        for part in (details_x, details_y):
            for kind, entries in part.items():
                details.setdefault(kind, {}).update(entries)
        return feat_x, feat_y, self.name, details


def _eval_settings_hash(cfg) -> str:
    """Hash of the settings that decide an eval's pair results (see :mod:`spidermatch.cli.resume`)."""
    from omegaconf import OmegaConf

    from spidermatch.cli.resume import deciding_settings, settings_hash

    plain = OmegaConf.to_container(cfg, resolve=True)
    checkpoint = cfg.features.get("checkpoint") if "checkpoint" in cfg.features else None
    return settings_hash(deciding_settings(plain, checkpoint))


def _pair_input_files(dataset, source: str, target: str) -> list:
    """Identities (size, mtime) of a pair's mesh and ground-truth files; [] for generated data."""
    from spidermatch.cli.resume import file_identity

    if not hasattr(dataset, "mesh_path"):
        return []
    return [
        file_identity(path)
        for name in (source, target)
        for path in (dataset.mesh_path(name), dataset.corr_path(name))
    ]


def _open_eval(cfg):
    """Options, dataset, pairs and features of an eval run (bad ones raise an input error)."""
    from spidermatch.cli.batch import select_pairs
    from spidermatch.data.datasets import open_dataset

    check_options(cfg)
    if cfg.resolution is None:
        raise OptionError("bad option: resolution=null: an eval needs a face count")
    options = dict(cfg.synthetic) if cfg.dataset in (None, "", "synthetic") else {}
    dataset = open_dataset(cfg.dataset, **options)
    pairs = select_pairs(dataset.names, dataset.pairs(cfg.pairs_file), cfg.n_pairs, cfg.pair_seed)
    return dataset, pairs, FeatureMemo(cfg), _eval_settings_hash(cfg)


def _eval_pair(cfg, run_dir: Path, dataset, memo: FeatureMemo, key: str, pair: tuple) -> tuple[dict, int]:
    """Reuse or (re)compute one pair of an eval run; return its result record and exit code."""
    from spidermatch.cli.batch import finished_result, pair_dir
    from spidermatch.cli.resume import rerun_reason

    source, target = pair
    folder = pair_dir(run_dir, source, target)
    inputs = _pair_input_files(dataset, source, target)
    reason = rerun_reason(finished_result(folder), key, inputs)
    if reason is None:
        result = finished_result(folder)
        logger.info("skipping finished pair %s -> %s (%s)", source, target, result["status"])
        return result, 0
    logger.info("matching %s -> %s: %s", source, target, reason)
    code = run_pair(
        cfg,
        folder,
        lambda: _dataset_inputs(dataset, source, target, cfg.resolution),
        lambda inputs: memo.pair(inputs, (source, target)),
        record={"settings_hash": key, "input_files": inputs},
    )
    result = finished_result(folder)
    if result is None or result.get("settings_hash") != key:  # result.json could not be written
        result = {"status": "output_error", "error": f"no result.json written in {folder}"}
    return result, code


def _stop_eval(run_dir: Path, summary: dict, where: str, code: int) -> int:
    """Record in ``summary.json`` where a signal stopped the eval; return its exit code."""
    summary["interrupted"] = f"{where} (the pair in progress is not counted and runs again on resume)"
    shutdown.write_result(run_dir / "summary.json", summary)
    logger.warning("eval interrupted %s; run the same command again to resume", where)
    return code


def run_eval(cfg, run_dir: Path) -> int:
    """Match every selected pair of a dataset into ``run_dir``, resuming finished pairs.

    A stored pair result is reused only if it was made with the same settings (a hash in
    its ``result.json``) from unchanged input files; otherwise the pair runs again. A
    signal stops the run after recording the pair in progress as ``interrupted``.

    Returns 0 if any pair was matched; the first pair's exit code if none was; 6 if the
    summary cannot be written; 130/143 after a signal.
    """
    from spidermatch.cli.batch import summary_row, write_summary

    with shutdown.signals_handled():
        try:
            run_dir.mkdir(parents=True, exist_ok=True)
            dataset, pairs, memo, key = _open_eval(cfg)
        except (shutdown.RunInterrupted, OSError, *INPUT_ERRORS) as error:
            status, code, message, _ = shutdown.final_status(error, INPUT_ERRORS)
            logger.error("%s", message)
            return code
        settings = {
            "dataset": str(cfg.dataset),
            "resolution": cfg.resolution,
            "features": memo.name,
            "strategy": cfg.solver.strategy,
            "pairs": len(pairs),
            "settings_hash": key,
            "software": software_versions(),
        }
        rows, codes, summary = [], [], {"settings": settings}
        try:
            summary = write_summary(run_dir, [], len(pairs), settings)
            for source, target in _progress(pairs):
                result, code = _eval_pair(cfg, run_dir, dataset, memo, key, (source, target))
                if code in shutdown.SIGNAL_EXIT_CODES.values():
                    return _stop_eval(run_dir, summary, f"{source} -> {target}", code)
                rows.append(summary_row(source, target, result))
                codes.append(int(result.get("exit_code", code)))
                summary = write_summary(run_dir, rows, len(pairs), settings)
                shutdown.raise_if_stopped()  # a signal that came while a pair's files were written
        except shutdown.RunInterrupted as stop:
            return _stop_eval(run_dir, summary, "between pairs", stop.exit_code)
        except shutdown.OutputError as error:  # e.g. a full disk: the pairs' own files say what finished
            logger.error("%s; the same command resumes from the pairs that finished", error)
            return shutdown.EXIT_OUTPUT_ERROR
    _plot_run(run_dir, memo.name)
    logger.info("summary: %s", json.dumps({k: summary[k] for k in ("statuses", "quality", "geodesic_error")}))
    logger.info("wrote %s and %s", run_dir / "summary.csv", run_dir / "summary.json")
    return no_matching_code(rows, codes)


def no_matching_code(rows: list[dict], codes: list[int]) -> int:
    """0 if any pair was matched (or none was asked); else the first pair's exit code (``codes``).

    An eval whose every pair failed (a broken folder, a time limit too short for all) must not
    look like a success to a script.
    """
    from spidermatch.cli.batch import MATCHED

    if not rows or any(row["status"] in MATCHED for row in rows):
        return 0
    logger.error("no pair was matched; the first: %s", rows[0].get("reason") or rows[0]["status"])
    return codes[0] or 1


def _progress(pairs):
    from tqdm.auto import tqdm

    return tqdm(pairs, desc="pairs", unit="pair")


def _dataset_inputs(dataset, source: str, target: str, resolution: int) -> MatchInputs:
    x, y = dataset.load(source), dataset.load(target)
    if hasattr(dataset, "corr_path"):
        notes = check_ground_truth(
            x.corr, y.corr, str(dataset.corr_path(source)), str(dataset.corr_path(target))
        )
    else:
        notes = check_ground_truth(x.corr, y.corr, f"{source} ground truth", f"{target} ground truth")
    both = x.corr is not None and y.corr is not None  # one alone measures nothing (and was logged)
    return MatchInputs(
        x.mesh,
        y.mesh,
        x.corr if both else None,
        y.corr if both else None,
        int(resolution),
        f"{source} -> {target}",
        source_weld=x.weld,  # files of soups: outputs name their own vertices
        target_weld=y.weld,
        notes=tuple(notes),
    )


def _plot_run(run_dir: Path, label: str) -> None:
    from spidermatch.cli.batch import collect_errors
    from spidermatch.report.curves import save_error_curves

    errors = collect_errors(run_dir)
    if errors.size:
        try:
            save_error_curves({label: errors}, run_dir / "errors.png")
        except OSError as error:  # a picture, after summary.csv and summary.json: the run stands
            logger.warning("%s cannot be written (%s)", run_dir / "errors.png", error.strerror or error)
