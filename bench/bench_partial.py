"""Partial matching: parts of FAUST_r-style shapes (bench/make_partial.py) against whole ones or other parts.

For every listed pair (a, b) and every part of a (plane cut, holes, single view) the part is
matched to b, and every part of b to a, through the Python API as a user calls it. Per run:
the mode the pair was recognised in, the status, the solve and whole-run times, the mean
geodesic error of the dense map over the reference points the part kept (in sqrt(area) of
the target), and the overlap: the IoU, weighted by vertex area, of the target region the map
says it covers with the region that truly corresponds to the part (each target vertex takes
the answer of its nearest reference point).

``--mode whole`` runs today's forced full-shape matching (``partial="off"``: the part
measured in its own unit, features as for a whole shape) on the same pairs, for comparison.

``--mode both`` is partial-to-partial (``partial="both"``): each part of a against each part of
b, kept when each part truly shares at least ``--min-overlap`` of its area with the other (a
reference point is shared when both parts kept it). Per run also: ``source_iou``, the IoU of
the estimated source overlap (``Matching.source_overlap``) with the true one;
``overlap_mapped``, the share of the shared reference points the map reaches (the rest fell
outside the estimate); ``dense_error`` over those, on the whole target shape; ``iou`` of the
covered target region with the target's true overlap. ``--overlap-method matched`` finds the
source overlap by a matching with a void vertex (``overlap_method="matched"``; per run also that
solve's ``overlap_status``, ``void_share`` and ``overlap_solve_s``)::

    .venv/bin/python bench/bench_partial.py --data ../shared/data/FAUST_r --parts runs/partial_faust \\
        --pairs bench/faust_val_pairs.txt --checkpoint ../runs/faust_unsup_partial_seed0/best.pt \\
        --time-limit 120 --out bench/results/partial_to_full_faust_val_1000.json

Prints one row per run, then the summary; writes rows and summary as JSON and CSV.
"""

from __future__ import annotations

import argparse
import json
import logging
import statistics
import sys
import time
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from bench_scaling import format_row, write_rows
from bench_user_copies import HOLE_RINGS, holed_copy, scan_copy
from scipy.spatial import cKDTree

import spidermatch
from spidermatch.data.datasets import Shape, ShapeFolder, read_pairs_file
from spidermatch.data.synthetic import random_rotation, rotation_angle
from spidermatch.eval.errors import pointwise_geodesic_errors
from spidermatch.geometry.io import load_mesh
from spidermatch.geometry.mesh import Mesh, MeshError, topology
from spidermatch.geometry.partial import kept_part
from spidermatch.geometry.remesh import nearest_vertices
from spidermatch.model import void

logger = logging.getLogger(__name__)

COLUMNS = (
    "part", "target", "kept_area", "mode", "status", "gap", "solve_s", "total_s", "dense_error", "iou",
    "verdict", "distortion", "dense_distortion", "mirror", "dense_mirror", "second_opinion",
)  # fmt: skip
BAD_ERROR = 0.1  # a dense error above this is a wrong map (a misplaced or mirrored part)
OVERLAP_COLUMNS = (*COLUMNS, "source_iou", "overlap_mapped")
OVERLAP_COLUMNS += ("overlap_status", "void_share", "overlap_solve_s")  # --overlap-method matched
OVERLAP_COLUMNS += ("turned_degrees", "target_turned_degrees")  # --turn-parts, --turn-targets
OVERLAP_COLUMNS += ("scan_vertices",)  # --scan-copies


def true_overlap(target: Mesh, target_corr: np.ndarray, kept_rows: np.ndarray) -> np.ndarray:
    """Target vertices whose nearest reference point (3-D) is one the part kept, shape (V_Y,) bool."""
    _, nearest = cKDTree(target.verts[target_corr]).query(target.verts)
    return kept_rows[nearest]


