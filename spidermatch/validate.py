"""One validation layer for options and inputs, run before any work.

Options (the composed configuration of ``spidermatch-match`` / ``spidermatch-eval``) are
checked as plain values: each problem names its option, e.g. ``solver.mip_rel_gap=-1:
must be >= 0 and < 1``. Inputs are checked as a pair: ground-truth files of equal
length, the same topology (genus and number of boundary loops) on both sides, and a
mesh not far below the requested resolution.
"""

from __future__ import annotations

import logging
from pathlib import Path

from spidermatch.dense.settings import settings_problems as dense_settings_problems
from spidermatch.geometry.mesh import Mesh, MeshError
from spidermatch.model.curve import MATCHINGS, TOUR_SETTINGS
from spidermatch.solve.types import FLOW_ROWS_VALUES
from spidermatch.values import is_finite, is_number, is_whole, show

logger = logging.getLogger(__name__)

MIN_RESOLUTION = 4  # a tetrahedron: the coarsest closed triangle mesh
MIN_FEATURE_VERTICES = 500  # below this the decimated copy loses the eigenpairs features need
PRESOLVE_VALUES = ("choose", "on", "off")
DECIMATIONS = ("shortest_edge", "qslim")
REQUIRED_FAMILY = "CYC"  # every other family constrains the per-layer choice that CYC makes


class OptionError(ValueError):
    """One or more options have unusable values; the message names each option."""


def resolution_problem(value, key: str = "resolution") -> str | None:
    """Why ``value`` is not a usable face count (None if it is; None itself means 'the default')."""
    if value is None:
        return None
    if not is_whole(value) or value < MIN_RESOLUTION:
        return f"{key}={show(value)}: must be a whole number of faces >= {MIN_RESOLUTION}"
    return None


def feature_cap_problem(value, key: str = "features_max_vertices") -> str | None:
    """Why ``value`` is not a usable feature vertex cap (None and 0 mean no cap)."""
    if value is None or (is_whole(value) and (value == 0 or value >= MIN_FEATURE_VERTICES)):
        return None
    return f"{key}={show(value)}: must be a whole number of vertices >= {MIN_FEATURE_VERTICES} (0: no cap)"


def solver_problems(solver, strategies, prefix: str = "solver.") -> list[str]:
    """Problems with the ``solver`` option group (time_limit, mip_rel_gap, threads, presolve, ...).

    ``prefix`` starts every option's name in the messages (the Python API passes "", as its
    keywords are ``time_limit=``, ``mip_rel_gap=``, ``strategy=``).
    """
    problems = []
    limit = solver.get("time_limit")
    if not is_number(limit) or limit <= 0:
        problems.append(f"{prefix}time_limit={show(limit)}: must be a number of seconds > 0 (or inf)")
    gap = solver.get("mip_rel_gap")
    if not is_number(gap) or not 0 <= gap < 1:
        problems.append(f"{prefix}mip_rel_gap={show(gap)}: must be a number >= 0 and < 1")
    threads = solver.get("threads")
    if not is_whole(threads) or threads < 0:
        problems.append(f"{prefix}threads={show(threads)}: must be a whole number >= 0 (0: HiGHS chooses)")
    if solver.get("presolve") not in PRESOLVE_VALUES:
        problems.append(
            f"{prefix}presolve={show(solver.get('presolve'))}: choose from {', '.join(PRESOLVE_VALUES)}"
        )
    if solver.get("flow_rows", "found") not in FLOW_ROWS_VALUES:
        problems.append(
            f"{prefix}flow_rows={show(solver.get('flow_rows'))}: choose from {', '.join(FLOW_ROWS_VALUES)}"
        )
    if solver.get("strategy") not in strategies:
        problems.append(
            f"{prefix}strategy={show(solver.get('strategy'))}: choose from {', '.join(strategies)}"
        )
    share = solver.get("memory_share", 1.0)
    if not is_number(share) or not 0 < share <= 1:
        problems.append(f"{prefix}memory_share={show(share)}: must be a number > 0 and <= 1")
    for flag in ("log", "isolate", "lp_cuts"):
        if not isinstance(solver.get(flag, False), bool):
            problems.append(f"{prefix}{flag}={show(solver.get(flag))}: must be true or false")
    return problems


