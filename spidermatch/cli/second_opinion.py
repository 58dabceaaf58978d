"""The command line's second opinion: a map judged suspect is matched again with a second network.

``second_opinion=PATH`` (with ``features=learned``) names a second training of the network. Only a
run whose map the quality verdict calls suspect (judged with the dense map when there is one)
asks it: the pair is matched again with both networks' features joined
(:func:`spidermatch.pipeline.joined_features`), and the second map replaces the first, in every
file, if its verdict is plausible. With ``partial=both`` the joined features first search the
source's overlap again (:class:`OverlapSearch`), so the second map may match another piece. The
first map's files are written before; a second opinion that fails leaves them as they are.
Measured in docs/partial.md.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from functools import partial
from pathlib import Path

from spidermatch import shutdown
from spidermatch.cli.inputs import MatchInputs, OverlapSearch
from spidermatch.cli.outputs import result_summary, write_dense, write_interim_result, write_matching
from spidermatch.pipeline import (
    MatchResult,
    MatchSettings,
    joined_features,
    kept_opinion,
    match,
    matched_with_second_opinion,
)

logger = logging.getLogger("spidermatch.match")


@dataclasses.dataclass
class Opinion:
    """The map a run ends with: its result, the features it was matched with, its ground-truth errors."""

    result: MatchResult
    features: tuple
    picture_errors: tuple | None
    inputs: MatchInputs  # as matched: with partial=both, the source cut to the piece


def second_opinion_stage(
    cfg,
    output_dir: Path,
    settings: MatchSettings,
    first: Opinion,
    get_second_features,
    report: dict,
    search: OverlapSearch | None = None,
) -> Opinion:
    """Ask the second opinion about ``first`` (judged suspect); the opinion the run ends with.

    Parameters
    ----------
    cfg : DictConfig
    output_dir : Path
    settings : MatchSettings
        The run's settings (with its dense settings; with ``partial=both``, before the overlap's
        own solve took its share of the time).
    first : Opinion
        The suspect map, its files already written.
    get_second_features : callable (MatchInputs) -> (features_x (V_X, D), features_y (V_Y, D))
        The second network's features of the run's meshes.
    report : dict
        ``result.json`` so far: gets ``second_opinion`` and, when the second map is kept, its
        figures (and with ``partial=both`` its ``overlap``) in place of the first's.
    search : OverlapSearch, optional
        With ``partial=both``: the overlap is searched again with the joined features.

    Returns
    -------
    Opinion
        ``first``, or the second map when it is judged plausible (its files written).
    """
    logger.info("the map is judged suspect: asking the second opinion (%s)", cfg.second_opinion)
    started = time.perf_counter()
    try:
        rematch = _whole_opinion if search is None else partial(_overlap_opinion, search=search)
        kept, features, inputs, overlap = rematch(first, get_second_features, settings)
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
    if overlap is not None:
        report["overlap"] = overlap
    report.update(result_summary(kept, inputs, report["features"]))
    report.update(status="writing", solver_status=kept.solve.status, quality=kept.quality)
    report["timings_s"] = {**timings, "second_opinion": seconds}
    report["second_opinion"] = {**kept.second_opinion, "time_s": seconds}
    picture_errors = write_matching(cfg, output_dir, kept, inputs, report)
    write_interim_result(cfg, output_dir, report)
    if kept.dense is not None:
        dense_errors = write_dense(output_dir, kept, inputs, features, report)
        picture_errors = None if dense_errors is None else (inputs.source_corr, dense_errors)
    return Opinion(kept, features, picture_errors, inputs)


def _whole_opinion(first: Opinion, get_second_features, settings: MatchSettings) -> tuple:
    """The pair ``first`` matched, matched again with the two networks' features joined.

    Returns
    -------
    kept : MatchResult
        ``first.result`` or the second map (:func:`spidermatch.pipeline.kept_opinion`).
    features : tuple of np.ndarray
        The kept map's features, (V_X, D) and (V_Y, D).
    inputs : MatchInputs
        ``first.inputs``.
    overlap : None
        (The overlap's record of :func:`_overlap_opinion`.)
    """
    inputs = first.inputs
    second = get_second_features(inputs)
    kept, features = matched_with_second_opinion(
        first.result, inputs.source, inputs.target, first.features, second, settings
    )
    return kept, features, inputs, None


def _overlap_opinion(first: Opinion, get_second_features, settings: MatchSettings, search) -> tuple:
    """``partial=both``: the overlap searched again and matched with the two networks' features joined.

    ``search`` (:class:`OverlapSearch`) says where the first search ran.

    Returns
    -------
    kept : MatchResult
        ``first.result`` or the second map (:func:`spidermatch.pipeline.kept_opinion`).
    features : tuple of np.ndarray or None
        The second map's piece and target features, (V_piece, D) and (V_Y, D), when it is kept.
    inputs : MatchInputs or None
        The inputs cut to the second map's piece, when it is kept.
    overlap : dict or None
        ``result.json["overlap"]`` of the second map, when it is kept.
    """
    second = get_second_features(search.inputs)
    joined_x, joined_y = (joined_features(a, b) for a, b in zip(search.features, second))
    found: dict = {}
    inputs, piece_x, piece_settings = search.piece((joined_x, joined_y), found, settings)
    matched = match(inputs.source, inputs.target, piece_x, joined_y, piece_settings)
    search.read_target_overlap(matched, found["overlap"]["found_by"])
    kept = kept_opinion(first.result, matched)
    if kept is first.result:
        return kept, None, None, None
    return kept, (piece_x, joined_y), inputs, found["overlap"]