def area_iou(target: Mesh, predicted: np.ndarray, truth: np.ndarray) -> float:
    """Intersection over union of two vertex sets, each vertex weighted by its area."""
    areas = target.vertex_areas
    return float(areas[predicted & truth].sum() / areas[predicted | truth].sum())


SCAN_EVAL_POINTS = 300
"""Reference points whose dense error a scan copy's run measures (exact geodesics on ~80 000 vertices)."""


@dataclass(frozen=True)
class PartAgainstWhole:
    """One part (as presented to the matcher) against one whole shape, and what scores it."""

    part: Mesh
    target: Shape  # the whole target shape (mesh and reference points)
    sources: np.ndarray  # (K,) part vertex of each reference point the part kept
    kept_rows: np.ndarray  # (R,) bool: which of the target's reference points those are
    row: dict  # the run's row so far: part, target, kept area (and the turn)
    scored: np.ndarray | None = None  # (S,) the entries of ``sources`` the error is measured at; all if None

    def scored_points(self) -> tuple[np.ndarray, np.ndarray]:
        """Part vertex and true target vertex of each reference point the error is measured at, (S,) each."""
        truth = self.target.corr[self.kept_rows]
        if self.scored is None:
            return self.sources, truth
        return self.sources[self.scored], truth[self.scored]


def part_against_whole(
    parts: Path,
    folder: ShapeFolder,
    part_name: str,
    target_name: str,
    turn_seed: int | None,
    scan_seed: int | None = None,
    holes_seed: int | None = None,
    any_hole_size: bool = False,
) -> PartAgainstWhole:
    """Load a part and a whole target; with ``turn_seed``, the part turned and moved (:func:`turned_copy`);
    with ``scan_seed``, both as dense noisy scans (:func:`scanned_part`); with ``holes_seed``, the
    target with small holes (:func:`holed_target`)."""
    part, _, whole, position, kept_area = load_part(parts, folder, part_name)
    target = folder.load(target_name)
    row = {"part": part_name, "target": target_name, "kept_area": kept_area}
    if holes_seed is not None:
        rng = np.random.default_rng([holes_seed, zlib.crc32(target_name.encode())])
        target = holed_target(target, rng, any_hole_size)
    scored = None
    if scan_seed is not None:
        names = (part_name, target_name)
        rng = np.random.default_rng([scan_seed, *(zlib.crc32(name.encode()) for name in names)])
        part, position, _ = scanned_part(whole.mesh, position, rng, part.name)
        target = Shape(target.name, scan_copy(target.mesh, SCAN_SUBDIVISIONS, rng), target.corr)
        row["scan_vertices"] = f"{part.n_verts}/{target.mesh.n_verts}"
        kept = int((position[whole.corr] >= 0).sum())
        scored = np.sort(rng.choice(kept, size=min(SCAN_EVAL_POINTS, kept), replace=False))
    kept_rows = position[whole.corr] >= 0
    if turn_seed is not None:
        part, row["turned_degrees"] = turned_copy(part, turn_seed)
    return PartAgainstWhole(part, target, position[whole.corr[kept_rows]], kept_rows, row, scored)


TARGET_HOLES = 6
"""Small holes a ``--target-holes`` target gets (two rings of faces each, as bench_user_copies cuts)."""


def holed_target(target: Shape, rng: np.random.Generator, any_size: bool = False) -> Shape:
    """``target`` with :data:`TARGET_HOLES` small holes where a scanner saw nothing; each reference
    point at its nearest vertex left.

    Centres are drawn again until every hole is small (under ``SMALL_HOLE_SHARE`` of the area; two
    rings round a fingertip cut the finger off, and neighbouring holes may join): a larger loop
    would make the target a part, which this copy is not meant to be. ``any_size`` keeps the
    first draw, larger loops and all.
    """
    mesh = target.mesh
    for _ in range(100):
        holed = holed_copy(mesh, rng.choice(mesh.n_verts, size=TARGET_HOLES, replace=False), HOLE_RINGS)
        if any_size or topology(holed).open_boundaries == 0:
            return Shape(target.name, holed, nearest_vertices(holed.verts, mesh.verts[target.corr]))
    raise RuntimeError(f"{target.name}: no {TARGET_HOLES} small holes found in 100 draws")


