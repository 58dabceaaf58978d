"""The benchmark scripts' shared option checks (bench/feature_options.py)."""

import argparse
import sys

import pytest
from feature_options import add_feature_options, pair_problem, parse_checked


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


def test_match_process_row_reads_result_json_and_names_a_missing_one(tmp_path):
    import json

    from bench_match_process import pair_row

    assert pair_row("a:b", 1, 3.0, 100.0, tmp_path)["status"] == "no result.json"
    result = {
        "status": "optimal", "gap": 1e-4, "objective": 2.5, "total_time_s": 9.0,
        "timings_s": {"features": 2.0, "solve": 4.0}, "geodesic_error": {"mean": 0.03},
        "dense": {"dense": {"geodesic_error": 0.02}},
    }  # fmt: skip
    (tmp_path / "result.json").write_text(json.dumps(result))
    row = pair_row("a:b", 0, 12.345, 900.0, tmp_path)
    assert (row["status"], row["process_s"], row["solve_s"], row["sparse_error"], row["dense_error"]) == (
        "optimal", 12.35, 4.0, 0.03, 0.02,
    )  # fmt: skip


def test_adapt_steps_are_refused_for_wks_and_below_zero(capsys):
    parser = argparse.ArgumentParser(prog="bench")
    parser.add_argument("--data", default="synthetic")
    parser.add_argument("--pairs", nargs="+", required=True)
    add_feature_options(parser, adaptation=True)
    good = ["--pairs", "creature_000:creature_001"]
    with pytest.raises(SystemExit):
        parse_checked(parser, [*good, "--adapt-steps", "20"])  # WKS has nothing to adapt
    assert "--adapt-steps" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        parse_checked(parser, [*good, "--features", "learned", "--checkpoint", "x.pt", "--adapt-steps", "-1"])
    assert "--adapt-steps" in capsys.readouterr().err
    learned = [*good, "--features", "learned", "--checkpoint", "x.pt"]
    assert parse_checked(parser, [*learned, "--adapt-steps", "20"]).adapt_steps == 20
    plain = argparse.ArgumentParser(prog="bench")
    add_feature_options(plain)
    with pytest.raises(SystemExit):  # scripts that do not adapt do not offer the option
        plain.parse_args(["--adapt-steps", "20"])


def test_a_cold_cache_run_gets_its_own_empty_operator_cache(tmp_path):
    from bench_match_process import run_process

    command = [sys.executable, "-c", "import os; print(os.environ.get('SPIDERMATCH_CACHE_DIR'))"]
    log = tmp_path / "log.txt"
    code, _, _ = run_process(command, log, tmp_path / "cache")
    assert code == 0 and log.read_text().strip() == str(tmp_path / "cache")


def test_partial_bench_slices_merge_into_one_table(tmp_path):
    import json

    from bench_partial import main

    def row(part, status, error):
        return {"part": part, "target": "t", "status": status, "total_s": 10.0, "solve_s": 2.0,
                "dense_error": error, "iou": 0.5, "verdict": "plausible"}  # fmt: skip

    slices = [tmp_path / "a.json", tmp_path / "b.json"]
    contents = [[row("s-plane", "optimal", 0.02), row("s-holes", "optimal", 0.04)],
                [row("u-view", "feasible", 0.6)]]  # fmt: skip
    for number, (path, rows) in enumerate(zip(slices, contents)):
        path.write_text(json.dumps({"argv": ["bench_partial.py", "--runs", str(number)], "rows": rows}))
    out = tmp_path / "all.json"
    assert main(["merge", *map(str, slices), "--out", str(out), "--note", "side by side"]) == 0
    merged = json.loads(out.read_text())
    assert [r["part"] for r in merged["rows"]] == ["s-plane", "s-holes", "u-view"]
    assert merged["argv"] == [["bench_partial.py", "--runs", "0"], ["bench_partial.py", "--runs", "1"]]
    assert merged["note"] == "side by side" and out.with_suffix(".csv").read_text().count("\n") == 4
    assert merged["summary"]["all"]["runs"] == 3 and merged["summary"]["all"]["optimal"] == 2
    assert merged["summary"]["all"]["median_dense_error"] == 0.04 and merged["summary"]["view"]["runs"] == 1


