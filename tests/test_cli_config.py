"""The command line as a user meets it: --help, --cfg job and the saved .hydra/config.yaml."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from spidermatch.cli.main import file_run_overrides
from spidermatch.data.datasets import SyntheticShapes, write_dataset

ROOT = Path(__file__).resolve().parents[1]


def run_command(main: str, args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """Run an entry point (``module:function``) as its console script would, with ``args``."""
    module, function = main.split(":")
    code = f"import sys; sys.argv = ['prog'] + {args!r}; from {module} import {function}; {function}()"
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=cwd, env=env)


@pytest.mark.parametrize(
    ("main", "expected"),
    [
        (
            "spidermatch.cli.main:match_main",
            ["source=PATH target=PATH", "resolution=N", "solver.time_limit=S"],
        ),
        ("spidermatch.cli.main:eval_main", ["dataset=DIR", "n_pairs=N", "hydra/launcher=joblib"]),
        ("train.cli:main", ["train/experiment=faust_r", "data.root=DIR", "resume=PATH"]),
    ],
)
def test_help_lists_the_main_options(tmp_path, main, expected):
    out = run_command(main, ["--help"], tmp_path)
    assert out.returncode == 0, out.stderr
    for option in expected:
        assert option in out.stdout
    assert "== Configuration groups ==" not in out.stdout  # Hydra's generic listing
    if "train" not in main:
        assert "train/" not in out.stdout


def test_cfg_job_of_a_file_run_shows_files_and_the_resolution_used(tmp_path):
    out = run_command(
        "spidermatch.cli.main:match_main", ["--cfg", "job", "source=a.off", "target=b.off"], tmp_path
    )
    assert out.returncode == 0, out.stderr
    cfg = yaml.safe_load(out.stdout)
    assert (
        cfg["data"] == {"kind": "files"} and cfg["resolution"] == 500 and cfg["solver"]["time_limit"] == 300
    )
    args = ["--cfg", "job", "source=a.off", "target=b.off", "features=learned", "checkpoint=x.pt"]
    cfg = yaml.safe_load(run_command("spidermatch.cli.main:match_main", args, tmp_path).stdout)
    assert cfg["resolution"] == 1000
    cfg = yaml.safe_load(run_command("spidermatch.cli.main:match_main", ["--cfg", "job"], tmp_path).stdout)
    assert cfg["data"]["kind"] == "synthetic" and cfg["resolution"] == 200


@pytest.mark.parametrize(
    ("args", "code", "expected"),
    [
        (["run.n_stepz=5"], 2, "unknown option 'run.n_stepz' (did you mean run.n_steps?)"),
        (["train/experiment=nope"], 2, "train/experiment/nope"),
        (["hydra.run.dir={blocker}/run"], 6, "cannot write the run folder"),
    ],
)
def test_training_refuses_bad_options_and_run_folders_in_one_line(tmp_path, args, code, expected):
    """As spidermatch-match does: before Hydra starts, so no traceback and no stray run folder."""
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    args = [arg.format(blocker=blocker) for arg in args]
    if not any(arg.startswith("hydra.run.dir=") for arg in args):
        args.append(f"hydra.run.dir={tmp_path / 'run'}")
    out = run_command("train.cli:main", args, tmp_path)
    assert out.returncode == code, out.stderr[-2000:]
    assert expected in out.stderr and "Traceback" not in out.stderr
    assert not (tmp_path / "run").exists() and not (tmp_path / "outputs").exists()


def test_path_options_hydra_would_misread_are_quoted():
    from hydra.core.override_parser.overrides_parser import OverridesParser

    from spidermatch.cli.options import quoted_paths

    names = ["in/ünï/形状é.off", "a (1).off", "in/x,y.off", "it's.pt", "x=y/~z.off", "plain/name.off"]
    argv = [f"source={names[0]}", f"target={names[1]}", f"source_corr={names[2]}", f"checkpoint={names[3]}"]
    argv += [f"data.root={names[4]}", f"target_corr={names[5]}", "resolution=300"]
    quoted = quoted_paths(argv)
    parser = OverridesParser.create()
    assert [parser.parse_override(argument).value() for argument in quoted[:6]] == names
    assert quoted[5:] == argv[5:]  # what Hydra reads as given stays as given
    assert quoted_paths(["-m", "source=a.off,b.off"]) == ["-m", "source=a.off,b.off"]  # a sweep's list
    assert quoted_paths(["second_opinion=null", "checkpoint=null"]) == [
        "second_opinion=null",
        "checkpoint=null",
    ]
    for key in ("features.checkpoint", "name"):  # the learned features' network; eval's run folder name
        (argument,) = quoted_paths([f"{key}={names[1]}"])
        assert parser.parse_override(argument).value() == names[1]


def test_a_file_run_with_a_name_hydra_cannot_read_unquoted(tmp_path):
    root = write_dataset(SyntheticShapes(n_shapes=2, n_verts=700), tmp_path / "Körper (1)")
    args = [
        f"source={root}/off/creature_000.off",
        f"target={root}/off/creature_001.off",
        "resolution=60",
        "output.png=false",
        f"hydra.run.dir={tmp_path / 'run'}",
    ]
    out = run_command("spidermatch.cli.main:match_main", args, tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert (tmp_path / "run" / "matches.csv").is_file()


def test_file_run_overrides():
    assert file_run_overrides(["source=a", "target=b"]) == ["source=a", "target=b", "data=files"]
    assert file_run_overrides(["source=a", "data=synthetic"]) == ["source=a", "data=synthetic"]
    assert file_run_overrides(["--cfg", "job"]) == ["--cfg", "job"]


def test_saved_config_and_result_describe_the_file_run(tmp_path):
    root = write_dataset(SyntheticShapes(n_shapes=2, n_verts=700), tmp_path / "data")
    run_dir = tmp_path / "run"
    args = [
        f"source={root}/off/creature_000.off",
        f"target={root}/off/creature_001.off",
        "resolution=60",
        "output.png=false",
        f"hydra.run.dir={run_dir}",
    ]
    out = run_command("spidermatch.cli.main:match_main", args, tmp_path)
    assert out.returncode == 0, out.stderr
    saved = yaml.safe_load((run_dir / ".hydra" / "config.yaml").read_text())
    assert saved["data"] == {"kind": "files"} and saved["resolution"] == 60
    assert saved["source"].endswith("creature_000.off")
    result = json.loads((run_dir / "result.json").read_text())
    assert result["resolution"] == 60
    full, solved = result["full_model"], result["solved_model"]
    assert set(full) == {"variables", "rows", "nonzeros"} and set(solved) == {"rows", "nonzeros"}
    assert solved["nonzeros"] < full["nonzeros"]  # rcfix solves the surviving columns only
    log = next(run_dir.glob("*.log")).read_text()
    assert f"full model: {full['variables']} variables, {full['rows']} rows" in log


def test_a_training_refused_after_hydra_started_says_why_in_its_log_file(tmp_path):
    """A bad data folder: the reason was printed to the console only, not to the run folder's cli.log
    (all a batch job keeps)."""
    out = run_command(
        "train.cli:main",
        [
            "train/experiment=folder_unsup",
            f"data.root={tmp_path / 'nowhere'}",
            f"hydra.run.dir={tmp_path / 'run'}",
        ],
        tmp_path,
    )
    assert out.returncode == 2, out.stderr[-2000:]
    assert "spidermatch-train: error (data)" in out.stderr
    assert "spidermatch-train: error (data)" in (tmp_path / "run" / "cli.log").read_text()


def test_training_stopped_during_its_data_preparation_says_so(tmp_path):
    """SIGTERM before the first step (a pre-empted batch job) ended the process with 143 and no word."""
    import signal
    import time

    slow_preparation = (
        "import time, train.loop as loop; given = loop.prepare_data; "
        "loop.prepare_data = lambda config: (time.sleep(60), given(config))[1]; "
    )
    args = [f"hydra.run.dir={tmp_path / 'run'}"]
    code = f"import sys; sys.argv = ['prog'] + {args!r}; {slow_preparation}from train.cli import main; main()"
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    process = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    )
    deadline = time.monotonic() + 120
    while not (tmp_path / "run" / "cli.log").exists() and time.monotonic() < deadline:
        time.sleep(0.2)  # Hydra has started the job (its log file) and the preparation sleeps
    time.sleep(1.0)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 143, err[-2000:]
    assert "stopped by SIGTERM during the data preparation; nothing was trained" in err
    assert "nothing was trained" in (tmp_path / "run" / "cli.log").read_text()


def test_a_sweep_with_a_failed_job_says_which_and_exits_with_its_code(tmp_path):
    root = write_dataset(SyntheticShapes(n_shapes=2, n_verts=700), tmp_path / "data")
    (tmp_path / "empty.off").write_text("")
    targets = f"{root}/off/creature_001.off,{tmp_path / 'empty.off'}"
    args = ["-m", f"source={root}/off/creature_000.off", f"target={targets}", "resolution=60",
            "output.png=false", "dense.enabled=false", f"hydra.sweep.dir={tmp_path / 'sweep'}"]  # fmt: skip
    out = run_command("spidermatch.cli.main:match_main", args, tmp_path)
    said = out.stdout + out.stderr
    assert out.returncode == 2, said[-2000:]  # Hydra alone exits 0 whatever its jobs returned
    assert f"sweep job 1 failed (exit 2): {tmp_path / 'sweep' / '1'}" in said
    assert "1 of 2 jobs succeeded; failed: 1 (exit 2)" in said
    assert (tmp_path / "sweep" / "0" / ".hydra" / "exit_code").read_text() == "0\n"
    good = ["-m", f"source={root}/off/creature_000.off", f"target={root}/off/creature_001.off",
            "resolution=50,60", "output.png=false", "dense.enabled=false",
            f"hydra.sweep.dir={tmp_path / 'good'}"]  # fmt: skip
    out = run_command("spidermatch.cli.main:match_main", good, tmp_path)
    assert out.returncode == 0 and "2 of 2 jobs succeeded" in out.stdout + out.stderr


def test_runs_started_in_the_same_second_get_folders_of_their_own(tmp_path, monkeypatch):
    from spidermatch.cli.options import claimed_run_folder

    monkeypatch.chdir(tmp_path)
    argv = ["source=a.off", "target=b.off"]
    first, second = (claimed_run_folder("match", argv) for _ in range(2))
    folders = [args[-1].split("=", 1)[1] for args in (first, second)]
    assert all(args[:2] == argv for args in (first, second)) and folders[0] != folders[1]
    assert all((tmp_path / folder).is_dir() for folder in folders)
    same = Path(folders[0]).name
    taken = tmp_path / "outputs" / "match"
    assert {path.name for path in taken.iterdir()} <= {same, f"{same}_2", Path(folders[1]).name}
    given = [*argv, "hydra.run.dir=mine"]
    assert claimed_run_folder("match", given) == given and not (tmp_path / "mine").exists()
    assert claimed_run_folder("match", ["-m", *argv]) == ["-m", *argv]  # a sweep: Hydra's folders
