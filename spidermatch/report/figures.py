"""The pictures of one match run: correspondence, SpiderCurve, texture, error heat map and HTML viewer."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spidermatch.geometry.mesh import Mesh
from spidermatch.shutdown import atomic_path

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class MatchPictures:
    """What the pictures of a match show.

    Attributes
    ----------
    source, target : Mesh
        Full-resolution meshes.
    low_source : Mesh
        The low-resolution source the SpiderCurve runs on.
    curve_vertices : np.ndarray, shape (L,)
        The SpiderCurve (vertices of ``low_source``).
    matches : np.ndarray, shape (V_src,) or (N, 2)
        Dense ``src_to_tgt`` map, or sparse (source, target) full-resolution pairs.
    title, status : str
        Title line (paths are shortened in the PNGs) and status line.
    target_covered : np.ndarray, shape (V_tgt,) bool, optional
        The target region a partial source covers; the rest is drawn greyed out.
    """

    source: Mesh
    target: Mesh
    low_source: Mesh
    curve_vertices: np.ndarray
    matches: np.ndarray
    title: str
    status: str
    target_covered: np.ndarray | None = None


DISPLAY_FACES = 100_000
"""Faces a mesh may have in the pictures and the viewer; a larger one is decimated for display."""


def for_display(
    pictures: MatchPictures, errors: tuple[np.ndarray, np.ndarray] | None = None
) -> tuple[MatchPictures, tuple[np.ndarray, np.ndarray] | None]:
    """``pictures`` (and ``errors``) on meshes of at most :data:`DISPLAY_FACES` faces.

    A larger mesh is decimated for display only; the map is carried over through the display
    vertices' nearest full-resolution vertices, so the pictures and the viewer cost the same
    whatever the input's size (the outputs' files keep every vertex).
    """
    import dataclasses

    from scipy.spatial import cKDTree

    from spidermatch.geometry.remesh import decimate

    if max(pictures.source.n_faces, pictures.target.n_faces) <= DISPLAY_FACES:
        return pictures, errors
    shown = [decimate(mesh, min(mesh.n_faces, DISPLAY_FACES)) for mesh in (pictures.source, pictures.target)]
    on_source, on_target = (cKDTree(low.mesh.verts) for low in shown)
    matches = np.asarray(pictures.matches)
    if matches.ndim == 1:  # a dense map: every display source vertex through its full vertex
        image = pictures.target.verts[matches[shown[0].to_full]]
        matches = np.asarray(on_target.query(image)[1], dtype=np.int64)
    else:
        matches = np.stack(
            [
                on_source.query(pictures.source.verts[matches[:, 0]])[1],
                on_target.query(pictures.target.verts[matches[:, 1]])[1],
            ],
            axis=1,
        )
    if errors is not None:
        errors = (np.asarray(on_source.query(pictures.source.verts[errors[0]])[1]), errors[1])
    covered = pictures.target_covered
    if covered is not None:
        covered = np.asarray(covered)[shown[1].to_full]
    small = dataclasses.replace(
        pictures, source=shown[0].mesh, target=shown[1].mesh, matches=matches, target_covered=covered
    )
    logger.info(
        "pictures drawn on meshes decimated to %d and %d faces", shown[0].mesh.n_faces, shown[1].mesh.n_faces
    )
    return small, errors


def status_line(report: dict) -> str:
    """``optimal, gap 0.0e+00 | 1000 faces, wks features`` from a run's ``result.json`` figures."""
    gap = report.get("gap")
    parts = [f"{report.get('status', '?')}, gap " + (f"{gap:.1e}" if gap is not None else "unknown")]
    if report.get("resolution"):
        parts.append(f"{report['resolution']} faces, {report.get('features', '?')} features")
    return " | ".join(parts)


def map_errors(
    pictures: MatchPictures, source_corr: np.ndarray, target_corr: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Geodesic error of the map at the source points where it can be judged.

    Returns
    -------
    vertices : np.ndarray, shape (N,)
        Source vertices: the reference points (dense map) or the matched vertices (pairs).
    errors : np.ndarray, shape (N,)
        Fraction of sqrt(target area).
    """
    from spidermatch.eval.errors import dense_map_errors, sparse_map_errors

    matches = np.asarray(pictures.matches)
    if matches.ndim == 1:
        evaluation = dense_map_errors(matches, source_corr, target_corr, pictures.target)
        return np.asarray(source_corr), evaluation.errors
    evaluation = sparse_map_errors(
        matches[:, 0], matches[:, 1], pictures.source, source_corr, target_corr, pictures.target
    )
    return matches[:, 0], evaluation.errors


def write_match_pictures(
    output_dir: Path,
    pictures: MatchPictures,
    errors: tuple[np.ndarray, np.ndarray] | None = None,
    viewer: bool = True,
) -> list[Path]:
    """Write the PNGs and ``viewer.html`` of a match.

    ``correspondence.png``, ``spider_curve.png``, ``texture.png`` (with a dense map),
    ``error.png`` (with errors) and ``viewer.html``.

    Parameters
    ----------
    output_dir : Path
    pictures : MatchPictures
    errors : tuple of np.ndarray, optional
        (source vertices (N,), geodesic errors (N,)), e.g. from :func:`map_errors`.
    viewer : bool
        Also write the interactive ``viewer.html``.

    Returns
    -------
    list of Path
        The files written.
    """
    from spidermatch.report.plot import (
        save_correspondence_png,
        save_curve_png,
        save_error_png,
        save_texture_png,
    )

    output_dir = Path(output_dir)
    p, errors = for_display(pictures, errors)
    jobs = [
        (
            "correspondence.png",
            save_correspondence_png,
            (p.source, p.target, p.matches),
            (p.title, p.status, p.target_covered),
        ),
        ("spider_curve.png", save_curve_png, (p.low_source, p.curve_vertices), ("", p.status)),
    ]
    if np.asarray(p.matches).ndim == 1:  # a dense map: the texture transfer too
        labels = (p.title, p.status, p.target_covered)
        jobs.append(("texture.png", save_texture_png, (p.source, p.target, p.matches), labels))
    if errors is not None:
        jobs.append(("error.png", save_error_png, (p.source, *errors), (p.title, p.status)))
    if viewer:
        from spidermatch.report.viewer import save_match_viewer

        jobs.append(
            (
                "viewer.html",
                save_match_viewer,
                (p.source, p.target, p.matches),
                (p.title, p.status, errors, p.target_covered),
            )
        )
    paths = []
    for name, save, data, labels in jobs:
        with atomic_path(output_dir / name) as tmp:  # no half picture is ever left; OSError -> OutputError
            save(*data, tmp, *labels)
        paths.append(output_dir / name)
        logger.info("wrote %s", output_dir / name)
    return paths
    for path in paths:
        logger.info("wrote %s", path)
    return paths
