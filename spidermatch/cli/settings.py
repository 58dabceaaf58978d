"""A run's configuration translated into :class:`~spidermatch.pipeline.MatchSettings`."""

from __future__ import annotations

from spidermatch.dense.settings import DenseSettings
from spidermatch.model.costs import RobustLoss
from spidermatch.pipeline import MatchSettings
from spidermatch.solve.strategies import strategy_for
from spidermatch.solve.types import SolverOptions


def settings_from_config(cfg, resolution: int, feature_name: str) -> MatchSettings:
    """Plain-value :class:`MatchSettings` from the composed config.

    ``feature_name`` (the extractor's name) decides ``solver.strategy=auto`` (:func:`strategy_for`).
    """
    solver = cfg.solver
    return MatchSettings(
        resolution=int(resolution),
        decimation=cfg.curve.decimation,
        curve_augmented=bool(cfg.curve.augmented),
        target_augmented=bool(cfg.costs.target_augmented),
        curve_seed=int(cfg.curve.seed),
        curve_matching=str(cfg.curve.matching),
        curve_tour=str(cfg.curve.get("tour", "christofides")),
        close_small_holes=bool(cfg.curve.get("close_small_holes", True)),
        loss=RobustLoss(float(cfg.costs.alpha), float(cfg.costs.scale), float(cfg.costs.bowl_exponent)),
        constraints=tuple(cfg.costs.constraints),
        solver=SolverOptions(
            time_limit=float(solver.time_limit),
            mip_rel_gap=float(solver.mip_rel_gap),
            threads=int(solver.threads),
            presolve=str(solver.presolve),
            log=bool(solver.log),
            flow_rows=str(solver.get("flow_rows", "found")),
            lp_cuts=bool(solver.get("lp_cuts", True)),
        ),
        strategy=strategy_for(str(solver.strategy), feature_name),
        isolate_solver=bool(solver.get("isolate", True)),
        dense=dense_settings(cfg),
    )


def dense_settings(cfg) -> DenseSettings | None:
    """:class:`DenseSettings` from the ``dense`` group, or None when ``dense.enabled=false`` (or no group)."""
    group = cfg.get("dense")
    if group is None or not group.enabled:
        return None
    return DenseSettings(**{key: value for key, value in group.items() if key != "enabled"})