def constraints_problem(value, families) -> str | None:
    """Why ``costs.constraints`` is not a usable set of constraint families (None if it is)."""
    if isinstance(value, str) or not hasattr(value, "__iter__"):
        return f"costs.constraints={show(value)}: must be a list such as [{', '.join(families)}]"
    names = list(value)
    if not names:
        return f"costs.constraints=[]: give at least {REQUIRED_FAMILY} (choose from {', '.join(families)})"
    unknown = [name for name in names if name not in families]
    if unknown:
        return f"costs.constraints: unknown families {unknown}; choose from {', '.join(families)}"
    if len(set(names)) != len(names):
        return f"costs.constraints={names}: a family is named twice"
    if REQUIRED_FAMILY not in names:
        return (
            f"costs.constraints={names}: {REQUIRED_FAMILY} is required (it makes the curve cross "
            "every layer once; the other families only constrain that choice)"
        )
    return None


def costs_and_curve_problems(cfg) -> list[str]:
    """Problems with the ``costs`` (apart from constraints) and ``curve`` option groups."""
    problems = []
    for key in ("alpha", "scale", "bowl_exponent"):
        value = cfg.costs.get(key)
        if not is_finite(value):
            problems.append(f"costs.{key}={show(value)}: must be a finite number")
    scale = cfg.costs.get("scale")
    if is_number(scale) and scale <= 0:
        problems.append(f"costs.scale={show(scale)}: must be > 0")
    for key, group in (("target_augmented", cfg.costs), ("augmented", cfg.curve)):
        if not isinstance(group.get(key), bool):
            problems.append(f"{'costs' if group is cfg.costs else 'curve'}.{key}: must be true or false")
    if not isinstance(cfg.curve.get("close_small_holes", True), bool):
        problems.append(
            f"curve.close_small_holes={show(cfg.curve.get('close_small_holes'))}: must be true or false"
        )
    if not is_whole(cfg.curve.get("seed")):
        problems.append(f"curve.seed={show(cfg.curve.get('seed'))}: must be a whole number")
    if cfg.curve.get("decimation") not in DECIMATIONS:
        problems.append(
            f"curve.decimation={show(cfg.curve.get('decimation'))}: choose from {', '.join(DECIMATIONS)}"
        )
    problems.append(tour_problem(cfg.curve.get("tour", "christofides"), "curve.tour"))
    if cfg.curve.get("matching", "greedy") not in MATCHINGS:
        problems.append(
            f"curve.matching={show(cfg.curve.get('matching'))}: choose from {', '.join(MATCHINGS)}"
        )
    return problems


PATH_OPTIONS = ("source", "target", "source_corr", "target_corr", "checkpoint", "second_opinion")
OUTPUT_SWITCHES = ("matches_csv", "result_json", "png", "viewer")


def path_problems(cfg) -> list[str]:
    """File options must be single paths (``target=[1,2]`` is a list, not a file)."""
    problems = []
    for key in PATH_OPTIONS:
        value = cfg.get(key)
        if value is not None and not isinstance(value, str):
            problems.append(f"{key}={value}: must be one file path")
    return problems


def dense_and_output_problems(cfg) -> list[str]:
    """Problems with the ``dense`` and ``output`` option groups (checked before any work)."""
    problems = []
    dense = cfg.get("dense")
    if dense is not None:
        if not isinstance(dense.get("enabled"), bool):
            problems.append(f"dense.enabled={show(dense.get('enabled'))}: must be true or false")
        values = {key: value for key, value in dense.items() if key != "enabled"}
        problems += [f"dense.{problem}" for problem in dense_settings_problems(values)]
    output = cfg.get("output")
    if output is not None:
        for key in OUTPUT_SWITCHES:
            if key in output and not isinstance(output.get(key), bool):
                problems.append(f"output.{key}={show(output.get(key))}: must be true or false")
    return problems


def check_options(cfg) -> None:
    """Validate every option that decides a match; raise :class:`OptionError` listing all problems.

    Parameters
    ----------
    cfg : DictConfig or mapping
        Needs ``resolution`` and the groups ``solver``, ``costs`` and ``curve``; ``dense``,
        ``output`` and the file options are checked where present.

    """
    from spidermatch.model.ilp import FAMILIES
    from spidermatch.solve.strategies import AUTO

    problems = [
        resolution_problem(cfg.get("resolution")),
        feature_cap_problem(cfg.get("features_max_vertices")),
    ]
    problems += solver_problems(cfg.solver, [AUTO, *strategy_names()])
    problems.append(constraints_problem(cfg.costs.get("constraints"), FAMILIES))
    problems += costs_and_curve_problems(cfg)
    problems += path_problems(cfg) + dense_and_output_problems(cfg)
    problems.append(second_opinion_problem(cfg))
    raise_problems(problems)