SCAN_SUBDIVISIONS = 2
"""Loop subdivisions of a scan copy (about 80 000 vertices for a FAUST_r body)."""


def scanned_part(
    whole: Mesh, position: np.ndarray, rng: np.random.Generator, name: str
) -> tuple[Mesh, np.ndarray, np.ndarray]:
    """The part's region cut from a dense noisy scan of its whole, as a raw partial scan arrives.

    The whole is Loop-subdivided ``SCAN_SUBDIVISIONS`` times with noise along the normals
    (``bench_user_copies.scan_copy``; its original vertices come first) and each face of the
    scan is kept when the original vertices nearest to its three corners all belong to the part
    (then its largest clean piece, ``spidermatch.geometry.partial.kept_part``). Subdividing the
    part itself would not do: Loop subdivision of a ragged boundary (a single view's) inflated
    the area of ``tr_reg_070-view`` by 62 %.

    Returns
    -------
    part : Mesh
        The scanned part, named ``name``.
    position : np.ndarray, shape (V_whole,)
        Part vertex of each original vertex of the whole, -1 where cut away.
    to_whole : np.ndarray, shape (V_part,)
        The original vertex of the whole nearest to each vertex of the scanned part (itself for
        an original vertex).
    """
    scan = scan_copy(whole, SCAN_SUBDIVISIONS, rng)
    owner = cKDTree(whole.verts).query(scan.verts)[1]
    owner[: whole.n_verts] = np.arange(whole.n_verts)
    piece = kept_part(scan, (position[owner[scan.faces]] >= 0).all(axis=1), name, "scan")
    scanned_position = -np.ones(whole.n_verts, dtype=np.int64)
    originals = piece.to_original < whole.n_verts
    scanned_position[piece.to_original[originals]] = np.flatnonzero(originals)
    return piece.mesh, scanned_position, owner[piece.to_original]


def run_pair(part_name: str, parts: Path, folder: ShapeFolder, target_name: str, args, extractor) -> dict:
    """Match one part to one whole shape and score it."""
    run = part_against_whole(
        parts,
        folder,
        part_name,
        target_name,
        args.turn_parts,
        args.scan_copies,
        args.target_holes,
        args.any_hole_size,
    )
    part, target, kept_rows, row = run.part, run.target, run.kept_rows, run.row
    result = _timed_match(
        part, target.mesh, args, extractor, "auto" if args.mode == "partial" else "off", row
    )
    if result is None or result.dense_map is None:
        return row
    sources, truth_images = run.scored_points()
    errors = pointwise_geodesic_errors(target.mesh, result.dense_map[sources], truth_images)
    row["dense_error"] = round(float(errors.mean()), 4)
    truth = true_overlap(target.mesh, target.corr, kept_rows)
    covered = result.target_covered
    if covered is None:  # the whole mode says nothing of coverage: every image vertex, as the map gives it
        covered = np.zeros(target.mesh.n_verts, dtype=bool)
        covered[result.dense_map] = True
    row["iou"] = round(area_iou(target.mesh, covered, truth), 4)
    return row


def turned_copy(part: Mesh, seed: int) -> tuple[Mesh, float]:
    """``part`` in a random rotation (seeded by ``seed`` and its name) and moved, as a scanner may
    give it, and the rotation's angle in degrees."""
    rng = np.random.default_rng([seed, zlib.crc32(part.name.encode())])
    rotation = random_rotation(rng)
    moved = part.verts @ rotation.T + rng.normal(scale=np.sqrt(part.area), size=3)
    return Mesh(moved, part.faces, part.name), round(rotation_angle(rotation), 1)


