"""The stress run's draw and checks (bench/bench_stress.py)."""

import json

from bench_stress import KINDS, Collections, checked_row, draw_runs, summaries_of


def collections(tmp_path):
    for folder, names in {"faust": ["tr_reg_000", "tr_reg_001", "tr_reg_002"],
                          "tosca": ["cat0", "cat1", "dog0", "dog1", "horse0"]}.items():  # fmt: skip
        (tmp_path / folder / "off").mkdir(parents=True)
        for name in names:
            (tmp_path / folder / "off" / f"{name}.off").write_text("OFF\n0 0 0\n")
    return Collections(tmp_path / "faust", tmp_path / "tosca")


def test_every_drawn_pair_is_of_its_kind_and_every_kind_meets_every_configuration(tmp_path):
    shapes = collections(tmp_path)
    configurations = [(500, 0), (500, 20), (1000, 0), (1000, 20)]
    runs = draw_runs(shapes, 64, configurations, seed=0)
    assert runs == draw_runs(shapes, 64, configurations, seed=0)  # fixed seed, same runs
    for run in runs:
        source, target = run["source"], run["target"]
        animals = [name for name in (source, target) if name in shapes.animals]
        classes = {Collections.animal_class(name) for name in animals}
        expected = {
            "humans": (0, 0),
            "one animal class": (2, 1),
            "two animal classes": (2, 2),
            "human and animal": (1, 1),
        }[run["kind"]]
        assert source != target and (len(animals), len(classes)) == expected
        assert shapes.has_ground_truth(source, target) == (run["kind"] in ("humans", "one animal class"))
    cells = {(run["kind"], run["faces"], run["adapt"]) for run in runs}
    assert len(cells) == len(KINDS) * len(configurations)


def test_checks_flag_an_undocumented_exit_an_unfinished_status_and_a_hang(tmp_path):
    run = {"n": 0, "kind": "humans", "faces": 500, "adapt": 0}
    (tmp_path / "result.json").write_text('{"status": "started", "timings_s": {"solve": 75.0}}')
    row = checked_row(
        run, {"exit_code": -6, "status": "started", "process_s": 80.0, "peak_mib": 1.0}, tmp_path, 60, 10
    )
    assert not row["documented_exit"] and not row["final_status"] and not row["within_limit"]
    summary = summaries_of([row])["all"]
    assert (summary["undocumented_exits"], summary["not_final"], summary["past_limit_and_grace"]) == (1, 1, 1)


def test_a_run_with_both_tours_says_which_ended_how_and_which_was_kept(tmp_path):
    run = {"n": 0, "kind": "humans", "faces": 1000, "adapt": 0}
    tours = [
        {"tour": "christofides", "status": "no_solution", "chosen": False},
        {"tour": "two_opt", "status": "optimal", "chosen": True},
    ]
    (tmp_path / "result.json").write_text(json.dumps({"status": "optimal", "curve_tours": tours}))
    row = checked_row(run, {"exit_code": 0, "status": "optimal"}, tmp_path, 60, 10)
    assert row["tours"] == "christofides:no_solution; *two_opt:optimal"
    (tmp_path / "result.json").write_text(json.dumps({"status": "optimal", "curve_tours": None}))
    assert checked_row(run, {"exit_code": 0, "status": "optimal"}, tmp_path, 60, 10)["tours"] is None