def second_opinion_problem(cfg) -> str | None:
    """``second_opinion`` (a second network's checkpoint) needs learned features and an existing file."""
    second = cfg.get("second_opinion")
    if second is None or not isinstance(second, str):
        return None  # none asked, or not a path (path_problems says so)
    features = cfg.get("features")
    if features is None or "checkpoint" not in features:
        return f"second_opinion={second}: needs features=learned (the second network is joined to the first)"
    if not Path(second).is_file():
        return f"second_opinion={second}: no such file"
    return None


def strategy_names() -> list[str]:
    """Every solving strategy's name, sorted (``auto`` apart)."""
    from spidermatch.solve.strategies import LAZY_STRATEGIES, STRATEGIES

    return sorted({*STRATEGIES, *LAZY_STRATEGIES})


def raise_problems(problems: list) -> None:
    """Raise one :class:`OptionError` listing every problem (None entries are no problem)."""
    problems = [p for p in problems if p]
    if problems:
        raise OptionError("bad option: " + "; ".join(problems))


def check_settings(settings, solver_prefix: str = "solver.") -> None:
    """Validate a :class:`~spidermatch.pipeline.MatchSettings` as :func:`check_options` does the config.

    The Python API and every other caller of :func:`spidermatch.pipeline.match` get the
    same checks, with the same messages, as the command line (``resolution=150.9``, a text
    ``'150'`` or ``time_limit=nan`` are refused, never truncated or passed on).
    ``solver_prefix`` starts the solver options' names in the messages (see :func:`solver_problems`).

    Raises
    ------
    OptionError
        Listing every problem, each naming its setting.

    """
    import dataclasses

    from spidermatch.model.ilp import FAMILIES

    solver = {
        **dataclasses.asdict(settings.solver),
        "strategy": settings.strategy,
        "isolate": settings.isolate_solver,
    }
    problems = [resolution_problem(settings.resolution)]
    problems += solver_problems(solver, strategy_names(), solver_prefix)
    problems.append(constraints_problem(settings.constraints, FAMILIES))
    if settings.decimation not in DECIMATIONS:
        problems.append(f"decimation={show(settings.decimation)}: choose from {', '.join(DECIMATIONS)}")
    problems.append(tour_problem(settings.curve_tour, "curve_tour"))
    raise_problems(problems)


def tour_problem(tour, name: str) -> str | None:
    """The problem with a SpiderCurve tour setting named ``name``, or None."""
    if tour in TOUR_SETTINGS:
        return None
    return f"{name}={show(tour)}: choose from {', '.join(TOUR_SETTINGS)}"


def check_ground_truth(source_corr, target_corr, source_name: str, target_name: str) -> list[str]:
    """Ground-truth files of a pair must have the same number of points (row k corresponds).

    Returns the warnings: with only one of the two given (a missing ``.vts`` file in a dataset)
    no error can be measured, and the warning (logged too) says which file is missing.
    """
    if (source_corr is None) != (target_corr is None):
        missing, other = (source_name, target_name) if source_corr is None else (target_name, source_name)
        warning = f"{missing} is missing ({other} is there): the pair's error is not measured"
        logger.warning("%s", warning)
        return [warning]
    if source_corr is not None and len(source_corr) != len(target_corr):
        raise MeshError(
            f"ground-truth files of different lengths: {source_name} has {len(source_corr)} points, "
            f"{target_name} has {len(target_corr)} (row k of the two files must correspond)"
        )
    return []


def coarseness_warnings(meshes: tuple[Mesh, ...], resolution: int) -> list[str]:
    """Warnings for meshes with fewer faces than the requested resolution (they are not refined)."""
    warnings = []
    for mesh in meshes:
        if mesh.n_faces < resolution:
            warnings.append(
                f"{mesh.name} has only {mesh.n_faces} faces, fewer than resolution={resolution}: it is "
                "matched as it is, and the matching is only as fine as this mesh"
            )
    for text in warnings:
        logger.warning("%s", text)
    return warnings
