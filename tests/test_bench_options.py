"""The benchmark scripts' shared option checks (bench/feature_options.py)."""

import argparse
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from feature_options import add_feature_options, pair_problem, parse_checked  # noqa: E402


def test_known_synthetic_pair_passes():
    assert pair_problem("synthetic", ["creature_000:creature_001"]) is None


@pytest.mark.parametrize(
    "pair, expected",
    [("creature_000", "expected two shape names"), ("creature_000:", "expected two shape names"),
     ("creature_000:nobody", "unknown shape 'nobody'")],
)  # fmt: skip
def test_bad_pairs_are_named(pair, expected):
    message = pair_problem("synthetic", ["creature_000:creature_001", pair])
    assert expected in message and pair in message


def test_missing_data_folder_is_named(tmp_path):
    message = pair_problem(str(tmp_path / "absent"), ["a:b"])
    assert message.startswith("--data:") and "absent" in message


def test_parse_checked_exits_with_usage_error(capsys):
    parser = argparse.ArgumentParser(prog="bench")
    parser.add_argument("--data", default="synthetic")
    parser.add_argument("--pairs", nargs="+", required=True)
    add_feature_options(parser)
    with pytest.raises(SystemExit):
        parse_checked(parser, ["--pairs", "creature_000:ghost"])
    assert "unknown shape 'ghost'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        parse_checked(parser, ["--pairs", "creature_000:creature_001", "--features", "learned"])
    assert "--checkpoint" in capsys.readouterr().err
    good = ["creature_000:creature_001"]
    assert parse_checked(parser, ["--pairs", *good]).pairs == good