def _timed_match(source: Mesh, target: Mesh, args, extractor, partial: str, row: dict):
    """``spidermatch.match`` as a user calls it; the mode, status, gap and times go into ``row``.

    None when the library refuses the pair (a ``MeshError``: e.g. ``partial="both"`` finding no
    overlap): the row then says ``status`` "refused" and the ``message``, and the bench goes on.
    """
    started = time.perf_counter()
    try:
        result = spidermatch.match(
            source,
            target,
            features=extractor,
            resolution=args.faces,
            time_limit=args.time_limit,
            strict=False,
            partial=partial,
            second_opinion=getattr(args, "second_network", None),
            overlap_method=getattr(args, "overlap_method", "features"),
        )
    except MeshError as refusal:
        row.update(total_s=round(time.perf_counter() - started, 1), status="refused", message=str(refusal))
        logger.warning("%s against %s refused: %s", row["part"], row["target"], refusal)
        return None
    row["total_s"] = round(time.perf_counter() - started, 1)
    row.update(
        mode=result.details.pair.mode if result.details.pair else "?",
        status=result.status,
        gap=result.gap,
        solve_s=round(result.timings.get("solve", float("nan")), 1),
    )
    found_by = result.details.overlap_found or {}
    if found_by.get("method") == "matched":  # the overlap's own solve
        row.update(overlap_status=found_by.get("status"), void_share=found_by.get("void_share"))
        row["overlap_solve_s"] = found_by.get("solve_s")
    if result.details.second_opinion:  # asked: which map was kept
        row["second_opinion"] = result.details.second_opinion.get("kept")
    if result.quality:  # the verdict without ground truth, to set beside the error
        figures = ("verdict", "distortion", "dense_distortion", "mirror", "dense_mirror")
        row.update({name: result.quality.get(name) for name in figures})
    return result


def run_overlap_pair(
    part_name: str, parts: Path, folder: ShapeFolder, target_part: str, args, extractor
) -> dict:
    """Match one part to a part of another shape (``partial="both"``) and score both overlaps."""
    pair = part_pair(parts, folder, (part_name, target_part))
    row = {"part": part_name, "target": target_part, "kept_area": pair.kept_area}
    if args.scan_copies is not None:
        pair = scanned_pair(pair, args.scan_copies)
        row["scan_vertices"] = "/".join(str(mesh.n_verts) for mesh in pair.meshes)
    meshes, wholes, to_original = list(pair.meshes), pair.wholes, pair.to_original
    if args.turn_parts is not None:  # the source as a scanner may give it; the scores read indices only
        meshes[0], row["turned_degrees"] = turned_copy(meshes[0], args.turn_parts)
    if args.turn_targets is not None:  # two scans, each in a frame of its own
        meshes[1], row["target_turned_degrees"] = turned_copy(meshes[1], args.turn_targets)
    if args.unit_scale != 1.0:  # both parts in another unit (one unit for the two: a partial pair's rule)
        meshes = [Mesh(mesh.verts * args.unit_scale, mesh.faces, mesh.name) for mesh in meshes]
    result = _timed_match(meshes[0], meshes[1], args, extractor, "both", row)
    if result is None:
        return row
    if result.source_overlap is not None:
        row["source_iou"] = round(area_iou(meshes[0], result.source_overlap, pair.truths[0]), 4)
    if result.dense_map is None:
        return row
    row["iou"] = round(area_iou(meshes[1], result.target_covered, pair.truths[1]), 4)
    if not pair.shared.any():  # parts that share nothing (--min-overlap 0): no share mapped, no error
        return row
    images = result.dense_map[pair.positions[0][wholes[0].corr[pair.shared]]]
    mapped = images >= 0
    row["overlap_mapped"] = round(float(mapped.mean()), 4)
    if not mapped.any():  # the estimated overlap missed the true one: no error to measure
        return row
    # measured on the whole target shape, as the partial-to-full runs are
    truth_images = wholes[1].corr[pair.shared][mapped]
    errors = pointwise_geodesic_errors(wholes[1].mesh, to_original[1][images[mapped]], truth_images)
    row["dense_error"] = round(float(errors.mean()), 4)
    return row


