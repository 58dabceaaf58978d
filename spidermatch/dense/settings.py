"""The options of a densification (:class:`DenseSettings`) and their checks.

Defaults come from ``conf/dense/default.yaml`` (:mod:`spidermatch.defaults`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields, replace

from spidermatch import defaults
from spidermatch.values import is_finite, is_whole

METHODS = ("deformation", "interp", "interp_features", "zoomout", "zoomout_local", "zoomout_accept")


_DEFAULTS = defaults.group("dense/default")


@dataclass(frozen=True)
class DenseSettings:
    """Parameters of the densification.

    Attributes
    ----------
    method : str
        One of :data:`METHODS`.
    radius : float
        Search radius around the interpolated image, in local low-resolution edge lengths
        (``deformation``: in the first round).
    distance_weight : float
        ``interp_features``: weight of (distance / radius)^2 against the feature
        distance ``1 - cos`` of the L2-normalised descriptors.
    n_neighbours : int
        Target vertices considered inside the radius (the nearest ones).
    spectral_start, spectral_stop, spectral_step : int
        ZoomOut's eigenfunction counts: start, stop (inclusive), step.
    spectral_feature_weight : float
        Weight of the descriptors appended to the spectral embedding (0: pure ZoomOut).
    smoothing : int
        Rounds of neighbour averaging of the image points (certified ones held fixed,
        except for ``deformation``), then one projection onto the target surface.
    fit_weight : float
        ``deformation``: weight of a vertex's feature match against the rigidity of its
        edges, per unit of (mean) vertex area.
    part_fit_weight : float
        ``deformation``: ``fit_weight`` for a source matched as a part of its target (the
        partial modes), whose features are less certain than a whole shape's
        (:meth:`for_part`).
    deformation_rounds : int
        ``deformation``: rounds of feature matching and fitting.
    inverse : bool
        Also map every target vertex back onto the source (:func:`inverse_map`).
    unfold : bool
        Round the image points to target vertices without folds or tears where a vertex
        within two edges avoids one (:mod:`spidermatch.dense.unfold`); else each takes its
        nearest corner.

    """

    method: str = _DEFAULTS["method"]
    radius: float = float(_DEFAULTS["radius"])
    distance_weight: float = float(_DEFAULTS["distance_weight"])
    n_neighbours: int = int(_DEFAULTS["n_neighbours"])
    spectral_start: int = int(_DEFAULTS["spectral_start"])
    spectral_stop: int = int(_DEFAULTS["spectral_stop"])
    spectral_step: int = int(_DEFAULTS["spectral_step"])
    spectral_feature_weight: float = float(_DEFAULTS["spectral_feature_weight"])
    smoothing: int = int(_DEFAULTS["smoothing"])
    fit_weight: float = float(_DEFAULTS["fit_weight"])
    part_fit_weight: float = float(_DEFAULTS["part_fit_weight"])
    deformation_rounds: int = int(_DEFAULTS["deformation_rounds"])
    inverse: bool = bool(_DEFAULTS["inverse"])
    unfold: bool = bool(_DEFAULTS["unfold"])

    def __post_init__(self) -> None:
        problems = settings_problems(asdict(self))
        if problems:
            raise ValueError("dense settings: " + "; ".join(problems))

    def for_part(self) -> DenseSettings:
        """These settings for a source matched as a part of its target: its own fit weight.

        A part's features find their partners less surely than a whole shape's (the FAUST_r
        partial networks' nearest-feature validation error is 0.058-0.069 on cut copies against
        0.028 on whole shapes), so its deformation leans more on rigidity (docs/dense_maps.md).
        """
        return replace(self, fit_weight=self.part_fit_weight)


WHOLE_SETTINGS = {
    "n_neighbours": 1,
    "spectral_start": 1,
    "spectral_stop": 1,
    "spectral_step": 1,
    "smoothing": 0,
    "deformation_rounds": 1,
}
"""Whole-number settings of :class:`DenseSettings` and their least values."""


REAL_SETTINGS = {
    "radius": "> 0",
    "distance_weight": ">= 0",
    "spectral_feature_weight": ">= 0",
    "fit_weight": "> 0",
    "part_fit_weight": "> 0",
}
"""Real-number settings of :class:`DenseSettings` and their allowed range."""


def settings_problems(values: Mapping) -> list[str]:
    """Why ``values`` (keys of :class:`DenseSettings`) are unusable, one ``key=value: rule`` each.

    Checked before any work, so that a bad dense option never ends a run after the solve.
    """
    known = {item.name for item in fields(DenseSettings)}
    problems = [
        f"{key}: unknown (choose from {', '.join(sorted(known))})" for key in values if key not in known
    ]
    if "method" in values and values["method"] not in METHODS:
        choices = ", ".join(METHODS)
        problems.append(f"method={values['method']!r}: unknown dense method; choose from {choices}")
    for key in ("inverse", "unfold"):
        if key in values and not isinstance(values[key], bool):
            problems.append(f"{key}={values[key]!r}: must be true or false")
    for key, least in WHOLE_SETTINGS.items():
        if key in values and (not is_whole(values[key]) or values[key] < least):
            problems.append(f"{key}={values[key]!r}: must be a whole number >= {least}")
    for key, allowed in REAL_SETTINGS.items():
        value = values.get(key, 1.0)
        if not is_finite(value) or (value <= 0 if allowed == "> 0" else value < 0):
            problems.append(f"{key}={value!r}: must be a finite number {allowed}")
    start, stop = values.get("spectral_start", 1), values.get("spectral_stop", 1)
    if is_whole(start) and is_whole(stop) and start > stop:
        problems.append(f"spectral_start={start} > spectral_stop={stop}: the schedule must grow")
    return problems
