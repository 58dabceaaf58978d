"""Fault cases of issue 17: bad input, bad options, failing outputs, signals, stale eval results.

One test per case of the audit (numbered as there), on small meshes the tests write.
"""

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from conftest import composed, result_of

from spidermatch import shutdown
from spidermatch.cli.evaluate import run_eval
from spidermatch.cli.match import run_match
from spidermatch.cli.resume import file_identity, rerun_reason
from spidermatch.data.datasets import SyntheticShapes, write_dataset
from spidermatch.geometry.io import load_mesh, read_vts, save_mesh
from spidermatch.geometry.mesh import Mesh, MeshError, topology
from spidermatch.solve.highs import SolverOptionError, set_option
from spidermatch.versions import spidermatch_version

SMALL = ["data.n_verts=700", "resolution=60", "output.png=false"]


config = composed


def write_off(path: Path, verts, faces) -> Path:
    lines = ["OFF", f"{len(verts)} {len(faces)} 0"]
    lines += [" ".join(repr(float(c)) for c in v) for v in verts]
    lines += ["3 " + " ".join(str(int(i)) for i in f) for f in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def sphere(path: Path, subdivisions: int = 2) -> Path:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions)
    return write_off(path, mesh.vertices, mesh.faces)


def torus(path: Path, n_major: int = 16, n_minor: int = 8) -> Path:
    u, v = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    a, b = 2 * np.pi * u.ravel() / n_major, 2 * np.pi * v.ravel() / n_minor
    verts = np.stack(
        [(1 + 0.4 * np.cos(b)) * np.cos(a), (1 + 0.4 * np.cos(b)) * np.sin(a), 0.4 * np.sin(b)], 1
    )
    index = lambda i, j: (i % n_major) * n_minor + (j % n_minor)  # noqa: E731
    faces = []
    for i in range(n_major):
        for j in range(n_minor):
            faces += [
                [index(i, j), index(i + 1, j), index(i + 1, j + 1)],
                [index(i, j), index(i + 1, j + 1), index(i, j + 1)],
            ]
    return write_off(path, verts, faces)


TETRA_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def match_files(tmp_path, source, target, *extra, out="run"):
    cfg = config("match", [f"source={source}", f"target={target}", "output.png=false", *extra])
    folder = tmp_path / out
    return run_match(cfg, folder), folder


# 1. eval results are keyed by their settings and input files


@pytest.fixture
def small_dataset(tmp_path):
    shapes = SyntheticShapes(n_shapes=2, n_verts=700)
    root = write_dataset(shapes, tmp_path / "data")
    (tmp_path / "pairs.txt").write_text("creature_000 creature_001\n")
    return root


def eval_config(root, tmp_path, *extra):
    return config(
        "eval", [f"dataset={root}", f"pairs_file={tmp_path / 'pairs.txt'}", "resolution=40", *extra]
    )


def test_01_eval_reruns_pairs_of_other_settings_and_changed_inputs(tmp_path, small_dataset):
    run_dir = tmp_path / "eval"
    pair = run_dir / "pairs" / "creature_000__creature_001"
    assert run_eval(eval_config(small_dataset, tmp_path), run_dir) == 0
    first = result_of(pair)
    assert first["status"] == "optimal" and first["resolution"] == 40
    assert run_eval(eval_config(small_dataset, tmp_path, "resolution=48"), run_dir) == 0
    second = result_of(pair)
    assert second["resolution"] == 48 and second["settings_hash"] != first["settings_hash"]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert (
        summary["settings"]["resolution"] == 48
        and summary["settings"]["settings_hash"] == second["settings_hash"]
    )
    # a broken mesh fails; once repaired, the pair runs again instead of keeping its stale failure
    mesh_file = small_dataset / "off" / "creature_001.off"
    good = mesh_file.read_text()
    mesh_file.write_text(good.replace("OFF", "OFF\n# broken", 1).rsplit("\n3 ", 3)[0] + "\n")
    assert (
        run_eval(eval_config(small_dataset, tmp_path, "resolution=48"), run_dir) == 2
    )  # its only pair failed
    assert result_of(pair)["status"] == "input_error"
    mesh_file.write_text(good)
    assert run_eval(eval_config(small_dataset, tmp_path, "resolution=48"), run_dir) == 0
    assert result_of(pair)["status"] == "optimal"


