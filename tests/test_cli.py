import csv
import json

import numpy as np
import pytest
from conftest import composed

from spidermatch.cli.match import run_match
from spidermatch.data.datasets import SyntheticShapes, write_dataset
from spidermatch.versions import spidermatch_version

# a generous time limit: on a loaded machine the 300 s default can stop a small solve
SMALL = ["data.n_verts=700", "resolution=60", "solver.time_limit=3600"]


def config(overrides):
    return composed("match", overrides)


@pytest.mark.parametrize("group", ["features=wks", "curve.augmented=true", "costs.target_augmented=true"])
def test_every_config_group_composes_and_runs(tmp_path, group):
    cfg = config(SMALL + [group])
    assert run_match(cfg, tmp_path) == 0
    result = json.loads((tmp_path / "result.json").read_text())
    assert result["status"] == "optimal" and result["check"]["ok"]
    assert result["bound"] <= result["objective"] + 1e-9
    assert set(result["timings_s"]) >= {"features", "decimate", "curve", "costs", "build", "solve", "check"}
    assert 0 <= result["geodesic_error"]["mean"] < 0.3
    rows = list(csv.reader((tmp_path / "matches.csv").open()))
    assert rows[0] == ["source_vertex", "target_vertex"]
    assert len(rows) - 1 == result["source_low_res"]["vertices"]
    assert (tmp_path / "correspondence.png").stat().st_size > 10_000
    assert (tmp_path / "spider_curve.png").stat().st_size > 10_000
    assert (tmp_path / "error.png").stat().st_size > 10_000  # the demo has ground truth
    assert (tmp_path / "viewer.html").stat().st_size > 10_000


def test_user_files_with_ground_truth(tmp_path):
    shapes = SyntheticShapes(n_shapes=2, n_verts=700)
    root = write_dataset(shapes, tmp_path / "data")
    cfg = config(
        [
            f"source={root}/off/creature_000.off",
            f"target={root}/off/creature_001.off",
            f"source_corr={root}/corres/creature_000.vts",
            f"target_corr={root}/corres/creature_001.vts",
            "resolution=60",
            "output.png=false",
        ]
    )
    out = tmp_path / "run"
    assert run_match(cfg, out) == 0
    result = json.loads((out / "result.json").read_text())
    assert result["resolution"] == 60 and "geodesic_error" in result
    pairs = np.loadtxt(out / "matches.csv", delimiter=",", skiprows=1, dtype=int)
    assert pairs[:, 0].max() < shapes.load("creature_000").mesh.n_verts
    assert pairs[:, 1].max() < shapes.load("creature_001").mesh.n_verts
    assert not (out / "correspondence.png").exists()
    assert not (out / "spider_curve.png").exists()
    assert not (out / "viewer.html").exists()


def test_bad_input_is_reported_with_exit_code_and_json(tmp_path):
    broken = tmp_path / "broken.off"
    broken.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n")
    good = (
        write_dataset(SyntheticShapes(n_shapes=1, n_verts=500), tmp_path / "d") / "off" / "creature_000.off"
    )
    cfg = config([f"source={broken}", f"target={good}"])
    assert run_match(cfg, tmp_path / "run") == 2
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["status"] == "input_error" and "broken.off" in result["error"]
    cfg = config([f"source={good}"])
    assert run_match(cfg, tmp_path / "run2") == 2
    assert "give both" in json.loads((tmp_path / "run2" / "result.json").read_text())["error"]


def test_time_limit_without_solution_exits_non_zero(tmp_path):
    cfg = config(SMALL + ["solver.time_limit=0.001"])
    code = run_match(cfg, tmp_path)
    result = json.loads((tmp_path / "result.json").read_text())
    if result["status"] == "feasible":  # HiGHS found an incumbent anyway: returned, not proven
        assert code == 0 and result["proven_optimal"] is False
    else:
        assert code == 4 and result["status"] == "no_solution" and "stopped" in result["error"]
        assert "raise solver.time_limit" in result["error"]  # and says what to do
        assert "the solver said:" in result["error"]  # its own words last, after the user's


def test_no_solution_messages_say_in_plain_words_what_the_solver_ran_into():
    from spidermatch.pipeline import why_no_solution

    cut = why_no_solution(
        "stopped early (on request, or to leave time for the repair); detached cycles cut off"
    )
    assert "separate loops, not one closed path" in cut
    relaxation = why_no_solution("LP relaxation not solved: Time limit reached")
    assert "symmetries" in relaxation and "resolution" in relaxation
    assert why_no_solution("Time limit reached") == ""


def test_learned_features_in_match(tmp_path, tiny_checkpoint):
    cfg = config(SMALL + ["features=learned", f"checkpoint={tiny_checkpoint}", "output.png=false"])
    assert run_match(cfg, tmp_path) == 0
    result = json.loads((tmp_path / "result.json").read_text())
    assert result["features"] == "learned" and result["check"]["ok"]
    # which code made it: spidermatch (with its commit in a checkout), HiGHS, and torch for the network
    software = result["software"]
    assert software["spidermatch"] == spidermatch_version() and software["highs"] and software["torch"]


def test_learned_features_need_a_usable_checkpoint(tmp_path):
    cfg = config(SMALL + ["features=learned"])
    assert run_match(cfg, tmp_path / "a") == 2
    assert "needs a trained network" in json.loads((tmp_path / "a" / "result.json").read_text())["error"]
    cfg = config(SMALL + ["features=learned", f"features.checkpoint={tmp_path / 'nope.pt'}"])
    assert run_match(cfg, tmp_path / "b") == 2
    assert "nope.pt: no such checkpoint" in json.loads((tmp_path / "b" / "result.json").read_text())["error"]


def test_a_log_file_that_cannot_be_written_prints_no_logging_tracebacks(tmp_path, capsys):
    """On a full disk the run folder's log file failed every record with '--- Logging error ---' and a
    traceback on the console; the command line lets that file drop such records quietly (the run's
    error says why), while a console handler keeps Python's default."""
    import logging

    from spidermatch.cli.main import configure_logging

    class FullDisk(logging.FileHandler):  # as Hydra's main.log on a full disk
        def emit(self, record):
            try:
                raise OSError(28, "No space left on device")
            except OSError:
                self.handleError(record)

    root = logging.getLogger()
    handler = FullDisk(tmp_path / "main.log", delay=True)
    root.addHandler(handler)
    try:
        configure_logging("INFO")
        logging.getLogger("spidermatch.test_full_disk").warning("a record")
    finally:
        root.removeHandler(handler)
    assert "Logging error" not in capsys.readouterr().err