@dataclass(frozen=True)
class PartPair:
    """Two parts (of two shapes), where each vertex came from, and their true overlap."""

    meshes: list  # the two part meshes
    to_original: list  # (V_part,) vertex of its whole shape, per part
    wholes: list  # the two whole shapes (mesh and reference points)
    positions: list  # (V_whole,) index in the part, -1 where cut away, per part
    shared: np.ndarray  # (K,) bool: reference points both parts kept
    truths: list  # (V_part,) bool: vertices whose nearest reference point is shared, per part
    kept_area: float  # the first part's share of its whole's area


def load_part(parts: Path, folder: ShapeFolder, name: str) -> tuple:
    """One part of ``make_partial.py``'s output and where it lies in its whole shape.

    Returns
    -------
    part : Mesh
    to_original : np.ndarray, shape (V_part,)
        Vertex of the whole shape each part vertex came from.
    whole : the whole shape (mesh and reference points)
    position : np.ndarray, shape (V_whole,)
        Part index of each whole vertex, -1 where cut away.
    kept_area : float
        The part's share of the whole's area.

    """
    entry = {row["part"]: row for row in part_manifest(parts)}[name]
    to_original = np.load(parts / "maps" / f"{name}.npy")
    whole = folder.load(entry["shape"])
    position = -np.ones(whole.mesh.n_verts, dtype=np.int64)
    position[to_original] = np.arange(to_original.size)
    return load_mesh(parts / "off" / f"{name}.off"), to_original, whole, position, entry["kept_area"]


def part_pair(parts: Path, folder: ShapeFolder, names: tuple[str, str]) -> PartPair:
    """Two parts of ``make_partial.py``'s output and their true overlap (both kept the reference point)."""
    meshes, to_original, wholes, positions, kept_areas = zip(*(load_part(parts, folder, n) for n in names))
    shared = (positions[0][wholes[0].corr] >= 0) & (positions[1][wholes[1].corr] >= 0)
    truths = [_part_truth(*items, shared) for items in zip(meshes, wholes, to_original)]
    return PartPair(
        list(meshes), list(to_original), list(wholes), list(positions), shared, truths, kept_areas[0]
    )


def scanned_pair(pair: PartPair, seed: int) -> PartPair:
    """Both parts of ``pair`` as raw partial scans give them (:func:`scanned_part`), seeded by ``seed``
    and the parts' names; each scan vertex stands for its nearest original vertex of its whole."""
    rng = np.random.default_rng([seed, *(zlib.crc32(mesh.name.encode()) for mesh in pair.meshes)])
    scans = [
        scanned_part(whole.mesh, position, rng, mesh.name)
        for mesh, whole, position in zip(pair.meshes, pair.wholes, pair.positions)
    ]
    meshes, positions, to_original = (list(items) for items in zip(*scans))
    wholes = pair.wholes
    shared = (positions[0][wholes[0].corr] >= 0) & (positions[1][wholes[1].corr] >= 0)
    truths = [_part_truth(*items, shared) for items in zip(meshes, wholes, to_original)]
    return PartPair(meshes, to_original, list(wholes), positions, shared, truths, pair.kept_area)


def overlap_shares(parts: Path, folder: ShapeFolder, names: tuple[str, str]) -> tuple[float, float]:
    """Share of each part's area that truly overlaps the other (both kept the reference point)."""
    pair = part_pair(parts, folder, names)
    return tuple(float(mesh.vertex_areas[t].sum() / mesh.area) for mesh, t in zip(pair.meshes, pair.truths))


def _part_truth(part: Mesh, whole, kept: np.ndarray, shared: np.ndarray) -> np.ndarray:
    """Vertices of a part whose nearest reference point (on its whole) is in the overlap, (V_part,) bool."""
    _, nearest = cKDTree(whole.mesh.verts[whole.corr]).query(whole.mesh.verts[kept])
    return shared[nearest]


