"""Bad inputs and faults as users bring them: every case run as its own process, one row each.

Each case is a whole ``spidermatch-match`` (or ``spidermatch-train``, or a Python API call)
process under a memory cap (``--memory-gib``, RLIMIT_AS) and a wall-clock cap, on copies of
FAUST_r tr_reg_070 -> tr_reg_071 at ``resolution=150`` with WKS unless the case says
otherwise. A row holds the exit code, the ``status`` in ``result.json``, the first error line
of the log (or the API's exception), the peak memory and the wall time, and what the case
checks beyond that (e.g. whether stale files of an earlier run remain).

Example (the table of the bad-input audit):

    .venv/bin/python bench/audit_bad_inputs.py --data ../shared/data/FAUST_r \
        --out bench/results/bad_input_audit

Writes ``<out>.csv`` and ``<out>.md``; ``--only`` runs the named cases (written into the work
folder unless ``--out`` is given, so that the committed table stays whole).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


@dataclass
class Case:
    """One audit case: a command and, optionally, a check of what it left behind."""

    name: str
    what: str
    argv: list
    check: object = None  # callable(run_dir) -> str, the case's own finding
    stdin_signal: tuple | None = None  # (seconds, signal) sent to the process after a delay
    extra: dict = field(default_factory=dict)


def write_off(path: Path, verts, faces) -> Path:
    """``verts``/``faces`` as an OFF file, unchecked (the audit writes broken meshes on purpose)."""
    sys.path.insert(0, str(ROOT))
    from spidermatch.geometry.io import save_mesh
    from spidermatch.geometry.mesh import Mesh

    save_mesh(Mesh(verts, faces), path)
    return path


def read_off(path: Path):
    sys.path.insert(0, str(ROOT))
    from spidermatch.geometry.io import read_off as read

    return read(path)


def match(*args) -> list:
    return [str(BIN / "spidermatch-match"), *map(str, args)]


def api(code: str) -> list:
    """A Python API call in its own process; prints the exception's type and message."""
    wrapped = (
        "import logging, sys\nlogging.basicConfig(level=logging.WARNING)\n"
        "try:\n" + "".join(f"    {line}\n" for line in code.splitlines()) + "except Exception as e:\n"
        "    print(f'ERROR {type(e).__name__}: {e}'[:400]); sys.exit(1)\n"
    )
    return [sys.executable, "-c", wrapped]


