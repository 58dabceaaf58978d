"""The size of a match's ILP before anything is built, and whether it fits in memory.

The product graph of a SpiderCurve with L positions and a target mesh with E edges and V
vertices has L (4 E + V) columns (every directed edge twice, one stay edge per vertex; with
augmented target edges, E counts those). A closed triangle mesh of F faces has E = 3F/2 and
V = F/2 + 2 - 2g; the SpiderCurve visits every source vertex and some twice, L <= 1.25 V_X
on the meshes measured (``bench/bench_scaling.py``). So the columns grow with the product of
the two face counts, about 4 F_X F_Y, and a resolution at or above the meshes' own face
counts (which are then matched as they are) can ask for hundreds of GB.

:func:`check_model_fits` estimates the memory of the solve stage from the column count and
the bytes per column measured for each kind of strategy, and refuses with an
:class:`~spidermatch.validate.OptionError` naming ``resolution`` and the largest one that
fits, before any array is allocated.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from spidermatch.memory import GIB, available_memory
from spidermatch.validate import OptionError

logger = logging.getLogger(__name__)

CURVE_POSITIONS_PER_VERTEX = 1.25
"""Upper end of L / V_X (SpiderCurve positions per low-resolution source vertex)."""

BYTES_PER_COLUMN = {"colgen": 80, "full": 500}
"""Peak bytes per product-graph column: column generation (costs and pricing arrays of every
column) and strategies that build the full model (matrix, costs and HiGHS's copy of it)."""

BASE_BYTES = 1 << 30
"""What a match process holds besides the model (interpreter, libraries, meshes, features)."""

FULL_MODEL = "full"


@dataclass(frozen=True)
class ModelEstimate:
    """Expected size of a match's ILP.

    Attributes
    ----------
    faces_x, faces_y : int
        Faces the two meshes are matched at (the resolution, or fewer for coarser meshes).
    columns : int
        Product-graph columns (edges) of the full model.
    bytes : int
        Expected peak memory of the match process for the chosen strategy.

    """

    faces_x: int
    faces_y: int
    columns: int
    bytes: int


def expected_columns(faces_x: int, faces_y: int, target_augmented: bool = False) -> int:
    """Product-graph columns for meshes matched at ``faces_x`` and ``faces_y`` faces (an upper estimate)."""
    positions = CURVE_POSITIONS_PER_VERTEX * (faces_x / 2 + 2)
    edges_y = 1.5 * faces_y * (2.0 if target_augmented else 1.0)
    return int(math.ceil(positions * (4 * edges_y + faces_y / 2 + 2)))


def strategy_kind(strategy: str) -> str:
    """Say "colgen" for strategies that never build the full model, else "full"."""
    from spidermatch.solve.strategies import LAZY_STRATEGIES

    return "colgen" if strategy in LAZY_STRATEGIES else FULL_MODEL


def estimate(faces_x: int, faces_y: int, resolution: int, strategy: str, target_augmented: bool = False):
    """:class:`ModelEstimate` of matching meshes of ``faces_x`` and ``faces_y`` faces at ``resolution``."""
    low_x, low_y = min(faces_x, resolution), min(faces_y, resolution)
    columns = expected_columns(low_x, low_y, target_augmented)
    peak = BASE_BYTES + columns * BYTES_PER_COLUMN[strategy_kind(strategy)]
    return ModelEstimate(low_x, low_y, columns, int(peak))


def largest_fitting_resolution(room: int, strategy: str, target_augmented: bool = False) -> int:
    """The largest face count (a multiple of 100, at least 100) whose match fits in ``room`` bytes."""
    per_column = BYTES_PER_COLUMN[strategy_kind(strategy)]
    columns = max(room - BASE_BYTES, 0) / per_column
    low, high = 100, 1_000_000
    while high - low > 100:
        middle = (low + high) // 2
        if expected_columns(middle, middle, target_augmented) <= columns:
            low = middle
        else:
            high = middle
    return low // 100 * 100


def check_model_fits(
    faces: tuple[int, int],
    resolution: int,
    strategy: str,
    target_augmented: bool = False,
    room: int | None = None,
) -> ModelEstimate:
    """Refuse a match whose ILP would not fit in memory, before anything is built.

    Parameters
    ----------
    faces : (int, int)
        Face counts of the full-resolution source and target.
    resolution : int
        The requested resolution (faces after decimation).
    strategy : str
        The solving strategy (decides the bytes per column).
    target_augmented : bool
        Augmented target edges (about twice the columns).
    room : int, optional
        Bytes available; by default :func:`available_memory`.

    Returns
    -------
    ModelEstimate

    Raises
    ------
    OptionError
        The estimate exceeds the memory available; the message names ``resolution``, the
        estimate and the largest resolution that fits.

    """
    expected = estimate(faces[0], faces[1], resolution, strategy, target_augmented)
    room = available_memory() if room is None else room
    logger.debug("model estimate %s, %s bytes available", expected, room)
    if room is None or expected.bytes <= room:
        return expected
    coarser = ""
    if expected.faces_x < resolution or expected.faces_y < resolution:
        coarser = f" (the meshes have {faces[0]} and {faces[1]} faces, so they would be matched as they are)"
    fits = largest_fitting_resolution(room, strategy, target_augmented)
    raise OptionError(
        f"resolution={resolution}: matching at {expected.faces_x} x {expected.faces_y} faces{coarser} "
        f"needs a product graph of about {expected.columns:.2g} columns, an estimated "
        f"{expected.bytes / GIB:.1f} GiB with strategy {strategy}, but only {room / GIB:.1f} GiB of memory "
        f"is available; choose resolution={fits} or lower"
    )


BYTES_PER_INPUT_VERTEX = {"dense": 7 * 1024, "sparse": 2 * 1024}
"""Peak bytes per vertex of the two input meshes together, with and without the dense map: the
meshes, their features (capped, then carried to every vertex), the decimation and, with the
dense map, its search tables and consistency figures. Measured on large scans with
``bench/bench_user_copies.py`` (measurements: bench/README.md, solver constants) and rounded up
for the address space a process maps beyond what it touches."""


def check_meshes_fit(n_verts: tuple[int, int], dense: bool, room: int | None = None) -> int:
    """Refuse, before the features stage, a pair whose whole run would not fit in memory.

    Parameters
    ----------
    n_verts : (int, int)
        Vertices of the full-resolution source and target.
    dense : bool
        Whether the dense map (and its figures) will be made.
    room : int, optional
        Bytes available; by default :func:`available_memory`.

    Returns
    -------
    int
        The estimate in bytes.

    Raises
    ------
    OptionError
        The estimate exceeds the memory available; the message names the vertex counts, the
        estimate, and what to change (``dense.enabled=false``, or decimating the meshes).

    """
    total = int(n_verts[0]) + int(n_verts[1])
    needed = BASE_BYTES + BYTES_PER_INPUT_VERTEX["dense" if dense else "sparse"] * total
    room = available_memory() if room is None else room
    if room is None or needed <= room:
        return needed
    sparse_needed = BASE_BYTES + BYTES_PER_INPUT_VERTEX["sparse"] * total
    advice = decimation_advice(n_verts, int(max(room - BASE_BYTES, 0) / BYTES_PER_INPUT_VERTEX["dense"]))
    if dense and sparse_needed <= room:
        only_matches = f"the certified matches only, about {sparse_needed / GIB:.1f} GiB"
        advice = f"set dense.enabled=false ({only_matches}) or {advice}"
    what = "a match with its dense map" if dense else "a match"
    raise OptionError(
        f"meshes of {n_verts[0]:,} and {n_verts[1]:,} vertices: {what} needs an estimated "
        f"{needed / GIB:.1f} GiB, but only {room / GIB:.1f} GiB of memory is available; {advice}"
    )


def decimation_advice(n_verts: tuple[int, int], budget: int) -> str:
    """What to decimate so that the two meshes (source, target) hold at most ``budget`` vertices together.

    Only the larger mesh when the smaller one leaves it room (a raw scan against a template),
    else both to half the budget each.
    """
    small, large = sorted(int(n) for n in n_verts)
    if small <= budget // 2:
        which = "source" if int(n_verts[0]) == large else "target"
        return f"decimate the {which} (the larger mesh) to about {budget - small:,} vertices before matching"
    return f"decimate both meshes to about {budget // 2:,} vertices each before matching"
