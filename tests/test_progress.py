import logging
import math
import types

from spidermatch.solve.progress import ProgressLog, format_gap


def mip_data(incumbent, bound, nodes=3):
    return types.SimpleNamespace(mip_primal_bound=incumbent, mip_dual_bound=bound, mip_node_count=nodes)


def test_progress_lines_say_incumbent_bound_gap_and_time(caplog):
    progress = ProgressLog("MIP over 10 columns", interval=0.0)
    with caplog.at_level(logging.INFO, logger="spidermatch.solve.progress"):
        progress.mip(mip_data(math.inf, -math.inf, 0))
        progress.mip(mip_data(2.0, 1.5))
        progress.simplex(types.SimpleNamespace(simplex_iteration_count=42))
    lines = [record.getMessage() for record in caplog.records]
    assert lines[0].startswith("MIP over 10 columns: incumbent none, bound none, gap n/a, 0 nodes")
    assert "incumbent 2, bound 1.5, gap 25.00 %, 3 nodes" in lines[1]
    assert "42 simplex iterations" in lines[2]


def test_progress_is_rate_limited(caplog):
    progress = ProgressLog("LP", interval=3600.0)
    with caplog.at_level(logging.INFO, logger="spidermatch.solve.progress"):
        for _ in range(100):
            progress.mip(mip_data(2.0, 1.0))
    assert not caplog.records


def test_format_gap():
    assert format_gap(1.0, 1.0) == "0.00 %"
    assert format_gap(math.inf, 1.0) == "n/a" and format_gap(1e40, 1.0) == "n/a"
