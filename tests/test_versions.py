"""Which software made a result (spidermatch.versions)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

import spidermatch
from spidermatch import versions
from spidermatch.versions import software_versions


def test_versions_name_spidermatch_python_highs_and_the_numeric_packages():
    found = software_versions()
    assert found["spidermatch"].startswith(spidermatch.__version__)
    for name in ("python", "highs", "highspy", "numpy", "scipy", "trimesh", "potpourri3d"):
        assert found[name][0].isdigit(), (name, found[name])


def _commit(folder: Path, message: str) -> None:
    subprocess.run(["git", "-C", str(folder), "add", "-A"], check=True)
    subprocess.run(
        ["git", "-C", str(folder), "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", message],
        check=True,
    )


def test_a_checkout_is_named_by_its_commit_and_dirty_when_its_code_changed(tmp_path):
    if subprocess.run(["git", "--version"], capture_output=True).returncode != 0:
        pytest.skip("git is not installed")
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    (tmp_path / "spidermatch").mkdir()
    code = tmp_path / "spidermatch" / "solve.py"
    code.write_text("x = 1\n")
    (tmp_path / "notes.txt").write_text("a\n")
    _commit(tmp_path, "first")
    head = subprocess.run(
        ["git", "-C", str(tmp_path), "rev-parse", "--short=10", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    assert versions._checkout_commit(tmp_path) == f"g{head}"
    (tmp_path / "notes.txt").write_text("b\n")  # not the code: still the commit
    assert versions._checkout_commit(tmp_path) == f"g{head}"
    code.write_text("x = 2\n")
    assert versions._checkout_commit(tmp_path) == f"g{head}.dirty"
    assert versions._checkout_commit(tmp_path / "spidermatch") is None  # no .git there: an installed copy