def test_01_rerun_reasons():
    stored = {
        "status": "optimal",
        "settings_hash": "abc",
        "input_files": [{"path": "a", "size": 1}],
        "software": {"spidermatch": spidermatch_version()},
    }
    assert rerun_reason(stored, "abc", [{"path": "a", "size": 1}]) is None
    assert "settings" in rerun_reason(stored, "xyz", [{"path": "a", "size": 1}])
    assert "input files" in rerun_reason(stored, "abc", [{"path": "a", "size": 2}])
    assert "interrupted" in rerun_reason({**stored, "status": "interrupted"}, "abc", stored["input_files"])
    # a result of other code is not reused: a fix since may change the pair's matching
    older = {**stored, "software": {"spidermatch": "0.0.9"}}
    assert "matched by spidermatch 0.0.9" in rerun_reason(older, "abc", stored["input_files"])
    unversioned = {key: value for key, value in stored.items() if key != "software"}
    assert "recorded none" in rerun_reason(unversioned, "abc", stored["input_files"])


# 2. solver options are validated up front, and HiGHS's option status is checked


def test_02_bad_solver_options_exit_2_naming_the_option(tmp_path):
    for override, key in [
        ("solver.mip_rel_gap=-1", "solver.mip_rel_gap"),
        ("solver.time_limit=0", "solver.time_limit"),
        ("solver.threads=-2", "solver.threads"),
        ("solver.presolve=maybe", "solver.presolve"),
        ("solver.strategy=magic", "solver.strategy"),
    ]:
        folder = tmp_path / key
        assert run_match(config("match", SMALL + [override]), folder) == 2
        result = result_of(folder)
        assert result["status"] == "input_error" and key in result["error"]
        assert result["proven_optimal"] is False and "bound" not in result


def test_02_every_strategy_and_curve_matching_is_accepted_and_unknown_ones_named():
    from spidermatch.validate import OptionError, check_options

    for strategy in ("auto", "rcfix", "plain", "colgen"):
        for matching in ("greedy", "blossom"):
            check_options(config("match", [f"solver.strategy={strategy}", f"curve.matching={matching}"]))
    with pytest.raises(OptionError, match="curve.matching='zigzag'"):
        check_options(config("match", ["curve.matching=zigzag"]))
    for tour in ("christofides", "two_opt", "auto"):
        check_options(config("match", [f"curve.tour={tour}"]))
    with pytest.raises(OptionError, match="curve.tour='three_opt'"):
        check_options(config("match", ["curve.tour=three_opt"]))


def test_02_strategy_auto_is_colgen_for_learned_features_and_rcfix_for_wks():
    from spidermatch.cli.settings import settings_from_config

    cfg = config("match", [])
    assert cfg.solver.strategy == "auto"
    assert settings_from_config(cfg, 200, "learned").strategy == "colgen"
    assert settings_from_config(cfg, 200, "wks").strategy == "rcfix"
    chosen = config("match", ["solver.strategy=plain"])
    assert settings_from_config(chosen, 200, "learned").strategy == "plain"


def test_02_highs_rejecting_a_value_is_an_error():
    import highspy

    highs = highspy.Highs()
    with pytest.raises(SolverOptionError, match="mip_rel_gap"):
        set_option(highs, "mip_rel_gap", -1.0)
    with pytest.raises(SolverOptionError, match="no_such_option"):
        set_option(highs, "no_such_option", 1)


# 3. .vts files must hold whole numbers


def test_03_vts_with_a_fraction_names_file_and_line(tmp_path):
    path = tmp_path / "a.vts"
    path.write_text("3\n12.7\n5\n")
    with pytest.raises(MeshError, match=r"a\.vts:2: '12\.7' is not an integer vertex index"):
        read_vts(path, 100)
    path.write_text("3\n12\n5\n")
    assert read_vts(path, 100).tolist() == [2, 11, 4]


# 4. resolution must be a face count


