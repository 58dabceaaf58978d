"""Which stored pair results a resumed ``spidermatch-eval`` may reuse.

A pair's ``result.json`` records a hash of the settings that decide it (resolution,
features and the checkpoint's content, curve, costs, solver options; not the log level or
the plots), a fingerprint of its input files (size and modification time) and the version of
spidermatch that made it (:mod:`spidermatch.versions`). A re-run reuses a stored result only if
all three match and its status is final; otherwise the pair is run again, so a run folder never
mixes results of different settings or of different code.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from spidermatch.feature_transfer import MAX_FEATURE_VERTICES
from spidermatch.versions import spidermatch_version

# statuses that are the pair's real outcome (interrupted, output_error, started: run again)
FINAL_STATUSES = ("optimal", "feasible", "infeasible", "no_solution", "solver_failure", "input_error")
IGNORED_SOLVER_KEYS = ("log",)  # options that do not change a result
SOLVER_KEYS_ADDED_LATER = {"flow_rows": "found", "lp_cuts": False}
"""Solver options added after pair results were stored, each with the value those runs had."""


def _without_effect(key: str, value) -> bool:
    """Whether a solver option stays out of the hash.

    It does when it does not change a result, or when it has the value stored runs had before it
    existed (so that they stay reusable).
    """
    if key in IGNORED_SOLVER_KEYS:
        return True
    return key in SOLVER_KEYS_ADDED_LATER and SOLVER_KEYS_ADDED_LATER[key] == value


def file_identity(path: str | os.PathLike | None) -> dict | None:
    """Size and modification time of a file (None when no path is given; 'missing' if absent)."""
    if path is None:
        return None
    path = Path(path)
    try:
        stat = path.stat()
    except OSError:
        return {"path": str(path), "missing": True}
    return {"path": str(path), "size": stat.st_size, "mtime_ns": stat.st_mtime_ns}


def content_hash(path: str | os.PathLike | None) -> str | None:
    """SHA-256 of a file's content (a checkpoint's identity), None without a readable file."""
    if path is None or not Path(path).is_file():
        return None
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def settings_hash(settings: dict) -> str:
    """A short stable hash of plain-value settings (JSON with sorted keys)."""
    text = json.dumps(settings, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def deciding_settings(config: dict, checkpoint: str | None) -> dict:
    """The settings that decide a pair's result, from the plain eval configuration.

    Parameters
    ----------
    config : dict
        The resolved eval configuration as plain values.
    checkpoint : str, optional
        The features' checkpoint file: its content hash stands for it.

    """
    solver = {k: v for k, v in config["solver"].items() if not _without_effect(k, v)}
    cap = config.get("features_max_vertices", MAX_FEATURE_VERTICES)
    # only a changed cap enters the hash: runs made before the option existed stay reusable
    changed_cap = {} if cap == MAX_FEATURE_VERTICES else {"features_max_vertices": cap}
    return {
        "dataset": str(config.get("dataset")),
        "synthetic": config.get("synthetic") if config.get("dataset") in (None, "", "synthetic") else None,
        "resolution": config.get("resolution"),
        "features": {k: v for k, v in config["features"].items() if k != "checkpoint"},
        "checkpoint_sha256": content_hash(checkpoint),
        "curve": config["curve"],
        "costs": config["costs"],
        "solver": solver,
        "allow_topology_mismatch": bool(config.get("allow_topology_mismatch", False)),
        **changed_cap,
        **({"partial": config.get("partial")} if config.get("partial", "auto") != "auto" else {}),
    }


def rerun_reason(result: dict | None, key: str, inputs: list) -> str | None:
    """Why a stored pair result cannot be reused (None: reuse it).

    Parameters
    ----------
    result : dict or None
        The pair's stored ``result.json``.
    key : str
        :func:`settings_hash` of the current settings.
    inputs : list
        :func:`file_identity` of the pair's current input files.

    """
    if result is None:
        return "no result yet"
    if result.get("status") not in FINAL_STATUSES:
        return f"the last run ended with status {result.get('status')!r}"
    if result.get("settings_hash") != key:
        return "the settings changed since it was matched"
    if result.get("input_files") != inputs:
        return "its input files changed since it was matched"
    made_by = (result.get("software") or {}).get("spidermatch")
    if made_by != spidermatch_version():
        earlier = "a version that recorded none" if made_by is None else made_by
        return f"it was matched by spidermatch {earlier}, this is {spidermatch_version()}"
    return None
