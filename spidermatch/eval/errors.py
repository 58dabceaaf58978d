"""Princeton-protocol evaluation: normalised geodesic errors and cumulative error curves."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from spidermatch.geometry.geodesics import GeodesicDistances
from spidermatch.geometry.mesh import Mesh

logger = logging.getLogger(__name__)

DEFAULT_THRESHOLDS = np.linspace(0.0, 0.25, 101)


@dataclass(frozen=True)
class MapEvaluation:
    """Errors of a point map at the points where ground truth is known.

    Attributes
    ----------
    errors : np.ndarray, shape (N,)
        Geodesic error of each evaluated point, divided by sqrt(area of the target).
    n_approximated : int
        Evaluated source points that are not reference points themselves and
        borrowed the ground truth of the nearest reference point (sparse maps only).

    """

    errors: np.ndarray
    n_approximated: int = 0

    @property
    def mean(self) -> float:
        """Mean normalised geodesic error."""
        return float(self.errors.mean())

    def curve(self, thresholds: np.ndarray = DEFAULT_THRESHOLDS) -> tuple[np.ndarray, np.ndarray]:
        """Cumulative curve: thresholds (T,) and the fraction of errors <= each, shape (T,)."""
        return thresholds, cumulative_curve(self.errors, thresholds)


def cumulative_curve(errors: np.ndarray, thresholds: np.ndarray = DEFAULT_THRESHOLDS) -> np.ndarray:
    """Fraction of ``errors`` (N,) that are <= each threshold (T,), shape (T,)."""
    errors = np.sort(np.asarray(errors, dtype=np.float64))
    return np.searchsorted(errors, thresholds, side="right") / max(errors.size, 1)


def pointwise_geodesic_errors(
    target: Mesh,
    predicted: np.ndarray,
    truth: np.ndarray,
    geodesics: GeodesicDistances | None = None,
) -> np.ndarray:
    """Geodesic distance on ``target`` between predicted and true vertices, over sqrt(area).

    Parameters
    ----------
    target : Mesh
    predicted, truth : np.ndarray, shape (N,)
        Target vertex indices.
    geodesics : GeodesicDistances, optional
        Reuse a solver built on ``target``.

    Returns
    -------
    np.ndarray, shape (N,)

    """
    predicted = np.asarray(predicted, dtype=np.int64)
    truth = np.asarray(truth, dtype=np.int64)
    if predicted.shape != truth.shape:
        raise ValueError(f"predicted {predicted.shape} and truth {truth.shape} must have one shape")
    for label, indices in (("predicted", predicted), ("true", truth)):
        if indices.size and (indices.min() < 0 or indices.max() >= target.n_verts):
            raise ValueError(
                f"{label} target vertex out of range for {target.name} ({target.n_verts} vertices)"
            )
    errors = np.zeros(predicted.shape, dtype=np.float64)
    wrong = predicted != truth
    if wrong.any():
        geodesics = geodesics or GeodesicDistances(target)
        errors[wrong] = geodesics.between(truth[wrong], predicted[wrong], progress=True)
    return errors / np.sqrt(target.area)


def dense_map_errors(
    src_to_tgt: np.ndarray,
    src_corr: np.ndarray,
    tgt_corr: np.ndarray,
    target: Mesh,
    geodesics: GeodesicDistances | None = None,
) -> MapEvaluation:
    """Evaluate a dense map at the K shared reference points.

    Parameters
    ----------
    src_to_tgt : np.ndarray, shape (V_src,)
        Target vertex of every source vertex.
    src_corr, tgt_corr : np.ndarray, shape (K,)
        Reference points: source vertex ``src_corr[k]`` corresponds to ``tgt_corr[k]``.
    target : Mesh

    """
    src_to_tgt = np.asarray(src_to_tgt, dtype=np.int64)
    _check_corr(src_corr, tgt_corr)
    if np.asarray(src_corr).max() >= src_to_tgt.size:
        raise ValueError(
            f"source reference index {int(np.max(src_corr))} beyond the map's {src_to_tgt.size} entries"
        )
    errors = pointwise_geodesic_errors(target, src_to_tgt[src_corr], tgt_corr, geodesics)
    return MapEvaluation(errors)


def nearest_feature_map(source_features: np.ndarray, target_features: np.ndarray) -> np.ndarray:
    """Target vertex of nearest descriptor (Euclidean) for every source vertex, shape (V_src,).

    The map the features alone give, without any solver: the usual yardstick of descriptors.

    Parameters
    ----------
    source_features : np.ndarray, shape (V_src, D)
    target_features : np.ndarray, shape (V_tgt, D)

    """
    from scipy.spatial import cKDTree

    return np.asarray(cKDTree(target_features).query(source_features)[1], dtype=np.int64)


def feature_map_errors(
    source_features: np.ndarray,
    target_features: np.ndarray,
    src_corr: np.ndarray,
    tgt_corr: np.ndarray,
    target: Mesh,
) -> MapEvaluation:
    """Errors of :func:`nearest_feature_map` at the K shared reference points, as :func:`dense_map_errors`."""
    return dense_map_errors(nearest_feature_map(source_features, target_features), src_corr, tgt_corr, target)


def sparse_map_errors(
    src_vertices: np.ndarray,
    tgt_vertices: np.ndarray,
    source: Mesh,
    src_corr: np.ndarray,
    tgt_corr: np.ndarray,
    target: Mesh,
    geodesics: GeodesicDistances | None = None,
) -> MapEvaluation:
    """Evaluate a map known only at some source vertices (e.g. the low-resolution ones).

    Each matched source vertex takes the ground truth of the reference point at
    that vertex, or, if it is not a reference point, of the nearest reference
    point on the source (Euclidean); the latter are counted in ``n_approximated``.

    Parameters
    ----------
    src_vertices, tgt_vertices : np.ndarray, shape (N,)
        Matched pairs in full-resolution vertex indices.
    source, target : Mesh
    src_corr, tgt_corr : np.ndarray, shape (K,)

    """
    src_vertices = np.asarray(src_vertices, dtype=np.int64)
    tgt_vertices = np.asarray(tgt_vertices, dtype=np.int64)
    _check_corr(src_corr, tgt_corr)
    ref_points = source.verts[src_corr]
    distance, nearest_ref = cKDTree(ref_points).query(source.verts[src_vertices])
    truth = np.asarray(tgt_corr)[nearest_ref]
    errors = pointwise_geodesic_errors(target, tgt_vertices, truth, geodesics)
    return MapEvaluation(errors, int(np.count_nonzero(distance > 0)))


def _check_corr(src_corr: np.ndarray, tgt_corr: np.ndarray) -> None:
    if np.shape(src_corr) != np.shape(tgt_corr):
        raise ValueError(
            "source and target correspondence files differ in length "
            f"({np.size(src_corr)} vs {np.size(tgt_corr)})"
        )
