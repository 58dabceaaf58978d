import json
import os
import signal
import subprocess
import sys
import time

import pytest
from conftest import composed

from spidermatch.cli.batch import select_pairs
from spidermatch.cli.collect import main as collect_main
from spidermatch.cli.evaluate import run_eval
from spidermatch.data.datasets import SyntheticShapes, write_dataset

SMALL = ["resolution=60", "synthetic.n_verts=700"]


def config(overrides):
    return composed("eval", overrides)


BROKEN_OFF = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 9\n"  # a face naming a vertex the file lacks


def eval_setup(tmp_path, n_shapes: int, pair_lines: str, broken: str | None = None):
    """A synthetic dataset of ``n_shapes`` creatures (mesh ``broken`` made unreadable), its pairs file
    and the eval config over them."""
    root = write_dataset(SyntheticShapes(n_shapes=n_shapes, n_verts=700), tmp_path / "data")
    if broken is not None:
        (root / "off" / f"{broken}.off").write_text(BROKEN_OFF)
    pairs = tmp_path / "pairs.txt"
    pairs.write_text(pair_lines)
    return root, config(SMALL + [f"dataset={root}", f"pairs_file={pairs}"])


def test_select_pairs_is_seeded():
    names = ["a", "b", "c", "d"]
    pairs = [(x, y) for x in names for y in names if x != y]
    assert select_pairs(names, pairs, 3, seed=1) == select_pairs(names, pairs, 3, seed=1)
    assert len(select_pairs(names, pairs, 3, seed=1)) == 3
    assert select_pairs(names, pairs) == pairs


def test_more_pairs_extend_fewer_pairs():
    names = [f"s{i}" for i in range(6)]
    pairs = [(x, y) for x in names for y in names if x != y]
    for seed in (0, 1, 7):
        chosen = [set(select_pairs(names, pairs, n, seed=seed)) for n in range(1, len(pairs) + 1)]
        assert all(small < large for small, large in zip(chosen, chosen[1:]))
        assert all(len(c) == n for n, c in enumerate(chosen, start=1))
    assert select_pairs(names, pairs, 5, seed=0) != select_pairs(names, pairs, 5, seed=1)


def test_broken_mesh_is_reported_and_other_pairs_complete(tmp_path):
    lines = "creature_000 creature_001\ncreature_002 creature_000\ncreature_001 creature_000\n"
    _, cfg = eval_setup(tmp_path, 3, lines, broken="creature_002")
    assert run_eval(cfg, tmp_path / "run") == 0
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["pairs_finished"] == 3
    assert summary["statuses"] == {"optimal": 2, "input_error": 1}
    failure = summary["failures"][0]
    assert failure["source"] == "creature_002" and "creature_002.off" in failure["reason"]
    assert summary["geodesic_error"]["n"] == 2
    assert sum(summary["quality"].values()) == 2  # the verdicts of the two matched pairs
    csv_lines = (tmp_path / "run" / "summary.csv").read_text().splitlines()
    assert len(csv_lines) == 4 and csv_lines[0].startswith(
        "source,target,resolution,features,status,quality,"
    )
    assert (tmp_path / "run" / "errors.png").is_file()
    collect_main([str(tmp_path)])
    assert (tmp_path / "collected.csv").is_file() and (tmp_path / "curves.png").is_file()


def test_an_unwritable_summary_ends_the_eval_with_exit_6_and_no_half_files(tmp_path, monkeypatch, caplog):
    """A full disk while the summary was written: a raw OSError traceback and exit 1, with
    summary.json.tmp left; now exit 6 naming the file, and the same command resumes."""
    from spidermatch import shutdown

    _, cfg = eval_setup(tmp_path, 2, "creature_000 creature_001\ncreature_001 creature_000\n")

    real_mkstemp, calls = shutdown.tempfile.mkstemp, []

    def full_after_the_first_pair(*args, **kwargs):  # the disk fills while the first pair is written
        calls.append(kwargs.get("prefix"))
        if calls.count(".summary.") > 2:  # after the first summary.json and summary.csv
            raise OSError(28, "No space left on device")
        return real_mkstemp(*args, **kwargs)

    monkeypatch.setattr(shutdown.tempfile, "mkstemp", full_after_the_first_pair)
    assert run_eval(cfg, tmp_path / "run") == shutdown.EXIT_OUTPUT_ERROR
    assert "summary.json: cannot be written (No space left on device)" in caplog.text
    assert not list((tmp_path / "run").glob("*.tmp*"))
    monkeypatch.undo()
    caplog.clear()
    with caplog.at_level("INFO", logger="spidermatch"):
        assert run_eval(cfg, tmp_path / "run") == 0
    assert "skipping finished pair creature_000 -> creature_001" in caplog.text  # resumed, not redone
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["pairs_finished"] == 2