def test_04_resolution_zero_or_text_exit_2(tmp_path):
    for value in ("0", "abc", "2.5", "-10"):
        folder = tmp_path / value
        assert run_match(config("match", SMALL + [f"resolution={value}"]), folder) == 2
        assert "resolution=" in result_of(folder)["error"]


# 5. OFF header counts must match the content


def test_05_off_header_must_match_the_content(tmp_path):
    sphere_file = sphere(tmp_path / "sphere.off", 1)
    lines = sphere_file.read_text().splitlines()
    short = tmp_path / "short.off"
    short.write_text("\n".join(lines[:-3]) + "\n")
    with pytest.raises(
        MeshError, match=r"short\.off: the header promises 42 vertices and 80 faces.*77 faces"
    ):
        load_mesh(short)
    half = tmp_path / "half.off"
    half.write_text("\n".join(lines[: 2 + 42 + 40]) + "\n")
    with pytest.raises(MeshError, match=r"half\.off: the header promises .* 40 faces"):
        load_mesh(half)
    junk = tmp_path / "junk.off"
    junk.write_text("\n".join(lines + ["3 0 1 2"]) + "\n")
    with pytest.raises(MeshError, match=r"junk\.off:125: unexpected content after"):
        load_mesh(junk)
    assert load_mesh(sphere_file).n_faces == 80


# 6. a mesh far below the requested resolution is matched with a warning


def test_06_mesh_below_resolution_warns_in_result(tmp_path):
    source = write_off(tmp_path / "tet.off", TETRA_V, TETRA_F)
    target = write_off(tmp_path / "tet2.off", TETRA_V * [1.0, 1.2, 0.9], TETRA_F)
    code, folder = match_files(tmp_path, source, target, "resolution=150")
    result = result_of(folder)
    assert code == 0, result
    assert any("tet.off has only 4 faces, fewer than resolution=150" in w for w in result["warnings"])


# 7. an output that cannot be written: output_error, never 'optimal'


def test_07_disk_full_while_writing_the_png(tmp_path, monkeypatch):
    import spidermatch.report.plot

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(spidermatch.report.plot, "save_correspondence_png", full)
    folder = tmp_path / "run"
    cfg = config("match", ["data.n_verts=700", "resolution=60"])
    assert run_match(cfg, folder) == shutdown.EXIT_OUTPUT_ERROR
    result = result_of(folder)
    assert result["status"] == "output_error" and result["proven_optimal"] is False
    assert "correspondence.png" in result["error"] and "No space left" in result["error"]
    assert not list(folder.glob(".*tmp*")), "a temporary file was left behind"


# 8. SIGINT / SIGTERM during the solve: result.json 'interrupted', exit 130 / 143


def match_command(*args):
    return [sys.executable, "-c", "from spidermatch.cli.main import match_main; match_main()", *args]


def run_until_solving(tmp_path, signum):
    folder = tmp_path / f"run_{signum}"
    args = ["data.n_verts=2000", "resolution=200", "solver.strategy=plain", f"hydra.run.dir={folder}"]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).parents[1]), "SPIDERMATCH_CACHE_DIR": str(tmp_path)}
    process = subprocess.Popen(
        match_command(*args), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env
    )
    log = []
    for line in process.stdout:
        log.append(line)
        if "solve ..." in line:
            time.sleep(0.2)
            process.send_signal(signum)
            break
    log += process.stdout.readlines()
    return process.wait(timeout=120), folder, "".join(log)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_08_signal_during_the_solve(tmp_path, signum):
    code, folder, log = run_until_solving(tmp_path, signum)
    assert code == 128 + signum, log
    result = result_of(folder)
    assert result["status"] == "interrupted" and result["proven_optimal"] is False
    assert signal.Signals(signum).name in result["error"]
    assert {"incumbent_objective", "bound"} <= set(result)
    assert "Traceback" not in log
    assert not (folder / "matches.csv").exists()


def test_08_training_stops_on_sigterm_and_at_once_on_a_second_signal():
    """Training's loop: the first signal asks to stop after the step, a second one stops at once."""
    with shutdown.graceful_stops("stopping after this step"):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)
        assert shutdown.stop_requested() and shutdown.received_signal() == signal.SIGTERM
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
    assert not shutdown.stop_requested()  # the block forgets the signal