def _overlap_figures(rows: list[dict]) -> dict:
    """Partial-to-partial: source overlap IoU, the share of the true overlap mapped, runs within 0.06."""
    estimated = [row for row in rows if "source_iou" in row]
    return {
        "mean_source_iou": _mean(estimated, "source_iou"),
        "mean_overlap_mapped": _mean([row for row in rows if "overlap_mapped" in row], "overlap_mapped"),
        "runs_error_within_0.06": sum(row.get("dense_error", float("inf")) <= 0.06 for row in rows),
        "runs_iou_from_0.7": sum(row.get("iou", 0.0) >= 0.7 for row in rows),
    }


def _verdict_counts(scored: list[dict]) -> dict:
    """Runs with a wrong map (dense error above BAD_ERROR) and how many of each kind were called suspect."""
    judged = [row for row in scored if "verdict" in row]
    bad = [row for row in judged if row["dense_error"] > BAD_ERROR]
    good = [row for row in judged if row["dense_error"] <= BAD_ERROR]
    return {
        "runs_bad": len(bad),
        "suspect_among_bad": sum(row["verdict"] == "suspect" for row in bad),
        "suspect_among_good": sum(row["verdict"] == "suspect" for row in good),
    }


def _median(rows: list[dict], key: str) -> float | None:
    return round(statistics.median(row[key] for row in rows), 4) if rows else None


def _mean(rows: list[dict], key: str) -> float | None:
    return round(statistics.mean(row[key] for row in rows), 4) if rows else None


def summary(rows: list[dict]) -> dict:
    """Certified share, median times, mean dense error and IoU over the runs (and per cut kind)."""

    def figures(group: list[dict]) -> dict:
        scored = [row for row in group if "dense_error" in row]
        return {
            "runs": len(group),
            "optimal": sum(row["status"] == "optimal" for row in group),
            "median_total_s": statistics.median(row["total_s"] for row in group),
            "refused": sum(row["status"] == "refused" for row in group),
            "median_solve_s": _median([row for row in group if "solve_s" in row], "solve_s"),
            "mean_dense_error": _mean(scored, "dense_error"),
            "mean_iou": _mean(scored, "iou"),
            "median_dense_error": _median(scored, "dense_error"),
            **_verdict_counts(scored),
            **(_overlap_figures(group) if any("source_iou" in r for r in group) else {}),
        }

    kinds = sorted({row["part"].rsplit("-", 1)[1] for row in rows})
    return {
        "all": figures(rows),
        **{kind: figures([r for r in rows if r["part"].endswith(kind)]) for kind in kinds},
    }


def add_part_options(parser: argparse.ArgumentParser, checkpoint_help: str) -> None:
    """The options that say which parts to run against which shapes, with which network."""
    parser.add_argument("--data", required=True, help="the FAUST_r-style folder the parts were cut from")
    parser.add_argument("--parts", required=True, type=Path, help="the output folder of make_partial.py")
    parser.add_argument("--pairs", required=True, help="pairs file: 'a b' per line")
    parser.add_argument(
        "--checkpoint", required=True, help=f"{checkpoint_help} (several, comma-separated: their ensemble)"
    )
    parser.add_argument(
        "--turn-parts",
        type=int,
        default=None,
        metavar="SEED",
        help="present every part in a random rotation (seeded by SEED and the part's name), moved",
    )
    parser.add_argument(
        "--scan-copies",
        type=int,
        default=None,
        metavar="SEED",
        help="match dense noisy scans instead: the part's region cut from its whole Loop-subdivided twice "
        "with noise, against the target scanned the same way (about 80 000 vertices); the dense error "
        f"on {SCAN_EVAL_POINTS} of the part's reference points (--mode both: both parts scanned so, "
        "the error at every shared reference point)",
    )
    parser.add_argument(
        "--placed-orientations",
        type=int,
        default=None,
        metavar="N",
        help="place the N best orientations of a part on its target (default: the library's "
        "features.orientation.PLACED_ORIENTATIONS); 0 measures the orientation search alone",
    )


