"""``spidermatch.match``: the Python entry point for notebooks and scripts.

Takes two meshes in any common form (file paths, ``trimesh.Trimesh`` objects, ``(V, F)``
array pairs or :class:`~spidermatch.geometry.mesh.Mesh`), computes their features, runs the
certified SpiderMatch pipeline and returns a :class:`Matching` of plain numpy arrays.

Direction convention
--------------------
Every map goes **from the source to the target**. ``matches[k] = (i, j)`` says source
vertex ``i`` corresponds to target vertex ``j``; ``dense_map[i] = j`` (shape (V_src,)) does
the same for every source vertex (``src_to_tgt``). In pyFM's and geomfum's naming this is
``p2p_12`` with mesh 1 the source: indexed by source vertices, holding target vertices.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from dataclasses import dataclass, field

import numpy as np

from spidermatch import defaults
from spidermatch.feature_transfer import MAX_FEATURE_VERTICES, reference_images
from spidermatch.feature_transfer import pair_features as capped_pair_features
from spidermatch.geometry.mesh import Mesh, MeshError, is_validated, make_mesh
from spidermatch.geometry.overlap import ReferenceImages, estimated_overlap, overlap_part, reference_overlap
from spidermatch.geometry.partial import (
    PairKind,
    PartialShape,
    announce_pair,
    ids_or_missing,
    overlap_kind,
    overlap_summary,
    pair_kind,
)
from spidermatch.geometry.repair import Repair, largest_clean_piece
from spidermatch.geometry.weld import Weld, welded
from spidermatch.model_size import check_meshes_fit
from spidermatch.validate import check_settings, feature_cap_problem, raise_problems

logger = logging.getLogger(__name__)

DEFAULT_TIME_LIMIT = float(defaults.option("solver/default", "time_limit"))
"""Seconds a default match may spend in the solver; when it stops, the incumbent and its gap are returned."""

WKS_RESOLUTION = defaults.resolution("files", "wks")
"""Default faces with WKS features (smaller: WKS makes the ILP harder)."""

LEARNED_RESOLUTION = defaults.resolution("files", "learned")
"""Default faces with learned (or any other) features."""

BETTER_FEATURES_HINT = (
    "WKS cannot tell left from right, which makes the problem hard and the matching prone to "
    "symmetric flips; for better features train a network (spidermatch-train) and match with "
    "features=learned checkpoint=PATH (Python: features=LearnedExtractor(PATH) from features.learned)"
)


WKS_ON_PARTS_HINT = (
    "WKS is unfit for parts: it describes each vertex by its shape's whole spectrum, and a part's "
    "spectrum is not its whole's (of 12 runs of FAUST_r parts against whole bodies with WKS none was "
    "certified or right, docs/partial.md); match parts with a network trained with partial copies "
    "(spidermatch-train train/experiment=faust_r_unsup_partial, then features=learned checkpoint=PATH)"
)


def wks_on_parts_hint(feature_name: str, parts: bool) -> str:
    """:data:`WKS_ON_PARTS_HINT` where WKS features meet a part (``parts``: a partial mode), else ""."""
    return WKS_ON_PARTS_HINT if feature_name == "wks" and parts else ""


def warned_wks_on_parts(feature_name: str, parts: bool) -> str:
    """:func:`wks_on_parts_hint`, logged as a warning when it says something."""
    hint = wks_on_parts_hint(feature_name, parts)
    if hint:
        logger.warning("%s", hint)
    return hint


def default_resolution(feature_name: str) -> int:
    """Faces of both decimated meshes when none is given: smaller for WKS, whose ILP is harder."""
    return WKS_RESOLUTION if feature_name == "wks" else LEARNED_RESOLUTION


@dataclass(frozen=True, eq=False)
class Matching:
    """The result of :func:`match`; every map goes source -> target.

    Attributes
    ----------
    matches : np.ndarray, shape (N, 2), int64, or None
        ``(source vertex, target vertex)`` pairs, 0-based indices into the full-resolution
        input meshes, one row per vertex of the decimated source (N of them): the matching
        the solver certified. None when the solver found no matching.
    dense_map : np.ndarray, shape (V_src,), int64, or None
        Target vertex for every vertex of the full-resolution source (``src_to_tgt``); None when
        the dense map is turned off or there is no matching. ``p2p`` is the same array. With
        ``partial="both"`` or a repaired source, -1 for the source vertices outside ``source_overlap``.
    dense : spidermatch.dense.densify.DenseMap or None
        The dense map in point-on-surface form (target face and barycentric coordinates); with
        ``partial="both"`` or a repaired source, of the matched piece's vertices
        (``details.source``), in their order. The coordinates follow the corners of the faces as
        matched: a mesh whose faces faced inwards had them reversed (its warning says so), and
        ``dense_map.npz`` of the command line converts them to the file's own corner order.
    status : str
        "optimal" (certified within ``mip_rel_gap``), "feasible" (stopped early with a
        matching that is not proven optimal), "infeasible", "no_solution" or "error".
    objective, bound, gap : float or None
        The matching's cost, the certified lower bound on every matching's cost, and their
        relative gap (None when undefined).
    resolution : int
        Faces of both decimated meshes.
    features : str
        Name of the features used ("wks", "learned", "precomputed", ...).
    timings : dict of str to float
        Seconds per stage ("features", "decimate", "curve", "costs", "build", "solve", "check").
    details : spidermatch.pipeline.MatchResult
        Everything else: the decimated meshes, the SpiderCurve, the solver's full report
        (with ``partial="both"``, of the matched overlap piece of the source).
    source_overlap : np.ndarray, shape (V_src,), bool, or None
        The source vertices that were matched, where not all of them were: with
        ``partial="both"`` those estimated to have a partner on the target, with
        ``repair=True`` those of the largest clean piece (both, with both). None otherwise.
    matched_meshes : tuple of Mesh, or None
        The full-resolution (source, target) as matched: the meshes as given, or welded, cut to
        their repaired pieces or to the source's overlap, in the indices of ``dense`` and
        ``details``; :meth:`save_pictures` draws them.
    as_given : bool
        Whether ``matched_meshes`` are the meshes as given (nothing welded, repaired or cut).
    target_covered : np.ndarray, shape (V_tgt,), bool, or None
        The target vertices the dense map covers, where a partial mode matched a part
        (``dense.covered`` told in the target's own vertices: a repeated vertex shares its
        welded vertex's entry, a vertex a repair cut away is False); None otherwise. With
        ``partial="both"`` and ``overlap_method="reference"``, the target's overlap read on the
        reference shape as the source's was (:func:`with_target_overlap_read`).

    """

    matches: np.ndarray | None
    dense_map: np.ndarray | None
    status: str
    objective: float | None
    bound: float | None
    gap: float | None
    resolution: int
    features: str
    timings: dict = field(default_factory=dict)
    details: object = field(default=None, repr=False)
    source_overlap: np.ndarray | None = field(default=None, repr=False)
    matched_meshes: tuple | None = field(default=None, repr=False)
    as_given: bool = field(default=True, repr=False)
    target_covered: np.ndarray | None = field(default=None, repr=False)

    @property
    def dense(self):
        """The :class:`~spidermatch.dense.densify.DenseMap` of every source vertex, or None."""
        return None if self.details is None else self.details.dense

    @property
    def quality(self) -> dict | None:
        """The verdict without ground truth: ``verdict`` ("plausible"/"suspect"), ``reasons``, figures."""
        return None if self.details is None else self.details.quality

    @property
    def proven_optimal(self) -> bool:
        """True if no matching has a lower cost than ``objective`` (within the relative gap)."""
        return self.status == "optimal"

    @property
    def p2p(self) -> np.ndarray | None:
        """The dense map, source -> target, shape (V_src,) (the pyFM/geomfum name)."""
        return self.dense_map

    def save_pictures(
        self,
        folder: str | os.PathLike,
        source_corr: np.ndarray | None = None,
        target_corr: np.ndarray | None = None,
        viewer: bool = True,
    ) -> list:
        """Write the command line's pictures of this matching into ``folder`` (created if needed).

        ``correspondence.png``, ``spider_curve.png``, ``texture.png`` (with a dense map),
        ``error.png`` (with ground truth) and the offline interactive ``viewer.html``, drawn
        on :attr:`matched_meshes` with the dense map when there is one, else the matches; a
        partial map greys out the target region it does not cover.

        Parameters
        ----------
        folder : str or PathLike
        source_corr, target_corr : np.ndarray, shape (K,), optional
            Ground truth: ``source_corr[k]`` and ``target_corr[k]`` are the same point (vertex
            indices of the meshes as given); adds the error picture and the viewer's error layer.
        viewer : bool
            Also write ``viewer.html``.

        Returns
        -------
        list of Path
            The files written.

        Raises
        ------
        ValueError
            No matching to draw, or ground truth for meshes that were welded, repaired or cut
            (its indices would name other vertices than those matched), or only one of the two.
        spidermatch.shutdown.OutputError
            A file cannot be written (a full disk, no permission); earlier pictures stay whole.
        """
        from pathlib import Path

        from spidermatch import shutdown
        from spidermatch.report.figures import MatchPictures, map_errors, status_line, write_match_pictures

        if self.details is None or self.details.low_map is None or self.matched_meshes is None:
            raise ValueError(f"no matching to draw (status {self.status!r})")
        if (source_corr is None) != (target_corr is None):
            raise ValueError("give both source_corr and target_corr, or neither")
        if source_corr is not None and not self.as_given:
            raise ValueError(
                "ground truth names the vertices of the meshes as given, but they were welded, "
                "repaired or cut before matching: draw without it"
            )
        source, target = self.matched_meshes
        dense = self.details.dense
        status = status_line({"status": self.status, "gap": self.gap, "resolution": self.resolution,
                              "features": self.features})  # fmt: skip
        pictures = MatchPictures(
            source.centred(),
            target.centred(),
            self.details.source.mesh,
            self.details.curve.vertices,
            self.details.full_pairs if dense is None else self.details.dense_map,
            f"{source.name} -> {target.name}",
            status,
            None if dense is None else dense.covered,
        )
        errors = None
        if source_corr is not None:
            corr = [np.asarray(c, dtype=np.int64).ravel() for c in (source_corr, target_corr)]
            if corr[0].size != corr[1].size:
                raise ValueError(
                    f"source_corr and target_corr differ in length ({corr[0].size} vs {corr[1].size})"
                )
            errors = map_errors(pictures, corr[0], corr[1])
        folder = Path(folder)
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise shutdown.OutputError(f"{folder}: cannot be created ({error.strerror})") from error
        return write_match_pictures(folder, pictures, errors, viewer)

    def __repr__(self) -> str:
        n = 0 if self.matches is None else len(self.matches)
        gap = "n/a" if self.gap is None else f"{self.gap:.2e}"
        return (
            f"Matching(status={self.status!r}, {n} matches, objective={self.objective}, gap={gap}, "
            f"resolution={self.resolution}, features={self.features!r})"
        )


def as_mesh(shape, role: str) -> Mesh:
    """A validated :class:`Mesh` from a path, a trimesh object, a (V, F) pair or a Mesh.

    Parameters
    ----------
    shape : str, os.PathLike, trimesh.Trimesh, trimesh.Scene, tuple (verts (V, 3), faces (F, 3)) or Mesh
        A Scene's meshes are placed by its transforms and joined (as a GLB file is read).
    role : str
        "source" or "target", named in error messages of in-memory meshes.

    Raises
    ------
    MeshError
        The mesh is missing, unreadable or not a single manifold triangle surface.
    TypeError
        ``shape`` is none of the accepted kinds.

    """
    shape = _one_trimesh(shape, role)
    if isinstance(shape, Mesh):
        return validated(shape)
    if isinstance(shape, (str, os.PathLike)):
        from spidermatch.geometry.io import load_mesh

        return load_mesh(shape)
    if isinstance(shape, (tuple, list)) and len(shape) == 2:
        return _from_arrays(shape[0], shape[1], f"{role} mesh (V, F) arrays")
    if hasattr(shape, "vertices") and hasattr(shape, "faces"):
        return _from_arrays(shape.vertices, shape.faces, f"{role} mesh ({type(shape).__name__})")
    raise TypeError(
        f"{role}: expected a mesh file path, a trimesh.Trimesh or Scene, a (verts, faces) pair or a "
        f"spidermatch Mesh, got {type(shape).__name__}"
    )


def _one_trimesh(shape, role: str):
    """A ``trimesh.Scene`` as one ``Trimesh`` (its meshes placed and joined as a file's), or ``shape``.

    ``trimesh.load`` returns a Scene for GLB/GLTF files and for OBJ files with materials.

    Raises
    ------
    MeshError
        A scene without triangles, or a point cloud (vertices without faces).
    """
    import trimesh

    if isinstance(shape, trimesh.Scene):
        meshes = [item for item in shape.geometry.values() if isinstance(item, trimesh.Trimesh)]
        if not meshes or not any(len(item.faces) for item in meshes):
            raise MeshError(
                f"{role} mesh (Scene): no triangle mesh in the scene ({len(shape.geometry)} geometries)"
            )
        return shape.to_mesh()
    if isinstance(shape, trimesh.PointCloud):
        raise MeshError(
            f"{role} mesh (PointCloud): a point cloud of {len(shape.vertices)} points; "
            "spidermatch needs a triangle mesh"
        )
    return shape


def _unchecked_mesh(shape, role: str) -> Mesh | None:
    """``shape`` (a path, trimesh object, (V, F) pair or Mesh) read without validation; None if unreadable."""
    if isinstance(shape, Mesh):
        return shape
    try:
        if isinstance(shape, (str, os.PathLike)):
            from spidermatch.geometry.io import load_mesh

            return load_mesh(shape, validate=False)
        if isinstance(shape, (tuple, list)) and len(shape) == 2:
            verts, faces, name = shape[0], shape[1], f"{role} mesh (V, F) arrays"
        elif hasattr(shape, "vertices") and hasattr(shape, "faces"):
            verts, faces, name = shape.vertices, shape.faces, f"{role} mesh ({type(shape).__name__})"
        else:
            return None
        if np.iscomplexobj(verts) or np.iscomplexobj(faces):  # refused as given; nothing to repair
            return None
        faces = np.asarray(faces)
        if faces.ndim != 2 or faces.shape[1] != 3 or np.ndim(verts) != 2 or np.shape(verts)[1] != 3:
            return None  # refused as given (make_mesh names the shapes it expects)
        if faces.dtype.kind == "f" and not np.array_equal(faces, np.round(faces)):
            return None  # refused as given (not vertex indices); never truncated into others
        return Mesh(np.asarray(verts, dtype=np.float64), faces.astype(np.int64), name)
    except (MeshError, ValueError, TypeError):
        return None


def validated(mesh: Mesh) -> Mesh:
    """``mesh`` if :func:`make_mesh` made it, else made from its arrays (checked, faces oriented).

    ``Mesh(verts, faces)`` checks nothing, so a mesh a user builds that way is checked here as
    a file would be: a broken one is refused naming it and the problem, not deep in a stage.
    """
    if is_validated(mesh):
        return mesh
    return make_mesh(mesh.verts, mesh.faces, mesh.name, mesh.notes)


def _from_arrays(verts, faces, name: str) -> Mesh:
    try:
        verts, faces = np.asarray(verts), np.asarray(faces)
    except ValueError as error:  # ragged nested lists
        raise MeshError(f"{name}: not rectangular arrays ({error})") from None
    if faces.dtype.kind == "f" and faces.size and np.array_equal(faces, np.round(faces)):
        faces = faces.astype(np.int64)  # integral floats, e.g. from a loaded text file
    return make_mesh(verts, faces, name)


def pair_features(
    features,
    source: Mesh,
    target: Mesh,
    max_vertices: int | None = MAX_FEATURE_VERTICES,
    *,
    partial: bool = False,
    overlap: bool = False,
) -> tuple[np.ndarray, np.ndarray, str]:
    """Features of both meshes (centred) and their name, from ``features`` as :func:`match` takes it.

    Parameters
    ----------
    features : "wks", an extractor, or a pair (source (V_src, D), target (V_tgt, D)) of arrays
        An extractor is any callable ``mesh -> (V, D)``; one with ``pair_features(source,
        target)`` (test-time adaptation) is asked for both at once.
    source, target : Mesh
    max_vertices : int, optional
        A mesh with more vertices gets an extractor's features on a decimated copy of about
        this many, carried to all its vertices (:mod:`spidermatch.feature_transfer`; None: no cap).
    partial : bool
        The source is a part of the target (an extractor with ``part_features`` measures it in
        the target's unit).
    overlap : bool
        Both are parts of one surface (an extractor with ``parts_features`` measures both in
        one unit).

    Returns
    -------
    source_features : np.ndarray, shape (V_src, D)
    target_features : np.ndarray, shape (V_tgt, D)
    name : str

    """
    if isinstance(features, str):
        features = _extractor_by_name(features)
    if isinstance(features, (tuple, list)) and len(features) == 2:
        return np.asarray(features[0]), np.asarray(features[1]), "precomputed"
    if not callable(features):
        raise TypeError(
            "features: expected 'wks', an extractor (e.g. features.learned.LearnedExtractor(checkpoint)) "
            f"or a pair of (V, D) arrays, got {type(features).__name__}"
        )
    name = str(getattr(features, "name", type(features).__name__))
    feat_x, feat_y = capped_pair_features(
        features, source, target, max_vertices, partial=partial, overlap=overlap
    )
    return feat_x, feat_y, name


def _extractor_of(features):
    """The extractor ``features`` names or is; None for precomputed arrays."""
    if isinstance(features, str):
        return _extractor_by_name(features)
    return None if isinstance(features, (tuple, list)) else features


def _extractor_by_name(name: str):
    if name == "wks":
        from spidermatch.geometry.descriptors import WKSExtractor

        return WKSExtractor()
    if name == "learned":
        raise ValueError(
            "features='learned' needs the network: pass features=LearnedExtractor(checkpoint) "
            "(from features.learned import LearnedExtractor; it needs PyTorch)"
        )
    raise ValueError(f"unknown features {name!r}: give 'wks', an extractor or a pair of (V, D) arrays")


def match(
    source,
    target,
    *,
    features="wks",
    resolution: int | None = None,
    time_limit: float | None = None,
    mip_rel_gap: float | None = None,
    strategy: str | None = None,
    settings=None,
    strict: bool = True,
    features_max_vertices: int | None = MAX_FEATURE_VERTICES,
    partial: str = "auto",
    repair: bool = False,
    second_opinion=None,
    overlap_method: str = "features",
) -> Matching:
    """Match ``source`` to ``target`` with SpiderMatch and return a certified :class:`Matching`.

    Parameters
    ----------
    source, target : path, trimesh.Trimesh or Scene, (verts (V, 3), faces (F, 3)) or Mesh
        One connected manifold triangle surface each. A triangle soup (an STL file, a
        vertex per face corner, seams split by an exporter) is welded into its surface
        (:mod:`spidermatch.geometry.weld`); ``matches``, ``dense_map`` and ``source_overlap``
        still name its own vertices (each repeated vertex with the image of the vertex it was
        welded into), ``dense`` and ``details`` the welded mesh's; precomputed features are
        given for the mesh as given.
    features : "wks", extractor, or (source (V_src, D), target (V_tgt, D)) arrays
        Per-vertex descriptors. "wks" needs no training; learned features come as
        ``features.learned.LearnedExtractor(checkpoint)``.
    resolution : int, optional
        Faces of both decimated meshes; default 500 for WKS, 1000 otherwise.
    time_limit : float, optional
        Solver seconds (default 300, or that of ``settings``); when it stops, the best
        matching found is returned with status "feasible" and its gap.
    mip_rel_gap : float, optional
        Relative gap at which a matching counts as optimal (default 1e-4).
    strategy : str, optional
        "auto" (default: "colgen" for learned features, "rcfix" for WKS), "colgen", "rcfix"
        or "plain"; all certify the same optimum.
    settings : spidermatch.pipeline.MatchSettings, optional
        Every other option (costs, curve, decimation); the keywords above take precedence.
    strict : bool
        Raise :class:`~spidermatch.pipeline.MatchError` (``InfeasibleError``,
        ``NoSolutionError``, ``SolverFailure``) when there is no checked matching; with
        False, return the :class:`Matching` with ``matches=None`` instead.
    features_max_vertices : int, optional
        A mesh with more vertices gets an extractor's features on a decimated copy of about
        this many vertices, carried to all of them (None or 0: no cap; precomputed arrays
        are used as given).
    partial : str
        "auto": a source with boundary loops the target lacks and a smaller area is matched
        as a part of the target (:func:`spidermatch.geometry.partial.pair_kind`; the reason is
        logged and kept in ``details.pair``); "off": always as two whole shapes; "both": the
        meshes are two parts of one surface in one unit: the source region that overlaps the
        target is estimated (:mod:`spidermatch.geometry.overlap`) and only it is matched, as a
        part of the target (``source_overlap``; ``dense_map`` is -1 elsewhere).
    repair : bool
        A mesh that fails the loader's checks only by bow-tie vertices, several pieces,
        unused vertices, degenerate faces or non-manifold edges (a raw scan) is matched as
        its largest clean piece (:func:`spidermatch.geometry.repair.largest_clean_piece`;
        what was dropped is logged). ``matches`` and ``dense_map`` still name each mesh's
        own vertices: a source's left-out vertices get -1 and lie outside
        ``source_overlap``, a target's are nobody's image; ``dense`` and ``details`` are in
        the pieces' indices. Precomputed features are given for the meshes as given. A mesh
        given as a ``Mesh`` is checked and repaired as a file is.
    second_opinion : extractor or (source (V_src, D), target (V_tgt, D)) arrays, optional
        Features of a second opinion, asked only when the map's quality verdict is
        "suspect": the pair is matched again with ``features`` and these joined
        (:func:`spidermatch.pipeline.joined_features`), and the second map is kept if its
        verdict is "plausible" (``details.second_opinion`` says which was kept; a second
        opinion that fails leaves the first map, the error there). Measured with a second
        training of the network (``LearnedExtractor(other_checkpoint)``) on partial-to-full
        pairs: docs/partial.md. With ``partial="both"`` the joined features search the source's
        overlap again before matching it, so the second map may match another piece.
    overlap_method : str
        With ``partial="both"``, how the source's overlap is found: "features" (the
        descriptors' cycle consistency, before any solve), "reference" (both parts read as
        parts of the network's whole reference shape, :func:`~spidermatch.geometry.overlap.reference_overlap`;
        an extractor with ``reference_mesh``, else "features" is used, logged) or "matched" (a
        certified matching of all of the source onto the target, a void vertex standing for
        "no partner": :mod:`spidermatch.model.void`; one more solve). ``details.overlap_found``
        records it.

    Returns
    -------
    Matching
        ``matches`` (N, 2) source -> target vertex pairs; ``dense_map`` (V_src,) when available.

    Raises
    ------
    MeshError, ValueError, TypeError
        Bad meshes or features, with a message naming the mesh and the problem.

    """
    from spidermatch.pipeline import match as run_pipeline
    from spidermatch.pipeline import needs_second_opinion

    raise_problems([feature_cap_problem(features_max_vertices, "features_max_vertices")])
    source_mesh, repaired, source_weld = mesh_of(source, "source", repair)
    target_mesh, target_repaired, target_weld = mesh_of(target, "target", repair)
    if isinstance(features, (tuple, list)) and len(features) == 2:  # given for the meshes as given
        features = (
            _matched_rows(features[0], source_weld, repaired),
            _matched_rows(features[1], target_weld, target_repaired),
        )
    dense_planned = settings is None or getattr(settings, "dense", None) is not None
    check_meshes_fit((source_mesh.n_verts, target_mesh.n_verts), dense_planned)
    check_overlap_method(overlap_method, "overlap_method")
    kind = recognised_pair(source_mesh, target_mesh, partial)
    started = time.perf_counter()
    overlap = kind.mode == "overlap"
    feat_x, feat_y, name = pair_features(
        features,
        source_mesh,
        target_mesh,
        features_max_vertices or None,
        partial=kind.mode == "partial",
        overlap=overlap,
    )
    reference = None
    if overlap and overlap_method == "reference":
        reference = reference_images(
            _extractor_of(features), source_mesh, target_mesh, features_max_vertices or None
        )
    feature_time = time.perf_counter() - started
    if name == "wks":
        logger.info("features: WKS. %s", BETTER_FEATURES_HINT)
    unfit_features = warned_wks_on_parts(name, kind.mode != "whole")
    run_settings = _settings(settings, name, resolution, time_limit, mip_rel_gap, strategy)
    run_settings = dataclasses.replace(run_settings, partial=kind.mode != "whole")
    check_settings(run_settings, solver_prefix="")  # messages name the keywords: time_limit=, not solver.
    if overlap:  # only the source region with a partner is matched, as a part of the target
        result, piece = _matched_overlap(
            (source_mesh, target_mesh), (feat_x, feat_y), overlap_method, run_settings, reference
        )
    else:
        piece, result = None, run_pipeline(source_mesh, target_mesh, feat_x, feat_y, run_settings)
    result.pair = kind
    if second_opinion is not None and needs_second_opinion(result):
        started = time.perf_counter()
        try:
            second_features = _second_opinion_features(
                second_opinion,
                (source_mesh, target_mesh),
                ((source_weld, repaired), (target_weld, target_repaired)),
                features_max_vertices or None,
                kind.mode,
            )
            result, piece = _second_opinion_kept(
                (result, piece),
                (source_mesh, target_mesh),
                ((feat_x, feat_y), second_features),
                run_settings,
                (overlap_method, reference),
            )
            result.pair = kind
        except Exception as error:  # the second opinion must not cost the first map
            logger.warning("the second opinion failed (%s): the first map stands", error)
            result.second_opinion = {"kept": "first", "error": str(error)}
        result.timings["second_opinion"] = time.perf_counter() - started
    matched_source = source_mesh if piece is None else piece.mesh
    if strict:
        result.raise_for_status(unfit_features)
    matching = _matching(result, name, run_settings.resolution, {"features": feature_time, **result.timings})
    changed = (source_weld, target_weld, repaired, target_repaired, piece)
    matching = dataclasses.replace(
        matching,
        matched_meshes=(matched_source, target_mesh),
        as_given=all(change is None for change in changed),
    )
    if piece is not None:
        matching = on_whole_source(matching, piece, source_mesh.n_verts)
    if repaired is not None:
        matching = on_whole_source(matching, repaired.piece, repaired.n_original)
    if target_repaired is not None:
        matching = on_whole_target(matching, target_repaired.piece, target_repaired.n_original)
    return on_file_vertices(matching, source_weld, target_weld)


def _second_opinion_features(second_opinion, meshes: tuple, changes: tuple, cap, mode: str) -> tuple:
    """The second opinion's features of the matched source and target, (V_src, D) and (V_tgt, D).

    ``changes``: each mesh's (weld, repair) from :func:`mesh_of`. Arrays are given for the
    meshes as given and cut as the first features were; an extractor is run on the matched
    meshes as the first one was (``mode``: the pair's :class:`PairKind` mode, which says how
    the parts are presented to it). With ``partial="both"`` they are the whole source's.
    """
    if isinstance(second_opinion, (tuple, list)) and len(second_opinion) == 2:
        return tuple(_matched_rows(rows, *change) for rows, change in zip(second_opinion, changes))
    second_x, second_y, _ = pair_features(
        second_opinion, *meshes, cap, partial=mode == "partial", overlap=mode == "overlap"
    )
    return second_x, second_y


def _second_opinion_kept(first: tuple, meshes: tuple, features: tuple, settings, overlap: tuple) -> tuple:
    """The pair matched again with the two networks' features joined; the map to keep and its piece.

    Parameters
    ----------
    first : (MatchResult, PartialShape or None)
        The map judged suspect and, with ``partial="both"``, the source's overlap it matched.
    meshes : (Mesh, Mesh)
        The whole source (V_X vertices) and the target (V_Y).
    features : ((np.ndarray (V_X, D1), np.ndarray (V_Y, D1)), (np.ndarray (V_X, D2), np.ndarray (V_Y, D2)))
        The first map's features and the second opinion's, of the whole meshes.
    settings : spidermatch.pipeline.MatchSettings
    overlap : (str, ReferenceImages or None)
        How the overlap is found (:func:`_matched_overlap`), used with ``partial="both"``: the
        joined features find it again, so a second opinion can move the overlap as well as the map.

    Returns
    -------
    result : MatchResult
        The kept map (:func:`spidermatch.pipeline.kept_opinion`), its ``second_opinion`` filled in.
    piece : PartialShape or None
        The kept map's source piece.
    """
    from spidermatch.pipeline import joined_features, kept_opinion, matched_with_second_opinion

    (result, piece), (first_features, second_features), (method, reference) = first, features, overlap
    if piece is None:
        kept, _ = matched_with_second_opinion(result, *meshes, first_features, second_features, settings)
        return kept, None
    joined = tuple(joined_features(a, b) for a, b in zip(first_features, second_features))
    second, second_piece = _matched_overlap(meshes, joined, method, settings, reference)
    kept = kept_opinion(result, second)
    return kept, second_piece if kept is second else piece


def _matched_overlap(meshes: tuple, features: tuple, method: str, settings, reference) -> tuple:
    """``partial="both"``: the source's overlap with the target found and matched as a part of it.

    Parameters
    ----------
    meshes : (Mesh, Mesh)
        The whole source (V_X vertices) and the target (V_Y).
    features : (np.ndarray (V_X, D), np.ndarray (V_Y, D))
    method, reference
        :func:`source_overlap_piece`'s; with ``reference``, the target's overlap is read on the
        reference shape (:func:`with_target_overlap_read`).
    settings : spidermatch.pipeline.MatchSettings
        The run's; the piece's solve gets the time the overlap's own solve leaves.

    Returns
    -------
    result : spidermatch.pipeline.MatchResult
        The piece matched, ``overlap_found`` filled in.
    piece : PartialShape
        The source's overlap (V_piece vertices).
    """
    from spidermatch.pipeline import match as run_pipeline
    from spidermatch.pipeline import solver_time_left

    (source, target), (feat_x, feat_y) = meshes, features
    piece, record = source_overlap_piece(source, target, feat_x, feat_y, method, settings, reference)
    piece_settings = solver_time_left(settings, record.get("solve_s", 0.0))
    result = run_pipeline(piece.mesh, target, feat_x[piece.to_original], feat_y, piece_settings)
    result.overlap_found = record
    if reference is not None:
        with_target_overlap_read(result, source, target, reference, record)
    return result, piece


def on_file_vertices(matching: Matching, source_weld: Weld | None, target_weld: Weld | None) -> Matching:
    """``matching`` told in the vertices of meshes given with repeated vertices (welded for matching).

    ``matches`` name each welded vertex's first file vertex; ``dense_map`` and
    ``source_overlap`` get one entry per vertex of the source file, ``target_covered`` one per
    vertex of the target file (a repeated vertex those of the vertex it was welded into);
    ``dense`` and ``details`` stay in the welded meshes' indices.
    """
    matches, dense_map, overlap = matching.matches, matching.dense_map, matching.source_overlap
    covered = matching.target_covered
    if source_weld is not None:
        matches = (
            None if matches is None else np.column_stack([source_weld.file_ids(matches[:, 0]), matches[:, 1]])
        )
        dense_map = None if dense_map is None else source_weld.file_values(dense_map)
        overlap = None if overlap is None else source_weld.file_values(overlap)
    if target_weld is not None:
        matches = (
            None if matches is None else np.column_stack([matches[:, 0], target_weld.file_ids(matches[:, 1])])
        )
        dense_map = None if dense_map is None else target_weld.file_ids(dense_map)
        covered = None if covered is None else target_weld.file_values(covered)
    return dataclasses.replace(
        matching, matches=matches, dense_map=dense_map, source_overlap=overlap, target_covered=covered
    )


def _matched_rows(features, weld: Weld | None, repaired: Repair | None):
    """Precomputed features (V_given, D) of a mesh as given, one row per vertex of the mesh matched.

    That mesh is the given one welded (``weld``), then cut to its repaired piece (``repaired``).
    """
    if weld is not None:
        features = _rows_kept(features, weld.n_file, weld.to_file, weld.mesh.name)
    if repaired is not None:
        features = _rows_kept(
            features, repaired.n_original, repaired.piece.to_original, repaired.piece.mesh.name
        )
    return features


def _rows_kept(features, n_given: int, kept: np.ndarray, name: str) -> np.ndarray:
    """The rows ``kept`` (V,) of features (``n_given``, D); other shapes are refused naming ``name``."""
    rows = np.asarray(features)
    if rows.ndim != 2 or rows.shape[0] != n_given:
        raise ValueError(
            f"features of {name}: expected one row per vertex of the mesh as given ({n_given}), "
            f"got shape {rows.shape}"
        )
    return rows[kept]


def on_whole_target(matching: Matching, piece: PartialShape, n_target: int) -> Matching:
    """``matching`` onto a repaired target's ``piece``, its target vertices told in the target's own indices.

    ``matches[:, 1]`` and ``dense_map`` name the target's own vertices, ``target_covered`` has one
    entry per target vertex (False off the piece); ``dense`` and ``details`` stay in the piece's.
    """
    matches, dense_map, covered = matching.matches, matching.dense_map, matching.target_covered
    if matches is not None:
        matches = np.column_stack([matches[:, 0], piece.to_original[matches[:, 1]]])
    if dense_map is not None:
        dense_map = ids_or_missing(piece.to_original, dense_map)
    if covered is not None:
        covered = np.zeros(n_target, dtype=bool)
        covered[piece.to_original] = matching.target_covered
    return dataclasses.replace(matching, matches=matches, dense_map=dense_map, target_covered=covered)


def mesh_of(shape, role: str, repair: bool) -> tuple[Mesh, Repair | None, Weld | None]:
    """``shape`` as a validated Mesh, its repair and its weld (None where not needed).

    A mesh whose faces meet on edges by position only (an STL file, a triangle soup, seams split
    by an exporter) is matched welded (:mod:`spidermatch.geometry.weld`) when the welded mesh
    is valid, or when neither it nor the mesh as given is (then it is the welded mesh that is
    refused or repaired). With ``repair``, an invalid mesh's largest clean piece is matched;
    without it, a mesh that the repair would mend is refused with what it would match.
    ``role`` ("source" or "target") names an in-memory mesh in messages.
    """
    shape = _one_trimesh(shape, role)  # a Scene joined once, for both readings below
    unchecked = _unchecked_mesh(shape, role)
    weld = None if unchecked is None else welded(unchecked)
    # a file is read once: its unchecked Mesh is validated as load_mesh would
    given = unchecked if unchecked is not None and isinstance(shape, (str, os.PathLike)) else shape
    if weld is None:
        return (*_checked_or_repaired(given, role, repair, unchecked), None)
    try:
        mesh = validated(weld.mesh)
    except MeshError:
        try:
            return as_mesh(given, role), None, None  # valid as given: its coincident vertices stay apart
        except MeshError:
            pass
        try:
            mesh, repaired = _checked_or_repaired(weld.mesh, role, repair, weld.mesh)
        except MeshError as error:
            repeats = weld.n_file - weld.mesh.n_verts
            raise MeshError(
                f"{error} (read with its {repeats} repeated vertices welded; vertex numbers count the "
                "welded vertices in the order they first appear in the file, face numbers are the file's)"
            ) from None
        if repaired is not None:
            mesh = dataclasses.replace(mesh, notes=(weld.note, *mesh.notes))
        logger.warning("%s", weld.note)
        return mesh, repaired, weld
    logger.warning("%s", weld.note)
    return mesh, None, weld


def _checked_or_repaired(
    shape, role: str, repair: bool, unchecked: Mesh | None
) -> tuple[Mesh, Repair | None]:
    """``shape`` validated, or (with ``repair``) the largest clean piece of ``unchecked``, its read form."""
    try:
        return as_mesh(shape, role), None
    except MeshError as error:
        if unchecked is None:
            raise
        try:
            repaired = largest_clean_piece(unchecked)
        except MeshError:
            if repair:
                raise
            raise error from None
        if not repair:
            raise MeshError(f"{error}; repair=true would match {repaired.summary}") from None
        logger.warning("%s (as given: %s)", repaired.note, error)
        return repaired.piece.mesh, repaired


OVERLAP_METHODS = ("features", "matched", "reference")
"""How ``partial="both"`` finds the source's overlap: by the descriptors' cycle consistency
(:func:`~spidermatch.geometry.overlap.estimated_overlap`), by a certified matching of all of
the source with a void vertex (:func:`~spidermatch.overlap_solve.matched_overlap`), or by
reading both parts on the network's whole reference shape
(:func:`~spidermatch.geometry.overlap.reference_overlap`)."""


def check_overlap_method(method: str, keyword: str) -> None:
    """Raise ValueError naming ``keyword`` unless ``method`` is one of :data:`OVERLAP_METHODS`."""
    if method not in OVERLAP_METHODS:
        raise ValueError(f"{keyword}={method!r}: choose from {', '.join(map(repr, OVERLAP_METHODS))}")


def descriptor_overlap(source: Mesh, target: Mesh, feat_x: np.ndarray, feat_y: np.ndarray) -> np.ndarray:
    """:func:`~spidermatch.geometry.overlap.estimated_overlap` of two parts in one unit, (V_X,) bool.

    The features (V_X, D) and (V_Y, D) are taken as given (normalised here); lengths are in the
    larger part's sqrt(area).
    """
    from spidermatch.model.costs import unit_rows

    unit_length = parts_unit_length(source, target)
    return estimated_overlap(source, target, unit_rows(feat_x), unit_rows(feat_y), unit_length)


def parts_unit_length(source: Mesh, target: Mesh) -> float:
    """The unit of length of two parts of one surface: the larger part's sqrt(area)."""
    return float(np.sqrt(max(source.area, target.area)))


def source_overlap_piece(
    source: Mesh,
    target: Mesh,
    feat_x: np.ndarray,
    feat_y: np.ndarray,
    method: str = "features",
    settings=None,
    reference: ReferenceImages | None = None,
) -> tuple[PartialShape, dict]:
    """The piece of ``source`` found to overlap ``target`` (two parts of one surface, one unit).

    Parameters
    ----------
    source, target : Mesh
    feat_x : np.ndarray, shape (V_X, D)
    feat_y : np.ndarray, shape (V_Y, D)
    method : str
        One of :data:`OVERLAP_METHODS`. "matched" solves with the void cheaper outside the
        descriptors' estimate (:func:`~spidermatch.overlap_solve.matched_overlap`); a solve that
        ends without a matching falls back to the estimate, logged.
    settings : spidermatch.pipeline.MatchSettings, optional
        The match's settings, for the "matched" solve, which takes at most
        :data:`~spidermatch.pipeline.OVERLAP_SOLVE_SHARE` of the solver's time limit (the
        piece's solve gets what it leaves: :func:`~spidermatch.pipeline.solver_time_left` with
        the record's ``solve_s``).
    reference : ReferenceImages, optional
        Both parts read on a whole reference shape (:func:`spidermatch.feature_transfer.reference_images`),
        for "reference"; without it that method falls back to the descriptors' estimate, logged.

    Returns
    -------
    piece : PartialShape
    record : dict
        ``method`` used and, for "matched", the solve's ``status``, ``objective``, ``bound``,
        ``gap``, ``solve_s`` and ``void_share`` (``result.json["overlap"]["found_by"]``).

    Raises
    ------
    MeshError
        No overlap found.

    """
    check_overlap_method(method, "overlap_method")
    if method == "reference" and reference is not None:
        region = reference_overlap(source, reference, parts_unit_length(source, target))
        record = {"method": "reference"}
        found_as = "has a partner on the reference shape where the target lies"
    else:
        region, record, found_as = _found_by_descriptors(source, target, feat_x, feat_y, method, settings)
    piece = overlap_part(source, region, found_as)
    logger.info(
        "%s: matching its overlap with %s, %d of %d vertices (%.0f %% of its area)",
        source.name,
        target.name,
        piece.mesh.n_verts,
        source.n_verts,
        100 * piece.kept_area,
    )
    return piece, record


def with_target_overlap_read(
    result, source: Mesh, target: Mesh, reference: ReferenceImages, record: dict
) -> None:
    """The target's overlap read on the reference shape as ``result.dense.covered``, (V_Y,) bool.

    The reading that found the source's overlap (:func:`source_overlap_piece`) tells the
    target's with the roles exchanged; it replaces the region the piece's dense map covers,
    which reaches only as far as the piece does and falls with the map where the piece is
    placed wrongly (on FAUST_r pairs of parts, IoU with the true overlap 0.78 against 0.47:
    docs/partial.md, "The overlap read on a reference shape"). ``record``
    (``result.json["overlap"]["found_by"]``) says so (``target_overlap``) and keeps the map's
    own coverage, as a share of the target's area (``map_covered_area``). Without a dense map
    nothing changes.

    Parameters
    ----------
    result : spidermatch.pipeline.MatchResult
        The match of the source's overlap piece onto ``target``.
    source : Mesh
        The whole source (V_X vertices), as ``reference`` read it.
    target : Mesh
        V_Y vertices, as matched.
    reference : ReferenceImages
    record : dict
    """
    if result.dense is None or result.dense.covered is None:
        return
    region = reference_overlap(target, reference.swapped(), parts_unit_length(source, target))
    map_covered = overlap_summary(target, result.dense.covered)["target_covered_area"]
    record.update(target_overlap="reference", map_covered_area=map_covered)
    result.dense = dataclasses.replace(result.dense, covered=region)


def _found_by_descriptors(
    source: Mesh, target: Mesh, feat_x: np.ndarray, feat_y: np.ndarray, method: str, settings
) -> tuple[np.ndarray, dict, str]:
    """The source's overlap (V_X,) bool by the descriptors' estimate, or by the matching it guides.

    Also the record of how it was found and the words that say so in a refusal
    (:func:`source_overlap_piece`, whose "reference" without a reference shape ends here too).
    """
    region = descriptor_overlap(source, target, feat_x, feat_y)
    record, found_as = {"method": "features"}, "has descriptors that match back to themselves"
    if method == "reference":  # no reference shape: the features have none (WKS, joined networks)
        logger.warning(
            "overlap_method='reference' needs a network with a reference shape: "
            "the descriptors' estimate is used"
        )
        record["fallback_from"] = "reference"
    if method == "matched":  # the estimate makes the void cheaper where it sees no partner
        from spidermatch.overlap_solve import matched_overlap
        from spidermatch.pipeline import MatchSettings, overlap_solve_settings

        overlap_settings = overlap_solve_settings(settings or MatchSettings())
        found = matched_overlap(source, target, feat_x, feat_y, overlap_settings, estimate=region)
        record = {"method": "matched", **found.summary()}
        if found.region is None:
            logger.warning("no overlap matched in time: the descriptors' estimate is matched instead")
            record["fallback"] = "features"
        else:
            region, found_as = found.region, "was matched to the target, the rest to the void"
    return region, record, found_as


def on_whole_source(matching: Matching, piece: PartialShape, n_source: int) -> Matching:
    """``matching`` of the overlap ``piece`` told in the whole source's vertex indices.

    ``matches`` name the source's own vertices; ``dense_map`` has one entry per source vertex,
    -1 outside the overlap; ``source_overlap`` marks the piece (or, when ``matching`` already
    has one, the part of the piece it marks).
    """
    inside = np.zeros(n_source, dtype=bool)
    if matching.source_overlap is None:
        inside[piece.to_original] = True
    else:  # a piece of a piece (the overlap of a repaired source)
        inside[piece.to_original[matching.source_overlap]] = True
    matches = matching.matches
    if matches is not None:
        matches = np.column_stack([piece.to_original[matches[:, 0]], matches[:, 1]])
    dense_map = matching.dense_map
    if dense_map is not None:
        dense_map = np.full(n_source, -1, dtype=np.int64)
        dense_map[piece.to_original] = matching.dense_map
    return dataclasses.replace(matching, matches=matches, dense_map=dense_map, source_overlap=inside)


def recognised_pair(source: Mesh, target: Mesh, partial: str) -> PairKind:
    """How the API matches a pair: a part of its target (``partial="auto"``) or two whole shapes.

    Meshes of different topology that no partial mode explains are matched as two whole
    shapes, with the reason as a warning (the API has never refused them).
    """
    if partial not in ("auto", "off", "both"):
        raise ValueError(f"partial={partial!r}: choose 'auto', 'off' or 'both'")
    if partial == "both":
        kind = overlap_kind(source, target)
        announce_pair(kind)
        return kind
    try:
        kind = pair_kind(source, target, partial=partial == "auto")
    except MeshError as error:
        logger.warning("%s (matched as two whole shapes)", error)
        return PairKind("whole", str(error), source.area / target.area)
    announce_pair(kind)
    return kind


def _settings(base, feature_name: str, resolution, time_limit, mip_rel_gap, strategy):
    from spidermatch.pipeline import MatchSettings
    from spidermatch.solve.strategies import strategy_for

    if base is None:  # MatchSettings() holds conf/'s defaults: strategy auto, DEFAULT_TIME_LIMIT
        base = MatchSettings(resolution=default_resolution(feature_name))
    solver = base.solver  # values pass unconverted: pipeline.match checks them (no silent int(150.9))
    if time_limit is not None:
        solver = dataclasses.replace(solver, time_limit=time_limit)
    if mip_rel_gap is not None:
        solver = dataclasses.replace(solver, mip_rel_gap=mip_rel_gap)
    changes = {"solver": solver}
    if resolution is not None:
        changes["resolution"] = resolution
    changes["strategy"] = strategy_for(str(strategy if strategy is not None else base.strategy), feature_name)
    return dataclasses.replace(base, **changes)


def _matching(result, feature_name: str, resolution: int, timings: dict) -> Matching:
    summary = result.solve.summary()
    matches = result.full_pairs.astype(np.int64) if result.low_map is not None and result.check.ok else None
    dense = result.dense_map if matches is not None else None
    covered = None if dense is None or result.dense is None else result.dense.covered
    if matches is not None and not result.solve.proven_optimal:
        logger.warning(
            "the solver stopped early: this matching is NOT proven optimal (gap %s)", summary["gap"]
        )
    return Matching(
        matches=matches,
        dense_map=None if dense is None else np.asarray(dense, dtype=np.int64),
        status=summary["status"],
        objective=summary["objective"],
        bound=summary["bound"],
        gap=summary["gap"],
        resolution=resolution,
        features=feature_name,
        timings=timings,
        details=result,
        target_covered=None if covered is None else np.asarray(covered, dtype=bool),
    )
