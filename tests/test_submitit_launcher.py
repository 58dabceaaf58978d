"""The cluster route: a sweep through Hydra's submitit launcher, run here by its local executor.

``hydra/launcher=slurm`` (conf/hydra/launcher/slurm.yaml) is ``submitit_slurm`` with our
resources; ``submitit_local`` goes through the same launcher code (pickled jobs, submitit's
folders, results collected back) with local processes instead of SLURM.
"""

import importlib.util
import json
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("hydra_plugins.hydra_submitit_launcher") is None,
    reason="hydra-submitit-launcher is not installed (pip install -e '.[dev]' installs it)",
)


def test_eval_sweep_through_submitit_local(tmp_path):
    command = [
        sys.executable,
        "-m",
        "spidermatch.cli.eval",
        "-m",
        "hydra/launcher=submitit_local",
        "hydra.launcher.timeout_min=10",
        "resolution=60",
        "synthetic.n_verts=700",
        "synthetic.n_shapes=2",
        "n_pairs=1",
        "curve.seed=0,1",
        "name=submitit",
    ]
    finished = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert finished.returncode == 0, finished.stderr[-2000:]
    sweep_dir = tmp_path / "multirun" / "eval" / "submitit"
    summaries = sorted(sweep_dir.glob("*/summary.json"))
    assert [s.parent.name for s in summaries] == ["0", "1"]
    for path in summaries:
        summary = json.loads(path.read_text())
        assert summary["pairs_finished"] == 1 and summary["statuses"] == {"optimal": 1}
    assert (sweep_dir / ".submitit").is_dir()  # the jobs really went through submitit
