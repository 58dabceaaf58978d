"""The command line's second opinion: a map judged suspect is matched again with a second network.

``second_opinion=PATH`` (with ``features=learned``) names a second training of the network. Only a
run whose map the quality verdict calls suspect (judged with the dense map when there is one)
asks it: the pair is matched again with both networks' features joined
(:func:`spidermatch.pipeline.joined_features`), and the second map replaces the first, in every
file, if its verdict is plausible. The first map's files are written before; a second opinion
that fails leaves them as they are. Measured on partial-to-full pairs in docs/partial.md.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path

from spidermatch import shutdown
from spidermatch.cli.inputs import MatchInputs
from spidermatch.cli.outputs import result_summary, write_dense, write_interim_result, write_matching
from spidermatch.pipeline import MatchResult, MatchSettings, matched_with_second_opinion

logger = logging.getLogger("spidermatch.match")


@dataclasses.dataclass
class Opinion:
    """The map a run ends with: its result, the features it was matched with, its ground-truth errors."""

    result: MatchResult
    features: tuple
    picture_errors: tuple | None


def second_opinion_stage(
    cfg,
    output_dir: Path,
    inputs: MatchInputs,
    settings: MatchSettings,
    first: Opinion,
    get_second_features,
    report: dict,
) -> Opinion:
    """Ask the second opinion about ``first`` (judged suspect); the opinion the run ends with.

    Parameters
    ----------
    cfg : DictConfig
    output_dir : Path
    inputs : MatchInputs
    settings : MatchSettings
        The run's settings (with its dense settings).
    first : Opinion
        The suspect map, its files already written.
    get_second_features : callable (MatchInputs) -> (features_x (V_X, D), features_y (V_Y, D))
        The second network's features of the run's meshes.
    report : dict
        ``result.json`` so far: gets ``second_opinion`` and, when the second map is kept, its
        figures in place of the first's.

    Returns
    -------
    Opinion
        ``first``, or the second map when it is judged plausible (its files written).
    """
    logger.info("the map is judged suspect: asking the second opinion (%s)", cfg.second_opinion)
    started = time.perf_counter()
    try:
        second_features = get_second_features(inputs)
        kept, features = matched_with_second_opinion(
            first.result, inputs.source, inputs.target, first.features, second_features, settings
        )
    except shutdown.RunInterrupted as interrupted:  # what the second solve knew is not the first map's
        report["second_opinion"] = {"kept": "first", "interrupted": dict(interrupted.known)}
        interrupted.known.clear()
        raise
    except Exception as error:  # the second opinion must not cost the first map
        logger.warning("the second opinion failed (%s): the first map stands", error)
        logger.debug("second opinion", exc_info=True)
        report["second_opinion"] = {"kept": "first", "error": str(error)}
        return first
    seconds = round(time.perf_counter() - started, 3)
    if kept is first.result:
        report["second_opinion"] = {**kept.second_opinion, "time_s": seconds}
        return first
    timings = report["timings_s"]
    report.update(result_summary(kept, inputs, report["features"]))
    report.update(status="writing", solver_status=kept.solve.status, quality=kept.quality)
    report["timings_s"] = {**timings, "second_opinion": seconds}
    report["second_opinion"] = {**kept.second_opinion, "time_s": seconds}
    picture_errors = write_matching(cfg, output_dir, kept, inputs, report)
    write_interim_result(cfg, output_dir, report)
    if kept.dense is not None:
        dense_errors = write_dense(output_dir, kept, inputs, features, report)
        picture_errors = None if dense_errors is None else (inputs.source_corr, dense_errors)
    return Opinion(kept, features, picture_errors)