def apply_part_search_options(args: argparse.Namespace) -> None:
    """Set the part search's number of placed orientations for this process, if asked."""
    if args.placed_orientations is not None:
        from features import orientation

        if args.placed_orientations < 0:
            raise SystemExit("--placed-orientations must be 0 or more")
        orientation.PLACED_ORIENTATIONS = args.placed_orientations


def network_extractor(checkpoint: str, **options):
    """The extractor of ``--checkpoint``: one network, or the ensemble of a comma-separated list.

    ``options`` go to each network's ``LearnedExtractor`` (e.g. ``turn_part_targets``).
    """
    from features.learned import EnsembleExtractor, LearnedExtractor

    paths = [path for path in checkpoint.split(",") if path]
    return LearnedExtractor(paths[0], **options) if len(paths) == 1 else EnsembleExtractor(paths, **options)


def part_manifest(parts: Path) -> list[dict]:
    """The parts ``make_partial.py`` wrote to ``parts``: one dict per part (its name, shape, kind)."""
    return json.loads((parts / "partial.json").read_text())["parts"]


def partial_to_full_runs(manifest: list[dict], pairs: str, folder: ShapeFolder) -> list[tuple[str, str]]:
    """(part, whole shape) of every partial-to-full run: each part against the other shape of each pair."""
    return [
        (row["part"], b if row["shape"] == a else a)
        for a, b in read_pairs_file(pairs, folder.names)
        for row in manifest
        if row["shape"] in (a, b)
    ]


def merged_slices(paths: list[Path], out: Path, note: str) -> dict:
    """Join the results of runs made in slices (``--runs``, e.g. one per core) into one file.

    The rows in the given order, the summary computed again over all of them, every slice's
    command line, and ``note`` (how they were run). Returns the summary.
    """
    parts = [json.loads(path.read_text()) for path in paths]
    rows = [row for part in parts for row in part["rows"]]
    merged = {"argv": [part["argv"] for part in parts], "note": note, "summary": summary(rows)}
    write_rows(out, rows, merged)  # its "argv" replaces this command's
    return merged["summary"]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["merge"]:
        return _merge_command(argv[1:])
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_part_options(parser, "a trained network, or 'wks' for WKS descriptors")
    parser.add_argument(
        "--mode",
        choices=("partial", "whole", "both"),
        default="partial",
        help="partial: each part against whole shapes; whole: the same forced as whole shapes; "
        "both: each part against the parts of the other shape of its pair (partial-to-partial)",
    )
    parser.add_argument(
        "--min-overlap",
        type=float,
        default=0.3,
        help="--mode both: only pairs of parts of which each truly shares at least this share of its area",
    )
    parser.add_argument(
        "--target-holes",
        type=int,
        default=None,
        metavar="SEED",
        help=f"the whole target with {TARGET_HOLES} small holes (two rings of faces each, seeded by SEED "
        "and its name), as a scanner leaves them; each reference point at its nearest vertex left",
    )
    parser.add_argument(
        "--any-hole-size",
        action="store_true",
        help="--target-holes: keep the first draw of centres, even where a hole spans over 1 %% of the area",
    )
    parser.add_argument(
        "--second-opinion",
        default=None,
        metavar="CHECKPOINT",
        help="a second network: a map judged suspect is matched again with both (spidermatch.match's "
        "second_opinion)",
    )
    parser.add_argument(
        "--turn-targets",
        type=int,
        default=None,
        metavar="SEED",
        help="--mode both: present the target part in a random rotation too (seeded by SEED and its name)",
    )
    parser.add_argument(
        "--turn-part-targets",
        action="store_true",
        help="--mode both: the network turns the target part onto its reference first (turn_part_targets)",
    )
    parser.add_argument(
        "--overlap-method",
        choices=("features", "matched", "reference"),
        default="features",
        help="--mode both: the source's overlap by the descriptors, by a matching with a void vertex, "
        "or read on the network's reference shape",
    )
    parser.add_argument(
        "--void-factor",
        type=float,
        default=None,
        help="--overlap-method matched: the void's cost factor (spidermatch.model.void.VOID_FACTOR)",
    )
    parser.add_argument(
        "--unit-scale",
        type=float,
        default=1.0,
        metavar="FACTOR",
        help="--mode both: both parts' coordinates times FACTOR (1000: millimetres, as scanners give them)",
    )
    parser.add_argument("--faces", type=int, default=1000)
    parser.add_argument("--time-limit", type=float, default=120.0)
    parser.add_argument("--runs", default=None, help="FIRST:STOP, a slice of the runs")
    parser.add_argument("--out", required=True, type=Path)
    args = parser.parse_args(argv)
    apply_part_search_options(args)
    if args.void_factor is not None:
        void.VOID_FACTOR = args.void_factor
    logging.basicConfig(level=logging.WARNING)
    folder = ShapeFolder(args.data)
    manifest = part_manifest(args.parts)
    if args.mode == "both":  # each part of a against each part of b: two scans of two people
        runs = overlap_runs(manifest, args, folder)
    else:
        runs = list(dict.fromkeys(partial_to_full_runs(manifest, args.pairs, folder)))
    runs = runs_slice(runs, args.runs)
    extractor = "wks"
    if args.checkpoint != "wks":
        extractor = network_extractor(args.checkpoint, turn_part_targets=args.turn_part_targets)
    args.second_network = network_extractor(args.second_opinion) if args.second_opinion else None
    columns = OVERLAP_COLUMNS if args.mode == "both" else COLUMNS
    run = run_overlap_pair if args.mode == "both" else run_pair
    run_and_write(
        runs,
        lambda part, target: run(part, args.parts, folder, target, args, extractor),
        columns,
        summary,
        args.out,
    )
    return 0