def make_cases(data: Path, work: Path) -> list[Case]:
    off = data / "off"
    x, y = off / "tr_reg_070.off", off / "tr_reg_071.off"
    vx, fx, _ = read_off(x)
    flipped = fx.copy()
    flipped[::2] = flipped[::2, ::-1]
    write_off(work / "flipped.off", vx, flipped)
    write_off(work / "big.off", vx * 1e30, fx)
    obj_groups = ["o body", "usemtl skin"] + [f"v {a} {b} {c}" for a, b, c in vx]
    obj_groups += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in fx[: len(fx) // 2]]
    obj_groups += ["o rest", "usemtl cloth"] + [
        f"f {a + 1} {b + 1} {c + 1}" for a, b, c in fx[len(fx) // 2 :]
    ]
    (work / "groups.obj").write_text("\n".join(obj_groups) + "\n")
    (work / "a_folder.off").mkdir(exist_ok=True)
    vts = data / "corres"
    two_col = np.loadtxt(vts / "tr_reg_070.vts", dtype=int)
    np.savetxt(work / "two_columns.vts", np.stack([two_col, two_col], 1), fmt="%d")
    tet_v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    tet_f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    write_off(work / "tet_a.off", tet_v, tet_f)
    write_off(work / "tet_b.off", tet_v * [1, 1.2, 0.9], tet_f)
    write_off(work / "raw_scan.off", *raw_scan(vx, fx))
    write_off(work / "scan_holes.off", *scanner_holes(*read_off(y)[:2], SCANNER_HOLES))
    write_binary_stl(work / "source.stl", vx, fx)
    write_soup_obj(work / "target_soup.obj", *read_off(y)[:2])
    base = [f"source={x}", f"target={y}", "resolution=150"]
    reuse = work / "reused"

    def run_into_reused(run_dir):
        first = subprocess.run(match(*base, f"hydra.run.dir={reuse}"), capture_output=True)
        before = {p.name: p.stat().st_mtime for p in reuse.iterdir() if p.is_file()}
        second = match(
            f"source={off / 'tr_reg_072.off'}",
            f"target={off / 'tr_reg_073.off'}",
            "resolution=150",
            "dense.enabled=false",
            "output.png=false",
            f"hydra.run.dir={reuse}",
        )
        subprocess.run(second, capture_output=True)
        stale = sorted(
            p.name
            for p in reuse.iterdir()
            if p.is_file()
            and p.name in before
            and p.stat().st_mtime == before[p.name]
            and p.name != "result.json"
        )
        return f"first exit {first.returncode}; left from the first run: {', '.join(stale) or 'nothing'}"

    return [
        Case(
            "flipped_faces",
            "every second source face reversed",
            match(f"source={work / 'flipped.off'}", f"target={y}", "resolution=150"),
        ),
        Case(
            "huge_resolution",
            "resolution=1000000000",
            match(*base[:2], "resolution=1000000000", "solver.time_limit=30"),
        ),
        Case("dense_radius_text", "dense.radius=abc", match(*base, "dense.radius=abc")),
        Case("dense_smoothing_text", "dense.smoothing=abc", match(*base, "dense.smoothing=abc")),
        Case("dense_neighbours_fraction", "dense.n_neighbours=2.5", match(*base, "dense.n_neighbours=2.5")),
        Case("dense_weight_text", "dense.distance_weight=abc", match(*base, "dense.distance_weight=abc")),
        Case("target_list", "target=[1,2]", match(base[0], "target=[1,2]", "resolution=150")),
        Case("target_dict", "target={a:1}", match(base[0], "target={a:1}", "resolution=150")),
        Case(
            "reused_folder",
            "second pair into the first pair's folder, dense and PNGs off",
            ["true"],
            check=run_into_reused,
        ),
        Case("gap_0.9", "solver.mip_rel_gap=0.9", match(*base, "solver.mip_rel_gap=0.9")),
        Case(
            "tetrahedra",
            "tetrahedron -> tetrahedron",
            match(f"source={work / 'tet_a.off'}", f"target={work / 'tet_b.off'}", "resolution=4"),
        ),
        Case(
            "train_sigterm",
            "spidermatch-train, SIGTERM after 25 s",
            [str(BIN / "spidermatch-train"), "run.n_steps=100000"],
            stdin_signal=(25, signal.SIGTERM),
        ),
        Case(
            "api_object_verts",
            "API: (V, F) with str vertices",
            api(
                "import numpy as np, spidermatch\nv=np.array([['a','b','c']]*4, dtype=object)\n"
                "f=np.array([[0,2,1],[0,1,3],[0,3,2],[1,2,3]])\nspidermatch.match((v,f),(v,f))"
            ),
        ),
        Case(
            "api_complex_verts",
            "API: complex vertices",
            api(
                "import numpy as np, spidermatch\nv=np.array([[0,0,0],[1,0,0],[0,1,0],[0,0,1]])+0j\n"
                "f=np.array([[0,2,1],[0,1,3],[0,3,2],[1,2,3]])\nprint(spidermatch.match((v,f),(v,f)))"
            ),
        ),
        Case(
            "api_resolution_float",
            "API: resolution=150.9",
            api(f"import spidermatch\nprint(spidermatch.match('{x}','{y}',resolution=150.9))"),
        ),
        Case(
            "api_resolution_str",
            "API: resolution='150'",
            api(f"import spidermatch\nprint(spidermatch.match('{x}','{y}',resolution='150'))"),
        ),
        Case(
            "api_time_limit_nan",
            "API: time_limit=nan",
            api(
                f"import spidermatch\nprint(spidermatch.match('{x}','{y}',resolution=150,"
                "time_limit=float('nan')))"
            ),
        ),
        Case(
            "api_gap_5",
            "API: mip_rel_gap=5",
            api(f"import spidermatch\nprint(spidermatch.match('{x}','{y}',resolution=150,mip_rel_gap=5))"),
        ),
        Case(
            "api_features_1e200",
            "API: WKS features x 1e200",
            api(
                "import spidermatch\nfrom spidermatch.geometry.descriptors import WKSExtractor\n"
                "from spidermatch.geometry.io import load_mesh\n"
                f"a,b=load_mesh('{x}'),load_mesh('{y}')\nw=WKSExtractor()\n"
                "m=spidermatch.match(a,b,features=(w(a.centred())*1e200,w(b.centred())*1e200),resolution=150)\n"
                "import numpy as np\nprint(m, 'distinct targets', len(np.unique(m.matches[:,1])))"
            ),
        ),
        Case(
            "obj_groups",
            "OBJ with o groups and usemtl",
            match(f"source={work / 'groups.obj'}", f"target={y}", "resolution=150"),
        ),
        Case(
            "directory_mesh",
            "a directory given as the source",
            match(f"source={work / 'a_folder.off'}", f"target={y}", "resolution=150"),
        ),
        Case(
            "vts_two_columns",
            "a two-column .vts",
            match(*base, f"source_corr={work / 'two_columns.vts'}", f"target_corr={vts / 'tr_reg_071.vts'}"),
        ),
        Case("png_maybe", "output.png=maybe", match(*base, "output.png=maybe")),
        Case(
            "coords_1e30",
            "source coordinates x 1e30",
            match(f"source={work / 'big.off'}", f"target={y}", "resolution=150"),
        ),
        Case(
            "raw_scan_source",
            "source with a bow-tie triangle, a debris island, a stray vertex, a degenerate face",
            match(f"source={work / 'raw_scan.off'}", f"target={y}", "resolution=150"),
        ),
        Case(
            "raw_scan_repaired",
            "the same with repair=true",
            match(f"source={work / 'raw_scan.off'}", f"target={y}", "resolution=150", "repair=true"),
        ),
        Case(
            "raw_scan_target",
            "the raw scan as the target, repair=true",
            match(f"source={y}", f"target={work / 'raw_scan.off'}", "resolution=150", "repair=true"),
        ),
        Case(
            "scan_holes_target",
            "the target with three small holes (the faces around 3 vertices cut), no options",
            match(f"source={x}", f"target={work / 'scan_holes.off'}", "resolution=150"),
        ),
        Case(
            "stl_source",
            "the source as a binary STL file (a triangle soup), no options",
            match(f"source={work / 'source.stl'}", f"target={y}", "resolution=150"),
        ),
        Case(
            "soup_obj_target",
            "the target as an OBJ with three vertices of its own per face, no options",
            match(f"source={x}", f"target={work / 'target_soup.obj'}", "resolution=150"),
        ),
    ]


def write_binary_stl(path: Path, verts: np.ndarray, faces: np.ndarray) -> Path:
    """A binary STL file: an 80-byte header, the facet count, then per facet a normal, three corners
    and a 2-byte attribute (all float32), as scanners export them."""
    corners = verts[faces].astype(np.float32)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    facets = np.zeros(len(faces), dtype=record)
    facets["normal"], facets["corners"] = normals, corners
    with open(path, "wb") as handle:
        handle.write(b"audit".ljust(80, b" ") + np.uint32(len(faces)).tobytes() + facets.tobytes())
    return path


def write_soup_obj(path: Path, verts: np.ndarray, faces: np.ndarray) -> Path:
    """An OBJ file with three vertices of its own per face (as some exporters write)."""
    lines = [f"v {a} {b} {c}" for a, b, c in verts[faces].reshape(-1, 3)]
    lines += [f"f {3 * i + 1} {3 * i + 2} {3 * i + 3}" for i in range(len(faces))]
    path.write_text("\n".join(lines) + "\n")
    return path


SCANNER_HOLES = (100, 2500, 4000)
"""Vertices whose faces ``scanner_holes`` cuts away from tr_reg_071 (three small holes)."""


def scanner_holes(verts: np.ndarray, faces: np.ndarray, centres: tuple) -> tuple[np.ndarray, np.ndarray]:
    """A closed mesh with the faces around each of ``centres`` cut away, as a scanner leaves holes.

    Returns the vertices left (V - len(centres), 3) and their faces.
    """
    keep = ~np.isin(faces, centres).any(axis=1)
    used = np.unique(faces[keep])
    index = -np.ones(len(verts), dtype=np.int64)
    index[used] = np.arange(used.size)
    return verts[used], index[faces[keep]]


def raw_scan(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A mesh as a raw scan may come: a lone triangle touching vertex 0 (a bow-tie), a two-triangle
    island of debris beside it, a stray vertex and a degenerate face.

    Returns vertices (V + 7, 3) and faces (F + 4, 3), the mesh's own first.
    """
    n, size = len(verts), float(np.ptp(verts, axis=0).max())
    far = verts.max(axis=0) + size * np.array([[0.3, 0, 0], [0.35, 0, 0], [0.3, 0.05, 0], [0.35, 0.05, 0.02]])
    lone = verts[0] + 0.02 * size * np.array([[1.0, 0, 0], [1.0, 1.0, 0]])
    extra = np.vstack([lone, far, verts.max(axis=0) + size])
    more = [[0, n, n + 1], [n + 2, n + 3, n + 4], [n + 3, n + 5, n + 4], [1, 1, 2]]
    return np.vstack([verts, extra]), np.vstack([faces, more])


def first_problem(log: str) -> str:
    """The log's first ERROR line, else a raised exception's last line, else its last line."""
    lines = [line for line in log.splitlines() if line.strip() and "it/s]" not in line]
    for pattern in ("][ERROR]", "ERROR ", "Error: ", "Error", "][WARNING]"):
        found = [line for line in lines if pattern in line]
        if found:
            return found[-1] if pattern in ("Error: ", "Error") else found[0]
    return lines[-1] if lines else ""


def run_case(case: Case, work: Path, memory_gib: float, timeout: float) -> dict:
    run_dir = work / f"run_{case.name}"
    shutil.rmtree(run_dir, ignore_errors=True)
    argv = list(case.argv)
    if argv and argv[0].endswith(("spidermatch-match", "spidermatch-train")):
        argv.append(f"hydra.run.dir={run_dir}")
    cap = int(memory_gib * 2**30)
    start = time.perf_counter()
    log = work / f"{case.name}.log"
    with open(log, "w") as out:
        process = subprocess.Popen(
            argv,
            stdout=out,
            stderr=subprocess.STDOUT,
            cwd=work,
            preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (cap, cap)),
        )
        if case.stdin_signal:
            time.sleep(case.stdin_signal[0])
            process.send_signal(case.stdin_signal[1])
        deadline = time.time() + timeout
        while True:
            pid, status, usage = os.wait4(process.pid, os.WNOHANG)
            if pid:
                break
            if time.time() > deadline:
                process.kill()
            time.sleep(0.2)
    code = os.waitstatus_to_exitcode(status)
    text = log.read_text(errors="replace")
    result = run_dir / "result.json"
    report = json.loads(result.read_text()) if result.is_file() else {}
    status_text = report.get("status", "-")
    message = first_problem(text)
    row = {
        "case": case.name,
        "what": case.what,
        "exit_code": code,
        "status": status_text,
        "gap": "-" if report.get("gap") is None else f"{report['gap']:.2g}",
        "traceback": "Traceback" in text,
        "peak_mib": round(usage.ru_maxrss / 1024),
        "wall_s": round(time.perf_counter() - start, 1),
        "message": message.split("] - ")[-1][:300],
    }
    if case.check:
        row["message"] = case.check(run_dir)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "FAUST_r"))
    parser.add_argument(
        "--out",
        default=None,
        help="results path without suffix (default: bench/results/bad_input_audit; with --only, the work "
        "folder, so that a few cases never overwrite the full table)",
    )
    parser.add_argument("--memory-gib", type=float, default=8.0)
    parser.add_argument("--timeout", type=float, default=600.0)
    parser.add_argument("--only", nargs="*", default=None)
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="audit_"))
    rows = []
    for case in make_cases(Path(args.data).resolve(), work):  # the cases run in other folders
        if args.only and case.name not in args.only:
            continue
        row = run_case(case, work, args.memory_gib, args.timeout)
        print(" | ".join(str(v) for v in row.values()), flush=True)
        rows.append(row)
    if not rows:
        raise SystemExit(f"no case named {' '.join(args.only)}")
    default_out = work / "bad_input_audit" if args.only else ROOT / "bench" / "results" / "bad_input_audit"
    out = Path(args.out) if args.out else default_out
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.with_suffix(".csv"), "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    lines = ["| " + " | ".join(rows[0]) + " |", "|" + "---|" * len(rows[0])]
    lines += ["| " + " | ".join(str(v).replace("|", "/") for v in row.values()) + " |" for row in rows]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out.with_suffix('.csv')} and {out.with_suffix('.md')} (work folder {work})")


if __name__ == "__main__":
    main()