def test_an_eval_whose_every_pair_failed_does_not_exit_0(tmp_path):
    """Every pair's mesh broken: the eval ended with exit 0, as if it had succeeded."""
    lines = "creature_000 creature_001\ncreature_001 creature_000\n"
    _, cfg = eval_setup(tmp_path, 2, lines, broken="creature_001")
    assert run_eval(cfg, tmp_path / "run") == 2  # the pairs' own exit code: bad input
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["statuses"] == {"input_error": 2}


def test_a_missing_ground_truth_file_is_named_in_the_pair_s_warnings(tmp_path):
    """One .vts file missing: the pair's error was left out of the summary without a word."""
    root, cfg = eval_setup(tmp_path, 2, "creature_000 creature_001\n")
    (root / "corres" / "creature_001.vts").unlink()
    assert run_eval(cfg, tmp_path / "run") == 0
    result = json.loads(
        (tmp_path / "run" / "pairs" / "creature_000__creature_001" / "result.json").read_text()
    )
    assert any("creature_001.vts is missing" in warning for warning in result["warnings"]), result["warnings"]


def _finished(pairs_dir):
    """Modification times of the pairs' result.json files that are final (not 'started' or 'writing')."""
    return {
        p.parent.name: p.stat().st_mtime_ns
        for p in pairs_dir.glob("*/result.json")
        if json.loads(p.read_text())["status"] not in ("started", "writing")
    }


def test_killed_evaluation_resumes_only_missing_pairs(tmp_path):
    run_dir = tmp_path / "outputs" / "eval" / "resume"
    command = [sys.executable, "-m", "spidermatch.cli.eval", *SMALL, "synthetic.n_shapes=3", "name=resume"]
    process = subprocess.Popen(command, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    pairs_dir = run_dir / "pairs"
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and len(_finished(pairs_dir)) < 2:
        time.sleep(0.2)
        assert process.poll() is None, "evaluation ended before it could be interrupted"
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    done_before = _finished(pairs_dir)  # the pair in progress says 'started' and runs again
    assert 2 <= len(done_before) < 6
    finished = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert finished.returncode == 0, finished.stderr[-2000:]
    after = {p.parent.name: p.stat().st_mtime_ns for p in pairs_dir.glob("*/result.json")}
    assert len(after) == 6
    assert all(after[name] == stamp for name, stamp in done_before.items())  # not re-run
    assert (finished.stdout + finished.stderr).count("skipping finished pair") == len(done_before)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["pairs_finished"] == 6


def test_sweep_with_joblib_launcher_and_collect(tmp_path):
    command = [
        sys.executable,
        "-m",
        "spidermatch.cli.eval",
        "-m",
        "hydra/launcher=joblib",
        "hydra.launcher.n_jobs=2",
        *SMALL,
        "synthetic.n_shapes=2",
        "n_pairs=1",
        "curve.seed=0,1",
        "name=sweep",
    ]
    finished = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert finished.returncode == 0, finished.stderr[-2000:]
    sweep_dir = tmp_path / "multirun" / "eval" / "sweep"
    summaries = sorted(sweep_dir.glob("*/summary.json"))
    assert [s.parent.name for s in summaries] == ["0", "1"]
    collect_main([str(sweep_dir)])
    table = (sweep_dir / "collected.csv").read_text().splitlines()
    assert len(table) == 3
    assert table[1].startswith("curve.seed=0,0,") and table[2].startswith("curve.seed=1,1,")
    assert (sweep_dir / "curves.png").is_file()


def test_a_joblib_sweep_with_a_failed_job_exits_with_its_code_and_collect_lists_it(tmp_path):
    command = [sys.executable, "-m", "spidermatch.cli.eval", "-m", "hydra/launcher=joblib",
               "hydra.launcher.n_jobs=2", *SMALL, "synthetic.n_shapes=2", "n_pairs=1",
               f"dataset=synthetic,{tmp_path / 'nothing here'}", "name=half"]  # fmt: skip
    (tmp_path / "nothing here").mkdir()
    finished = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    said = finished.stdout + finished.stderr
    assert finished.returncode == 2, said[-2000:]  # the jobs ran in joblib's workers
    assert "1 of 2 jobs succeeded; failed: 1 (exit 2)" in said
    sweep_dir = tmp_path / "multirun" / "eval" / "half"
    with pytest.raises(SystemExit, match=r"1 of 2 runs failed: 1 \(exit 2, no summary\)"):
        collect_main([str(sweep_dir), "--no-plot"])
    rows = (sweep_dir / "collected.csv").read_text().splitlines()
    assert len(rows) == 3 and rows[2].startswith("dataset=") and rows[2].endswith(",2")