def overlap_runs(manifest: list[dict], args: argparse.Namespace, folder: ShapeFolder) -> list[tuple]:
    """(part, part) runs of ``--mode both``: each part of a against each part of b, for every pair
    (a, b) of ``args.pairs``, kept when each part truly shares at least ``args.min_overlap``."""
    runs = [
        (row["part"], other["part"])
        for a, b in read_pairs_file(args.pairs, folder.names)
        for row in manifest
        if row["shape"] == a
        for other in manifest
        if other["shape"] == b
    ]
    runs = list(dict.fromkeys(runs))
    if args.min_overlap > 0:  # pairs of scans that share little are left out
        runs = [run for run in runs if min(overlap_shares(args.parts, folder, run)) >= args.min_overlap]
    return runs


def runs_slice(runs: list, text: str | None) -> list:
    """``runs[first:stop]`` for ``text`` "FIRST:STOP"; all of them for None."""
    if not text:
        return runs
    first, stop = (int(part) for part in text.split(":"))
    return runs[first:stop]


def run_and_write(runs: list[tuple[str, str]], run_one, columns: tuple, summarise, out: Path) -> list[dict]:
    """Run every (part, target), printing each row and rewriting ``out`` (rows and summary) after each."""
    print(" | ".join(columns), flush=True)
    rows = []
    for part_name, target_name in runs:
        rows.append(run_one(part_name, target_name))
        print(format_row(rows[-1], columns, 4), flush=True)
        write_rows(out, rows, {"summary": summarise(rows)})
    print(json.dumps(summarise(rows), indent=2))
    return rows


def _merge_command(argv: list[str]) -> int:
    """``bench_partial.py merge --out X.json --note "..." A.json B.json``: see :func:`merged_slices`."""
    parser = argparse.ArgumentParser(prog="bench_partial.py merge", description=merged_slices.__doc__)
    parser.add_argument("slices", nargs="+", type=Path, help="result files of --runs slices, in order")
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--note", default="", help="how the slices were run (written beside them)")
    args = parser.parse_args(argv)
    print(json.dumps(merged_slices(args.slices, args.out, args.note), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
