"""What a match run reads.

The meshes and ground truth a configuration names, the kind of pair they make and their features.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spidermatch.api import (
    BETTER_FEATURES_HINT,
    OVERLAP_METHODS,
    mesh_of,
    warned_wks_on_parts,
    with_target_overlap_read,
)
from spidermatch.cli.settings import dense_settings
from spidermatch.data.datasets import DatasetError, SyntheticShapes
from spidermatch.feature_transfer import MAX_FEATURE_VERTICES, pair_features
from spidermatch.geometry.io import read_vts
from spidermatch.geometry.mesh import Mesh, MeshError
from spidermatch.geometry.partial import PairKind, announce_pair, original_faces, overlap_kind, pair_kind
from spidermatch.geometry.repair import Repair
from spidermatch.geometry.weld import Weld
from spidermatch.model_size import check_meshes_fit
from spidermatch.pipeline import solver_time_left, usable_cores
from spidermatch.validate import (
    OptionError,
    check_ground_truth,
    coarseness_warnings,
)

logger = logging.getLogger("spidermatch.match")


INPUT_ERRORS = (MeshError, DatasetError, ValueError, FileNotFoundError)


@dataclass(frozen=True)
class MatchInputs:
    """Two full-resolution meshes, their names and optional ground truth (K,) each."""

    source: Mesh
    target: Mesh
    source_corr: np.ndarray | None
    target_corr: np.ndarray | None
    resolution: int
    description: str
    partial: bool = False
    overlap: bool = False
    piece_of: tuple | None = None  # (vertex ids, face ids, vertex count) of a matched piece of the user's
    target_of: tuple | None = None  # (vertex ids, face ids, vertex count) of a repaired target in the user's
    # a user's mesh with repeated vertices, matched welded (the files name the file's vertices)
    source_weld: Weld | None = None
    target_weld: Weld | None = None
    notes: tuple = ()  # what reading the inputs found, for the report's warnings (e.g. a missing .vts)


def load_inputs(cfg) -> MatchInputs:
    """Meshes named by ``source=``/``target=``, or the built-in synthetic pair."""
    if (cfg.source is None) != (cfg.target is None):
        raise DatasetError("give both source=PATH and target=PATH (or neither, for the built-in demo)")
    if cfg.source is not None:
        repair = bool(cfg.get("repair", False))
        source, repaired, source_weld = mesh_of(cfg.source, "source", repair)
        target, target_repaired, target_weld = mesh_of(cfg.target, "target", repair)
        source_corr = _ground_truth(cfg.source_corr, source, repaired, source_weld)
        target_corr = _ground_truth(cfg.target_corr, target, target_repaired, target_weld)
        if (source_corr is None) != (target_corr is None):
            raise DatasetError("give both source_corr= and target_corr= to evaluate against ground truth")
        check_ground_truth(source_corr, target_corr, cfg.source_corr, cfg.target_corr)
        inputs = MatchInputs(
            source,
            target,
            source_corr,
            target_corr,
            int(cfg.resolution),
            f"{cfg.source} -> {cfg.target}",
            source_weld=source_weld,
            target_weld=target_weld,
        )
        if target_repaired is not None:
            inputs = with_repaired(inputs, target_repaired, "target")
        return inputs if repaired is None else with_repaired(inputs, repaired, "source")
    data = cfg.data
    shapes = SyntheticShapes(n_shapes=1, n_verts=data.n_verts, seed=data.source_seed)
    other = SyntheticShapes(n_shapes=1, n_verts=data.n_verts, seed=data.target_seed)
    x, y = shapes.load(shapes.names[0]), other.load(other.names[0])
    return MatchInputs(
        x.mesh, y.mesh, x.corr, y.corr, int(cfg.resolution), f"built-in synthetic pair {x.name} -> {y.name}"
    )


def _ground_truth(path, mesh: Mesh, repaired: Repair | None, weld: Weld | None) -> np.ndarray | None:
    """Reference points (K,) of ``path`` (file vertices), told in the welded mesh's where it was welded.

    A repaired mesh's are told in the piece's later (:func:`with_repaired`).
    """
    if not path:
        return None
    if weld is not None:
        return weld.to_welded[read_vts(path, weld.n_file)]
    return read_vts(path, mesh.n_verts if repaired is None else repaired.n_original)


def with_repaired(inputs: MatchInputs, repaired: Repair, role: str) -> MatchInputs:
    """``inputs`` whose ``role`` mesh ("source" or "target") is the largest clean piece of the user's.

    The ground truth keeps the reference points inside the piece, that mesh's renumbered to
    it; ``piece_of`` (source) or ``target_of`` (target) says where the piece's vertices and
    faces lie in the user's mesh, for the files, and the piece's notes say what was dropped
    (the report's warnings).
    """
    piece, other = repaired.piece, "target" if role == "source" else "source"
    own_corr, other_corr = _corr_inside(
        piece, repaired.n_original, getattr(inputs, f"{role}_corr"), getattr(inputs, f"{other}_corr")
    )
    mesh = dataclasses.replace(piece.mesh, notes=(repaired.note, *piece.mesh.notes))
    if role == "source":
        where = {"piece_of": (piece.to_original, repaired.face_ids, repaired.n_original)}
    else:
        where = {"target_of": (piece.to_original, repaired.face_ids, repaired.n_original)}
    return dataclasses.replace(
        inputs, **{role: mesh, f"{role}_corr": own_corr, f"{other}_corr": other_corr}, **where
    )


def _corr_inside(piece, n_given: int, own_corr, other_corr) -> tuple:
    """Reference points (K',) inside ``piece`` of a mesh of ``n_given`` vertices; None stays None.

    The mesh's own are renumbered to the piece, the other mesh's keep the same rows.
    """
    if own_corr is None:
        return own_corr, other_corr
    position = piece.positions(n_given)
    inside = position[own_corr] >= 0
    return position[own_corr[inside]], other_corr[inside]


def check_inputs(cfg, inputs: MatchInputs, report: dict) -> MatchInputs:
    """Pair checks before any work: topology, meshes far below the resolution, memory for their size.

    What was repaired on reading the meshes (re-oriented faces, split polygons) joins the
    report's warnings. Returns ``inputs``, marked ``partial`` when the source is a part of
    the target (``report["pair"]`` says how the pair is matched and why).
    """
    repairs = [*inputs.notes, *inputs.source.notes, *inputs.target.notes]
    if repairs:
        report.setdefault("warnings", []).extend(repairs)
    kind = checked_pair_kind(cfg, inputs, report)
    report["pair"] = {"mode": kind.mode, "reason": kind.reason, "area_ratio": round(kind.area_ratio, 4)}
    announce_pair(kind)
    if kind.caution:
        report.setdefault("warnings", []).append(kind.caution)
    warnings = coarseness_warnings((inputs.source, inputs.target), inputs.resolution)
    if warnings:
        report.setdefault("warnings", []).extend(warnings)
    check_meshes_fit((inputs.source.n_verts, inputs.target.n_verts), dense_settings(cfg) is not None)
    return dataclasses.replace(inputs, partial=kind.mode != "whole", overlap=kind.mode == "overlap")


PARTIAL_OPTIONS = ("auto", "off", "both")


def checked_pair_kind(cfg, inputs: MatchInputs, report: dict) -> PairKind:
    """How the pair is matched (``partial=auto|off``); a refused pair raises, unless forced.

    ``allow_topology_mismatch=true`` matches a refused pair as two whole shapes, with the
    refusal as a warning.
    """
    option = cfg.get("partial", "auto")
    if option not in PARTIAL_OPTIONS:
        raise OptionError(f"partial={option!r}: choose from {', '.join(PARTIAL_OPTIONS)}")
    overlap_method = cfg.get("partial_overlap", "features")
    if overlap_method not in OVERLAP_METHODS:
        raise OptionError(f"partial_overlap={overlap_method!r}: choose from {', '.join(OVERLAP_METHODS)}")
    if option == "both":
        return overlap_kind(inputs.source, inputs.target)
    try:
        return pair_kind(inputs.source, inputs.target, partial=option == "auto")
    except MeshError as error:
        if not cfg.get("allow_topology_mismatch", False):
            raise
        logger.warning("%s (allow_topology_mismatch=true: matching anyway)", error)
        report.setdefault("warnings", []).append(str(error))
        ratio = inputs.source.area / inputs.target.area
        return PairKind("whole", "allow_topology_mismatch=true: matched as two whole shapes", ratio)


def resolution_text(inputs: MatchInputs) -> str:
    """'500 faces', or what each mesh is matched at when one has fewer faces than the resolution."""
    faces = [min(inputs.resolution, mesh.n_faces) for mesh in (inputs.source, inputs.target)]
    if faces == [inputs.resolution] * 2:
        return f"{inputs.resolution} faces"
    return (
        f"{faces[0]} x {faces[1]} faces (resolution={inputs.resolution}; a coarser mesh is matched as it is)"
    )


def make_extractor(cfg):
    """Instantiate ``cfg.features``; a learned extractor without a checkpoint is a clear error."""
    from hydra.utils import instantiate

    if "checkpoint" in cfg.features and cfg.features.checkpoint is None:
        raise ValueError(
            "features=learned needs a trained network: give checkpoint=PATH (see spidermatch-train)"
        )
    from hydra.errors import InstantiationException

    try:
        extractor = instantiate(cfg.features)
    except InstantiationException as error:
        # Hydra wraps the extractor's own error; a bad checkpoint is the user's input problem.
        if isinstance(error.__cause__, (ValueError, OSError)):
            raise error.__cause__ from None
        raise
    if "torch" in sys.modules:
        use_free_cores(sys.modules["torch"])
    return extractor


def free_cores() -> int:
    """Cores this process may use that other processes keep free, at least 1.

    Busy cores: the larger of the 1-minute load average and the processes running right now
    besides this one (``/proc/loadavg``; two matches started together see each other only there).
    """
    cores = usable_cores()
    busy = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
    try:
        running = int(Path("/proc/loadavg").read_text().split()[3].split("/")[0])
        busy = max(busy, running - 1)
    except (OSError, ValueError, IndexError):
        pass
    return max(1, min(cores, round(cores - busy)))


def use_free_cores(torch) -> None:
    """Give PyTorch only the free cores, unless ``OMP_NUM_THREADS`` says how many.

    PyTorch takes every core by default; two matches at once on two cores then run four
    spinning threads, and each takes far longer than with one thread apiece; a match alone
    still gains from the free cores (measurements: bench/README.md, solver constants).
    """
    if os.environ.get("OMP_NUM_THREADS"):
        return
    default = torch.get_num_threads()
    threads = min(free_cores(), default)
    if threads < default:
        logger.info(
            "PyTorch uses %d of %d threads: other processes keep the other cores busy", threads, default
        )
        torch.set_num_threads(threads)


def compute_features(cfg, inputs: MatchInputs) -> tuple[np.ndarray, np.ndarray, str, dict]:
    """Features of both full-resolution (centred) meshes, the extractor's name, and how they were made.

    The last item (for ``result.json``) names the meshes whose features were computed on a
    capped copy (``computed_on_vertices``) or a smoothed one (``smoothed_for_features``) and how
    an orientation search presented each mesh.
    """
    extractor = make_extractor(cfg)
    name = getattr(extractor, "name", type(extractor).__name__)
    if name == "wks":
        logger.info("features: WKS (no trained checkpoint given). %s", BETTER_FEATURES_HINT)
    warned_wks_on_parts(name, inputs.partial or inputs.overlap)
    record = {}
    feat_x, feat_y = pair_features(
        extractor,
        inputs.source,
        inputs.target,
        feature_cap(cfg),
        record,
        partial=inputs.partial,
        overlap=inputs.overlap,
    )
    return feat_x, feat_y, name, feature_details(extractor, record)


def second_opinion_features(cfg, inputs: MatchInputs) -> tuple[np.ndarray, np.ndarray]:
    """The second network's (``cfg.second_opinion``) features of both meshes, made as the first's are.

    The same extractor options as ``cfg.features`` (adaptation, orientation search), the same
    feature cap and the same partial presentation; (V_X, D) and (V_Y, D).
    """
    from omegaconf import OmegaConf

    second_cfg = OmegaConf.merge(cfg, {"features": {"checkpoint": str(cfg.second_opinion)}})
    feat_x, feat_y = pair_features(
        make_extractor(second_cfg),
        inputs.source,
        inputs.target,
        feature_cap(cfg),
        {},
        partial=inputs.partial,
        overlap=inputs.overlap,
    )
    return feat_x, feat_y


def overlap_reference(cfg, inputs: MatchInputs):
    """``partial_overlap=reference``: both parts read on the network's whole reference shape.

    :func:`spidermatch.feature_transfer.reference_images` with the extractor ``cfg.features``
    makes and the run's feature cap; None when it has no reference shape (WKS).
    """
    from spidermatch.feature_transfer import reference_images

    return reference_images(make_extractor(cfg), inputs.source, inputs.target, feature_cap(cfg))


def overlap_inputs(
    inputs: MatchInputs,
    feat_x: np.ndarray,
    feat_y: np.ndarray,
    report: dict,
    method: str = "features",
    settings=None,
    reference=None,
):
    """``partial=both``: the inputs cut to the source's overlap with the target, and its features.

    ``method``, ``settings`` and ``reference``: :func:`spidermatch.api.source_overlap_piece`'s
    (``partial_overlap`` on the command line; ``reference`` from :func:`overlap_reference`). The
    ground truth keeps the reference points inside the piece (renumbered to it); ``piece_of``
    says where each vertex and face of the piece lies in the user's source, so that the files
    name the source's own indices. ``report["overlap"]`` gets the piece's size and how it was
    found (``found_by``).

    Returns
    -------
    MatchInputs
        With ``source`` the piece (V_piece vertices).
    np.ndarray, shape (V_piece, D)
        The source features of the piece.
    """
    from spidermatch.api import source_overlap_piece

    piece, found_by = source_overlap_piece(
        inputs.source, inputs.target, feat_x, feat_y, method, settings, reference
    )
    report["overlap"] = {
        "source_overlap_vertices": int(piece.mesh.n_verts),
        "source_overlap_area": round(float(piece.kept_area), 4),
        "found_by": found_by,
    }
    source_corr, target_corr = _corr_inside(
        piece, inputs.source.n_verts, inputs.source_corr, inputs.target_corr
    )
    vertex_ids, face_ids = piece.to_original, original_faces(piece, inputs.source)
    n_user = inputs.source.n_verts
    if inputs.piece_of is not None:  # the overlap of a repaired source: in the user's indices
        vertex_ids, face_ids = inputs.piece_of[0][vertex_ids], inputs.piece_of[1][face_ids]
        n_user = inputs.piece_of[2]
    cut = dataclasses.replace(
        inputs,
        source=piece.mesh,
        source_corr=source_corr,
        target_corr=target_corr,
        piece_of=(vertex_ids, face_ids, n_user),
    )
    return cut, feat_x[piece.to_original]


@dataclass(frozen=True)
class OverlapSearch:
    """``partial=both``: where the source's overlap with the target is searched, and how.

    Kept so that a second opinion can search again with other features. ``inputs`` are the run's
    with the whole source (V_X vertices), ``features`` the (V_X, D) and (V_Y, D) features of the
    first search; ``method`` and ``reference`` are :func:`overlap_inputs`'s (with a reference, the
    target's overlap is read on it too).
    """

    inputs: MatchInputs
    features: tuple
    method: str
    reference: object

    def piece(self, features: tuple, report: dict, settings) -> tuple:
        """The inputs cut to the overlap ``features`` find, the piece's features and its settings.

        Parameters
        ----------
        features : (np.ndarray (V_X, D), np.ndarray (V_Y, D))
            Features of ``inputs``' meshes (the first search's or others).
        report : dict
            Gets ``overlap``, the piece's record (:func:`overlap_inputs`).
        settings : spidermatch.pipeline.MatchSettings
            The run's; the piece's solve gets what the overlap's own solve leaves of the time limit.

        Returns
        -------
        MatchInputs
            With ``source`` the piece (V_piece vertices).
        np.ndarray, shape (V_piece, D)
            The piece's source features.
        spidermatch.pipeline.MatchSettings
            The piece's settings.
        """
        feat_x, feat_y = features
        cut, piece_x = overlap_inputs(
            self.inputs, feat_x, feat_y, report, self.method, settings, self.reference
        )
        spent = report["overlap"]["found_by"].get("solve_s", 0.0)
        return cut, piece_x, solver_time_left(settings, spent)

    def read_target_overlap(self, result, found_by: dict) -> None:
        """With a reference shape: ``result``'s target overlap read on it.

        See :func:`spidermatch.api.with_target_overlap_read`.
        """
        if self.reference is not None:
            whole = self.inputs
            with_target_overlap_read(result, whole.source, whole.target, self.reference, found_by)


def feature_details(extractor, record: dict) -> dict:
    """``computed_on_vertices``, ``smoothed_for_features`` and ``orientation`` of a features stage.

    ``record`` is what :func:`pair_features` filled; empty entries are left out. Logs the
    orientations and forgets them, so that the next pair reports its own.
    """
    details = {key: dict(value) for key, value in record.items() if value}
    orientations = getattr(extractor, "orientations", None)
    if orientations:
        details["orientation"] = {key: value.describe() for key, value in orientations.items()}
        logger.info(
            "orientation search: %s",
            "; ".join(f"{key} {text}" for key, text in details["orientation"].items()),
        )
        orientations.clear()
    return details


def feature_cap(cfg) -> int | None:
    """``features_max_vertices`` of the run (None: no cap)."""
    return cfg.get("features_max_vertices", MAX_FEATURE_VERTICES) or None