def test_partial_benches_can_turn_the_part_placement_off(monkeypatch):
    from bench_partial import add_part_options, apply_part_search_options

    from features import orientation

    monkeypatch.setattr(orientation, "PLACED_ORIENTATIONS", orientation.PLACED_ORIENTATIONS)
    parser = argparse.ArgumentParser(prog="bench")
    add_part_options(parser, "a network")
    required = ["--data", "d", "--parts", "p", "--pairs", "q", "--checkpoint", "c"]
    default = orientation.PLACED_ORIENTATIONS
    apply_part_search_options(parser.parse_args(required))
    assert orientation.PLACED_ORIENTATIONS == default > 0
    apply_part_search_options(parser.parse_args([*required, "--placed-orientations", "0"]))
    assert orientation.PLACED_ORIENTATIONS == 0
    with pytest.raises(SystemExit, match="0 or more"):
        apply_part_search_options(parser.parse_args([*required, "--placed-orientations", "-1"]))


def test_a_scanned_part_is_a_clean_cut_of_the_dense_scan_with_its_originals_found():
    import numpy as np
    from bench_partial import scanned_part

    from spidermatch.data.synthetic import make_creature
    from spidermatch.geometry.mesh import make_mesh
    from spidermatch.geometry.partial import plane_cut

    whole = make_creature(n_verts=400, seed=2).mesh
    part = plane_cut(whole, np.array([0.0, 1.0, 0.2]), 0.5, "part")
    position = part.positions(whole.n_verts)
    scanned, scanned_position, to_whole = scanned_part(whole, position, np.random.default_rng(0), "part")
    make_mesh(scanned.verts, scanned.faces, "scan")  # one clean manifold piece
    assert scanned.name == "part" and scanned.n_verts > 10 * part.mesh.n_verts  # two Loop subdivisions
    found = scanned_position >= 0
    assert np.all(position[found] >= 0)  # only the part's originals are in the scan's cut
    assert found.sum() >= 0.8 * part.mesh.n_verts  # its rim may lose a few
    # an original stays near where it was (Loop smoothing and the scan's noise move it a little;
    # a wrong index would put it many edges away)
    moved = np.linalg.norm(scanned.verts[scanned_position[found]] - whole.verts[found], axis=1)
    edge = np.linalg.norm(whole.verts[whole.faces[:, 0]] - whole.verts[whole.faces[:, 1]], axis=1).mean()
    assert np.median(moved) < 0.5 * edge
    # each scan vertex stands for an original vertex of the part near it; the originals for themselves
    assert to_whole.shape == (scanned.n_verts,) and np.all(position[to_whole] >= 0)
    assert np.array_equal(to_whole[scanned_position[found]], np.flatnonzero(found))


def test_scaling_logs_of_two_flow_row_settings_get_two_names():
    """``bench_scaling.py --log-dir``: a run with ``--flow-rows intersections`` keeps the default's log."""
    from dataclasses import replace

    from bench_scaling import Instance

    task = Instance(
        None, ("tr_reg_076", "tr_reg_077"), 4000, "colgen", "wks", None, 0, 60.0, "ilp", tour="two_opt"
    )
    default, everywhere = task.log_name, replace(task, flow_rows="intersections").log_name
    assert default == "tr_reg_076_tr_reg_077_4000_colgen_two_opt_seed0.log"  # as the stored logs are named
    assert everywhere != default and "intersections" in everywhere
    without_cuts = replace(task, lp_cuts=False).log_name  # --no-lp-cuts
    assert without_cuts not in (default, everywhere) and "no_lp_cuts" in without_cuts


def test_solve_benchmarks_pass_no_lp_cuts_to_the_solver(monkeypatch):
    """``--no-lp-cuts`` reaches ``SolverOptions.lp_cuts`` through run_instance's task (both benchmarks)."""
    import bench_scaling
    import bench_solve

    seen = []

    class StopHere(Exception):
        pass

    def fake_match(source, target, feat_x, feat_y, settings):
        seen.append(settings.solver.lp_cuts)
        raise StopHere

    monkeypatch.setattr("spidermatch.pipeline.match", fake_match)
    from types import SimpleNamespace

    shape = SimpleNamespace(mesh=None)
    monkeypatch.setattr(bench_scaling, "load_pair_with_features", lambda *args: (shape, shape, None, None))

    class InProcess:  # the benchmarks' one-process pool, run here
        def __init__(self, *args):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def apply(self, function, args):
            return function(*args)

    class Context:
        Pool = InProcess

    monkeypatch.setattr("multiprocessing.get_context", lambda kind: Context())
    for main in (bench_solve.main, bench_scaling.main):
        for flag in ([], ["--no-lp-cuts"]):
            with pytest.raises(StopHere):
                pair = ["--pairs", "creature_000:creature_001", "--strategies", "colgen", "--time-limit", "1"]
                main([*pair, "--out", "/dev/null", *flag])
    assert seen == [True, False, True, False]


