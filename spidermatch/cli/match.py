"""One match run, stage by stage, with a final ``result.json`` whatever happens.

The run of ``spidermatch-match``, and of each pair of ``spidermatch-eval``. Exit codes: 0
certified (or time-limited with incumbent), 2 bad input, 3 infeasible, 4 no solution in time,
5 solver failure, 6 an output not written, 130/143 interrupted by SIGINT/SIGTERM (see
:mod:`spidermatch.shutdown`).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from functools import partial
from pathlib import Path

from spidermatch import shutdown
from spidermatch.api import wks_on_parts_hint
from spidermatch.cli.inputs import (
    INPUT_ERRORS,
    OverlapSearch,
    check_inputs,
    compute_features,
    load_inputs,
    overlap_reference,
    resolution_text,
    second_opinion_features,
)
from spidermatch.cli.outputs import (
    ForeignFolder,
    final_line,
    result_summary,
    stage_failed,
    start_run,
    write_dense,
    write_interim_result,
    write_matching,
    write_pngs,
)
from spidermatch.cli.second_opinion import Opinion, second_opinion_stage
from spidermatch.cli.settings import settings_from_config
from spidermatch.pipeline import (
    MatchError,
    add_dense_map,
    match,
    needs_second_opinion,
)
from spidermatch.validate import (
    check_options,
)
from spidermatch.versions import software_versions

logger = logging.getLogger("spidermatch.match")


def run_match(cfg, output_dir: Path) -> int:
    """Run one match and write its outputs into ``output_dir``; return the exit code."""
    second = partial(second_opinion_features, cfg) if cfg.get("second_opinion") else None
    return run_pair(
        cfg, output_dir, lambda: load_inputs(cfg), lambda inputs: compute_features(cfg, inputs), None, second
    )


def run_pair(
    cfg, output_dir: Path, get_inputs, get_features, record: dict | None = None, get_second_features=None
) -> int:
    """Load a pair, match it and write its outputs; ``result.json`` is written whatever happens.

    Options are validated first (:func:`spidermatch.validate.check_options`). A signal,
    bad input or an unwritable output ends the run with a final ``result.json`` (status
    ``interrupted``, ``input_error`` or ``output_error``; see :mod:`spidermatch.shutdown`).

    Parameters
    ----------
    cfg : DictConfig
        Needs the groups curve, costs, solver and output.
    output_dir : Path
    get_inputs : callable () -> MatchInputs
    get_features : callable (MatchInputs) -> (features_x (V_X, D), features_y (V_Y, D), name, details)
    record : dict, optional
        Extra entries for ``result.json`` (e.g. the eval's settings hash).
    get_second_features : callable (MatchInputs) -> (features_x (V_X, D), features_y (V_Y, D)), optional
        The second opinion's features (:mod:`spidermatch.cli.second_opinion`), asked only for
        a map judged suspect.

    Returns
    -------
    int
        The exit code (0 on success).
    """
    report: dict = {
        "status": "started",
        "output_dir": str(output_dir),
        "software": software_versions(),
        **(record or {}),
    }
    result_path = output_dir / "result.json" if cfg.output.result_json else None
    started = time.perf_counter()
    with shutdown.signals_handled():
        try:
            start_run(output_dir, result_path, report)
            check_options(cfg)
            code = run_stages(cfg, output_dir, report, (get_inputs, get_features, get_second_features))
        except (shutdown.RunInterrupted, OSError, *INPUT_ERRORS) as error:
            status, code, message, known = shutdown.final_status(error, INPUT_ERRORS)
            (logger.warning if status == "interrupted" else logger.error)("%s", message)
            if isinstance(error, ForeignFolder):  # its result.json, if any, is the user's too
                result_path = None
            report.update(known)
            report.update(status=status, proven_optimal=False, error=message, exit_code=code)
        with shutdown.signals_held():
            report["total_time_s"] = round(time.perf_counter() - started, 3)
            report["software"] = software_versions()  # torch too, if the features loaded it
            if result_path is not None:
                if shutdown.write_result(result_path, report):
                    logger.info("wrote %s", result_path)
                elif code == 0:
                    code = shutdown.EXIT_OUTPUT_ERROR
            logger.log(logging.INFO if code == 0 else logging.ERROR, "%s", final_line(report, code))
    return code


def run_stages(cfg, output_dir: Path, report: dict, getters: tuple) -> int:
    """Inputs, features, the match, the dense map and the files, each stage recorded in ``report``.

    ``getters``: ``get_inputs``, ``get_features`` and ``get_second_features`` (or None) of :func:`run_pair`.
    """
    get_inputs, get_features, get_second_features = getters
    inputs = get_inputs()
    report.update(input=inputs.description, resolution=inputs.resolution)
    inputs = check_inputs(cfg, inputs, report)
    logger.info("matching %s at %s", inputs.description, resolution_text(inputs))
    start = time.perf_counter()
    feat_x, feat_y, feature_name, details = get_features(inputs)
    feature_time = time.perf_counter() - start
    report["features"] = feature_name
    if details:
        report["feature_inputs"] = details
    logger.info("features (%s) done in %.2f s", feature_name, feature_time)
    settings = dataclasses.replace(
        settings_from_config(cfg, inputs.resolution, feature_name), partial=inputs.partial
    )
    search = None  # partial=both: where the overlap was searched, to read it or search it again
    run_settings = settings
    if inputs.overlap:  # partial=both: only the source's overlap with the target is matched
        method = cfg.get("partial_overlap", "features")
        reference = overlap_reference(cfg, inputs) if method == "reference" else None
        search = OverlapSearch(inputs, (feat_x, feat_y), method, reference)
        inputs, feat_x, settings = search.piece(search.features, report, settings)
    logger.info("solving strategy: %s", settings.strategy)
    result = match(
        inputs.source,
        inputs.target,
        feat_x,
        feat_y,
        dataclasses.replace(settings, dense=None),
        announce_quality=settings.dense is None,  # else add_dense_map does, judged with the dense map
    )
    report.update(result_summary(result, inputs, feature_name))
    report["timings_s"] = {"features": round(feature_time, 3), **report["timings_s"]}
    try:
        result.raise_for_status(wks_on_parts_hint(feature_name, inputs.partial or inputs.overlap))
    except MatchError as error:
        logger.error("%s", error)
        if report["status"] not in ("infeasible", "no_solution"):
            # e.g. a solution that fails the checker: never 'optimal' next to a failure
            report.update(solver_status=report["status"], status="solver_failure", proven_optimal=False)
        report.update(error=str(error), exit_code=error.exit_code)
        return error.exit_code
    status = report["status"]
    report.update(status="writing", solver_status=status)  # 'optimal' only once every output is written
    picture_errors = write_matching(cfg, output_dir, result, inputs, report)
    write_interim_result(cfg, output_dir, report)
    stage = "dense"
    try:
        if settings.dense is not None:
            add_dense_map(
                result, inputs.source, inputs.target, (feat_x, feat_y), settings.dense, settings.partial
            )
            report["timings_s"]["dense"] = round(result.timings["dense"], 3)
            report["quality"] = result.quality  # judged again with the dense map
            if search is not None:
                search.read_target_overlap(result, report["overlap"]["found_by"])
            stage = "dense outputs"
            dense_errors = write_dense(output_dir, result, inputs, (feat_x, feat_y), report)
            picture_errors = None if dense_errors is None else (inputs.source_corr, dense_errors)
        if get_second_features is not None and needs_second_opinion(result):
            stage = "second opinion"
            first = Opinion(result, (feat_x, feat_y), picture_errors, inputs)
            kept = second_opinion_stage(
                cfg, output_dir, run_settings, first, get_second_features, report, search
            )
            result, picture_errors, inputs = kept.result, kept.picture_errors, kept.inputs
            status = result.solve.status
        if cfg.output.png:
            stage = "pictures"
            viewer = bool(cfg.output.get("viewer", True))
            write_pngs(output_dir, result, inputs, {**report, "status": status}, viewer, picture_errors)
    except (MemoryError, shutdown.OutputError) as error:
        return stage_failed(report, stage, error)
    except Exception as error:  # a later stage's bug must not throw the certified matching away
        logger.debug("the %s stage failed", stage, exc_info=True)
        return stage_failed(report, stage, error)
    if not result.solve.proven_optimal:
        logger.warning(
            "the solver stopped early: this matching is NOT proven optimal (gap %.2e)", result.solve.gap
        )
    report.pop("solver_status")
    report.update(status=status, exit_code=0)
    return 0