# 9. an unwritable run folder


def test_09_unwritable_run_folder(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    assert run_match(config("match", SMALL), blocker / "run") == shutdown.EXIT_OUTPUT_ERROR


@pytest.mark.skipif(not Path("/proc/self").exists(), reason="needs a /proc file system")
def test_09_run_folder_in_a_place_no_folder_can_be_made(tmp_path, monkeypatch):
    """Permissions alone do not tell (root may write anywhere by them, yet not into /proc)."""
    from spidermatch.cli.options import unwritable_folder

    monkeypatch.setattr(os, "access", lambda *args, **kwargs: True)  # as root sees it
    assert "no folder can be made in /proc" in unwritable_folder("/proc/spidermatch_run")
    assert unwritable_folder(tmp_path / "outputs" / "run") is None
    assert list(tmp_path.iterdir()) == []  # the probe left nothing behind


# 10. option values and names: exit 2 naming the option (through the real entry point)


def test_10_bad_options_on_the_command_line(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    for args, expected, code in [
        (["resolution=abc"], "resolution='abc'", 2),
        (["solver.time_limit=abc"], "solver.time_limit='abc'", 2),
        (["resolutoin=5"], "resolutoin", 2),
        (SMALL + [f"hydra.run.dir={blocker}/run"], "is not a folder", 6),
    ]:
        run = subprocess.run(
            match_command(*args, f"hydra.run.dir={tmp_path / 'out'}") if code == 2 else match_command(*args),
            capture_output=True,
            text=True,
            env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[1])},
            timeout=300,
        )
        assert run.returncode == code, (args, run.stderr[-2000:])
        assert expected in run.stderr + run.stdout and "Traceback" not in run.stderr, args


# 11. / 12. constraint families: ablations produce checked results, an empty set is refused


def test_11_cyc_only_ablation_is_checked_against_its_families(tmp_path):
    folder = tmp_path / "cyc"
    assert run_match(config("match", SMALL + ["costs.constraints=[CYC]"]), folder) == 0
    result = result_of(folder)
    assert result["status"] == "optimal" and result["check"]["ok"]
    assert (folder / "matches.csv").exists()


def test_12_empty_or_inconsistent_constraints_exit_2(tmp_path):
    for value in ("[]", "[CON,PES]", "[CYC,XYZ]"):
        folder = tmp_path / value.strip("[]").replace(",", "_")
        assert run_match(config("match", SMALL + [f"costs.constraints={value}"]), folder) == 2
        assert "costs.constraints" in result_of(folder)["error"]


# 13. a non-manifold (bowtie) vertex is reported on the input mesh


def test_13_bowtie_vertex_names_file_and_input_vertex(tmp_path):
    verts = np.concatenate([TETRA_V, -TETRA_V[1:]]) + [5.0, 0, 0]
    faces = np.concatenate([TETRA_F, [[0, 4, 5], [0, 6, 4], [0, 5, 6], [4, 6, 5]]])
    path = write_off(tmp_path / "bowtie.off", verts, faces)
    with pytest.raises(MeshError, match=r"bowtie\.off: 1 non-manifold vertices .*first: vertex 0"):
        load_mesh(path)


# 14. ground-truth files of different lengths are refused before any solve


def test_14_vts_lengths_compared_before_the_solve(tmp_path):
    shapes = SyntheticShapes(n_shapes=2, n_verts=700)
    root = write_dataset(shapes, tmp_path / "data")
    target_vts = root / "corres" / "creature_001.vts"
    target_vts.write_text("\n".join(target_vts.read_text().split()[:-5]) + "\n")
    code, folder = match_files(
        tmp_path,
        root / "off" / "creature_000.off",
        root / "off" / "creature_001.off",
        f"source_corr={root / 'corres' / 'creature_000.vts'}",
        f"target_corr={target_vts}",
        "resolution=60",
    )
    result = result_of(folder)
    assert code == 2 and "creature_000.vts" in result["error"] and "creature_001.vts" in result["error"]
    assert "solve_time_s" not in result and not (folder / "matches.csv").exists()