def test_benchmark_results_say_which_software_made_them(tmp_path):
    import json

    from bench_scaling import write_rows

    from spidermatch.versions import spidermatch_version

    write_rows(tmp_path / "figures.json", [{"pair": "a:b", "status": "optimal"}], {"note": "n"})
    written = json.loads((tmp_path / "figures.json").read_text())
    assert written["software"]["spidermatch"] == spidermatch_version() and written["software"]["highs"]
    assert written["note"] == "n" and written["rows"] == [{"pair": "a:b", "status": "optimal"}]
    assert (tmp_path / "figures.csv").read_text().splitlines() == ["pair,status", "a:b,optimal"]


def test_a_scanned_pair_of_parts_keeps_the_truth_told_through_the_originals():
    """``bench_partial.py --mode both --scan-copies``: each shared reference point is found in both scans."""
    import numpy as np
    from bench_partial import PartPair, scanned_pair

    from spidermatch.data.datasets import Shape
    from spidermatch.data.synthetic import make_creature
    from spidermatch.geometry.partial import plane_cut

    creature = make_creature(n_verts=400, seed=2).mesh
    whole = Shape("whole", creature, np.arange(0, creature.n_verts, 3))
    cuts = [
        plane_cut(whole.mesh, np.array([0.0, sign, 0.2]), 0.7, f"cut{k}") for k, sign in enumerate((1, -1))
    ]
    positions = [cut.positions(whole.mesh.n_verts) for cut in cuts]
    shared = (positions[0][whole.corr] >= 0) & (positions[1][whole.corr] >= 0)
    pair = PartPair(
        [cut.mesh for cut in cuts], [cut.to_original for cut in cuts], [whole, whole], positions, shared,
        [np.ones(cut.mesh.n_verts, dtype=bool) for cut in cuts], 0.7,
    )  # fmt: skip
    scanned = scanned_pair(pair, seed=0)
    assert scanned.shared.sum() >= 0.8 * shared.sum() and not np.any(scanned.shared & ~shared)
    for cut, mesh, to_original, position, truth in zip(
        cuts, scanned.meshes, scanned.to_original, scanned.positions, scanned.truths
    ):
        assert mesh.n_verts > 10 * cut.mesh.n_verts  # two Loop subdivisions
        points = whole.corr[scanned.shared]
        assert np.array_equal(to_original[position[points]], points)  # each point found as itself
        assert truth.shape == (mesh.n_verts,) and 0 < truth.sum() < mesh.n_verts


def test_a_pair_the_library_refuses_is_a_row_and_the_bench_goes_on(monkeypatch):
    """partial=both may find no overlap (a MeshError naming the file): the run is recorded as refused,
    with the message, and the summary counts it instead of the whole bench dying on it."""
    import bench_partial

    from spidermatch.geometry.mesh import MeshError

    def refuse(*_args, **_kwargs):
        raise MeshError("a.off: no overlap with the target found")

    monkeypatch.setattr(bench_partial.spidermatch, "match", refuse)
    args = argparse.Namespace(faces=100, time_limit=1.0)
    row = {"part": "a-plane", "target": "b-view", "kept_area": 0.5}
    assert bench_partial._timed_match(None, None, args, "wks", "both", row) is None
    assert row["status"] == "refused" and "no overlap" in row["message"]
    done = {**row, "status": "optimal", "part": "c-plane", "total_s": 2.0, "solve_s": 1.0}
    figures = bench_partial.summary([row, done])["all"]
    assert figures["runs"] == 2 and figures["refused"] == 1 and figures["median_solve_s"] == 1.0