# 15. different topology is refused up front


def test_15_torus_against_sphere_is_refused(tmp_path):
    torus_file, sphere_file = torus(tmp_path / "torus.off"), sphere(tmp_path / "sphere.off")
    assert (topology(load_mesh(torus_file)).genus, topology(load_mesh(sphere_file)).genus) == (1, 0)
    code, folder = match_files(tmp_path, torus_file, sphere_file, "resolution=100")
    result = result_of(folder)
    assert code == 2 and "genus 1" in result["error"] and "genus 0" in result["error"]
    assert "allow_topology_mismatch" in result["error"]


def test_15_topology_of_an_open_surface():
    mesh = trimesh.creation.icosphere(subdivisions=1)
    keep = mesh.vertices[mesh.faces].mean(axis=1)[:, 2] < 0.5  # cut off a cap: one boundary loop
    faces = mesh.faces[keep]
    used = np.unique(faces)
    remap = np.full(len(mesh.vertices), -1)
    remap[used] = np.arange(used.size)
    top = topology(Mesh(mesh.vertices[used], remap[faces]))
    assert (top.genus, top.boundaries) == (0, 1)


# result files: atomic, with the normal file mode


def test_written_files_get_the_umask_mode(tmp_path):
    path = tmp_path / "x.json"
    shutdown.write_atomic(path, "{}\n")
    umask = os.umask(0)
    os.umask(umask)
    assert (path.stat().st_mode & 0o777) == (0o666 & ~umask)
    assert [p.name for p in tmp_path.iterdir()] == ["x.json"]


def test_file_identity_changes_with_the_file(tmp_path):
    path = tmp_path / "m.off"
    save_mesh(Mesh(TETRA_V, TETRA_F), path)
    before = file_identity(path)
    path.write_text(path.read_text() + "\n")
    assert file_identity(path) != before


# property test: randomly corrupted mesh files load as valid meshes or fail with our error


def _corrupt_tokens(text: str, rng) -> str:
    tokens = text.split(" ")
    lines = text.splitlines()
    kind = rng.integers(6)
    if kind == 0:  # a number replaced by NaN, inf, text, a fraction, a huge or negative value
        words = text.replace("\n", " \n ").split(" ")
        numbers = [i for i, w in enumerate(words) if w.strip() and w != "\n"]
        i = numbers[rng.integers(len(numbers))]
        words[i] = str(
            rng.choice(["nan", "inf", "-inf", "abc", "1.5", "1e999", "-1", "99999999999999999999", "0x10"])
        )
        return " ".join(words).replace(" \n ", "\n")
    if kind == 1:  # a face index out of range
        face_lines = [i for i, line in enumerate(lines) if line.startswith("3 ") or line.startswith("f ")]
        i = face_lines[rng.integers(len(face_lines))]
        parts = lines[i].split()
        parts[1 + rng.integers(3)] = str(int(rng.choice([-1, 10_000, len(lines)])))
        lines[i] = " ".join(parts)
    elif kind == 2:  # lines shuffled
        body = lines[1:]
        rng.shuffle(body)
        lines = lines[:1] + body
    elif kind == 3:  # a line deleted or duplicated
        i = 1 + rng.integers(len(lines) - 1)
        lines = lines[:i] + lines[i + 1 :] if rng.random() < 0.5 else lines[: i + 1] + lines[i:]
    elif kind == 4:  # junk appended
        lines.append(str(rng.choice(["junk", "3 0 1", "0 0 0", "#"])))
    else:
        return " ".join(tokens[: rng.integers(1, len(tokens))])  # cut at a random token
    return "\n".join(lines) + "\n"


def corrupted(data: bytes, rng) -> bytes:
    kind = rng.integers(4)
    if kind == 0:  # truncated at a random byte
        return data[: rng.integers(len(data))]
    if kind == 1:  # random bytes flipped
        array = bytearray(data)
        for _ in range(rng.integers(1, 6)):
            array[rng.integers(len(array))] = int(rng.integers(256))
        return bytes(array)
    return _corrupt_tokens(data.decode(), rng).encode()


def base_meshes() -> dict:
    tet = "OFF\n4 4 0\n" + "\n".join(" ".join(str(c) for c in v) for v in TETRA_V)
    tet += "\n" + "\n".join("3 " + " ".join(map(str, f)) for f in TETRA_F) + "\n"
    sphere_mesh = trimesh.creation.icosphere(subdivisions=1)
    obj = "".join(f"v {x} {y} {z}\n" for x, y, z in sphere_mesh.vertices)
    obj += "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in sphere_mesh.faces)
    octa = trimesh.creation.icosphere(subdivisions=0)
    off = f"OFF\n{len(octa.vertices)} {len(octa.faces)} 0\n"
    off += "".join(f"{x} {y} {z}\n" for x, y, z in octa.vertices) + "".join(
        f"3 {a} {b} {c}\n" for a, b, c in octa.faces
    )
    return {".off": [tet.encode(), off.encode()], ".obj": [obj.encode()]}


N_CORRUPTIONS = 1200


def test_corrupted_mesh_files_never_escape_as_other_errors(tmp_path):
    rng = np.random.default_rng(17)
    bases = base_meshes()
    outcomes = {"loaded": 0, "refused": 0}
    for case in range(N_CORRUPTIONS):
        suffix = ".off" if case % 5 else ".obj"
        data = bases[suffix][case % len(bases[suffix])]
        path = tmp_path / f"case_{case:04d}{suffix}"
        path.write_bytes(corrupted(data, rng))
        try:
            mesh = load_mesh(path)
        except MeshError as error:
            assert str(path) in str(error), (case, str(error))
            outcomes["refused"] += 1
            continue
        except Exception as error:  # noqa: BLE001
            pytest.fail(f"case {case} ({path.read_bytes()[:200]!r}): {type(error).__name__}: {error}")
        assert np.isfinite(mesh.verts).all() and mesh.faces.min() >= 0 and mesh.faces.max() < mesh.n_verts
        outcomes["loaded"] += 1
    print(f"{N_CORRUPTIONS} corrupted files: {outcomes}")
    assert outcomes["refused"] > N_CORRUPTIONS // 2


def test_corrupted_files_through_the_command_line(tmp_path):
    good = sphere(tmp_path / "good.off", 1)
    lines = good.read_text().splitlines()
    cases = {
        "nan.off": "\n".join(lines[:5] + ["nan 0 0"] + lines[6:]),
        "range.off": "\n".join(lines[:-1] + ["3 0 1 999"]),
        "binary.off": "OFF\n\x00\xff\xfe garbage",
    }
    for name, text in cases.items():
        path = tmp_path / name
        path.write_text(text + "\n")
        run = subprocess.run(
            match_command(
                f"source={path}", f"target={good}", "resolution=60", f"hydra.run.dir={tmp_path / name}.run"
            ),
            capture_output=True,
            text=True,
            env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[1])},
            timeout=300,
        )
        assert run.returncode == 2, (name, run.stderr[-2000:])
        assert str(path) in run.stdout + run.stderr and "Traceback" not in run.stderr, name


# 9. a native crash of the solver (issue 28): result.json 'solver_failure', exit 5, the figures known


def test_09_a_native_crash_of_the_solver_ends_in_solver_failure_with_what_was_known(tmp_path, monkeypatch):
    from spidermatch import pipeline
    from spidermatch.solve.progress import report_known

    def crashing(name, model, graph, curve, options):
        report_known(incumbent=12.5, bound=10.0)
        report_known(incumbent=13.0, bound=11.0)  # a dearer incumbent changes nothing
        os.abort()  # as free(): invalid pointer does in HiGHS

    monkeypatch.setattr(pipeline, "solve_with_strategy", crashing)
    folder = tmp_path / "run"
    code = run_match(config("match", [*SMALL, f"hydra.run.dir={folder}"]), folder)
    assert code == 5
    result = result_of(folder)
    assert result["status"] == "solver_failure" and result["proven_optimal"] is False
    assert result["objective"] == 12.5 and result["bound"] == 11.0
    assert result["gap"] == pytest.approx(1.5 / 12.5)
    assert "SIGABRT" in result["error"]
    assert not (folder / "matches.csv").exists()
