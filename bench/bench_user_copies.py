"""Whole matches of FAUST_r pairs as users bring them: other units and poses, dense raw scans.

For every pair, ``spidermatch-match`` runs (its own process, under a memory cap) on the clean
files and on copies made the way users' files arrive:

``scaled``
    the target in millimetres (x1000), turned by a random rotation and moved;
``sub80k``
    both meshes Loop-subdivided twice (about 80 000 vertices) with scan noise (Gaussian,
    0.1 of the mean edge length, along the normals);
``sub200k``
    the ``sub320k`` copy (below) decimated to 200 000 vertices (libigl edge collapses), its
    ground truth moved to the nearest remaining vertex;
``sub320k``
    three times (about 320 000 vertices), with the same noise;
``holes``
    small holes where a scanner saw nothing: the faces around ``SCAN_HOLES`` random vertices
    (two rings: about 0.3 % of the area each) cut from each mesh, 4 from the source and 6 from
    the target, each reference point of a cut vertex moved to the nearest vertex left.
``stl``
    both meshes as binary STL files (a triangle soup: three vertices per facet, float32), the
    target in millimetres, turned and moved as ``scaled``; the run's outputs name the files'
    corners and are told back in the original vertices to be scored.
``noisy20k``
    both meshes subdivided once at their edges' midpoints (about 20 000 vertices) with a
    depth camera's noise: Gaussian in every direction, ``NOISY_SHARE`` of the bounding box's
    diagonal (3.8 mm on a body 1.9 m across; the copies' edges are 5.6 mm long);
``noisy80k``
    the same noise on meshes subdivided twice (about 80 000 vertices, edges 2.8 mm: the noise is
    larger than the edges, the surface crumpled);
``needles``
    the faces of the upper body (centroids above the median height) split three times at their
    centroids (about 57 000 vertices, vertices of degree up to 64 among needle triangles; the
    rest at the original density), as some exporters triangulate;
``scene``
    both meshes as glTF binary scenes (``.glb``) of ``SCENE_PARTS`` parts (bands of faces by
    height), each stored in single precision moved away from the body and placed back by its
    node's transform, as an exporter writes the objects of a scene; the target in millimetres,
    turned and moved as ``scaled``. The two sides of each seam lie a rounding error apart.

Loop subdivision keeps the original vertices first, so the ``corres/*.vts`` ground truth
applies to the subdivided copies. Each match runs as a user runs it, without ground truth:
its wall time and peak memory are the user's. The errors are measured afterwards in this
process (their time apart, ``eval_s``): the sparse map at all its matches, the dense map at
``--eval-points`` reference points (a fixed sample, the same for every copy of a pair, as
exact geodesics on a 300 000-vertex target take a second each). A row holds the status,
gap, objective, both mean geodesic errors, the wall time, the peak memory and every
stage's time; the summary gives each copy's error against the clean pair's.

Example (the five FAUST_r validation pairs, WKS, the default resolution):

    .venv/bin/python bench/bench_user_copies.py --data ../shared/data/FAUST_r \
        --kinds scaled sub80k --out bench/results/user_copies_faust_val_wks

Writes ``<out>.json`` and ``<out>.csv``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_scaling import write_rows  # noqa: E402

from spidermatch.data.synthetic import centroid_split, random_rotation  # noqa: E402
from spidermatch.eval.errors import dense_map_errors, sparse_map_errors  # noqa: E402
from spidermatch.geometry.geodesics import GeodesicDistances  # noqa: E402
from spidermatch.geometry.io import load_mesh, read_vts, save_mesh, write_vts  # noqa: E402
from spidermatch.geometry.mesh import Mesh  # noqa: E402
from spidermatch.geometry.operators import vertex_normals  # noqa: E402
from spidermatch.geometry.partial import kept_part  # noqa: E402
from spidermatch.geometry.remesh import decimate, nearest_vertices  # noqa: E402

VALIDATION_PAIRS = [f"tr_reg_{i:03d}:tr_reg_{i + 1:03d}" for i in range(70, 80, 2)]
KINDS = ("clean", "scaled", "sub80k", "sub200k", "sub320k", "holes", "stl", "scene")
KINDS += ("noisy20k", "noisy80k", "needles")
NOISY_SHARE = 0.002
"""Noise of the ``noisy*`` copies (standard deviation per axis) over the bounding box's diagonal."""
NOISY_SUBDIVISIONS = {"noisy20k": 1, "noisy80k": 2}
NEEDLE_SPLITS = 3
"""Times the ``needles`` copy splits the upper body's faces at their centroids."""
SCENE_PARTS = 3
"""Parts of the ``scene`` copy, each with its own vertices and node transform."""
SCAN_HOLES = (4, 6)
"""Small holes cut from the source and from the target by the ``holes`` copy."""
HOLE_RINGS = 2
"""Rings of faces around each hole's centre vertex that the ``holes`` copy cuts away."""
SUBDIVISIONS = {"sub80k": 2, "sub200k": 3, "sub320k": 3}
DECIMATED_VERTICES = {"sub200k": 200_000}


def scan_copy(mesh: Mesh, times: int, rng) -> Mesh:
    """``mesh`` Loop-subdivided ``times`` times, with noise along the normals (original vertices first)."""
    import trimesh

    verts, faces = mesh.verts, mesh.faces
    for _ in range(times):
        verts, faces = trimesh.remesh.subdivide_loop(verts, faces)
    edges = np.linalg.norm(verts[faces[:, 0]] - verts[faces[:, 1]], axis=1)
    noise = rng.normal(scale=0.1 * edges.mean(), size=len(verts))
    return Mesh(verts + noise[:, None] * vertex_normals(verts, faces), faces, mesh.name)


def copies(kind: str, meshes: list[Path], corr: list[Path], folder: Path, seed: int) -> tuple[list, list]:
    """The pair's mesh and ground-truth files for ``kind`` (made in ``folder`` unless clean)."""
    if kind == "clean":
        return meshes, corr
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    if kind == "scaled":
        mesh = load_mesh(meshes[1])
        moved = in_millimetres_turned(mesh.verts, rng)
        out = folder / f"{meshes[1].stem}_mm.off"
        save_mesh(Mesh(moved, mesh.faces), out)
        return [meshes[0], out], corr
    if kind == "holes":
        return holed_copies(meshes, corr, folder, rng)
    if kind == "stl":
        return stl_copies(meshes, folder, rng), corr
    if kind == "scene":
        return scene_copies(meshes, folder, rng), corr
    if kind in NOISY_SUBDIVISIONS:
        return noisy_copies(meshes, folder, rng, kind), corr
    if kind == "needles":
        return needle_copies(meshes, folder), corr
    made_meshes, made_corr = [], []
    for path, truth in zip(meshes, corr):
        out, out_corr = folder / f"{path.stem}_{kind}.off", folder / f"{path.stem}_{kind}.vts"
        if not out.is_file() or not out_corr.is_file():
            scan = scan_copy(load_mesh(path), SUBDIVISIONS[kind], rng)
            truth_vertices = read_vts(truth)
            if kind in DECIMATED_VERTICES:
                scan, truth_vertices = decimated_copy(scan, truth_vertices, DECIMATED_VERTICES[kind])
            save_mesh(scan, out)
            write_vts(truth_vertices, out_corr)
        made_meshes.append(out)
        made_corr.append(out_corr)
    return made_meshes, made_corr


def in_millimetres_turned(verts: np.ndarray, rng) -> np.ndarray:
    """``verts`` (V, 3) in metres as a user's target arrives: in millimetres, turned and moved."""
    return 1000.0 * verts @ random_rotation(rng).T + rng.uniform(-2000, 2000, size=3)


def stl_copies(meshes: list[Path], folder: Path, rng) -> list[Path]:
    """Both meshes written as binary STL (the target in mm, turned and moved), as a scanner exports them."""
    import trimesh

    made = []
    for index, path in enumerate(meshes):
        mesh = load_mesh(path)
        verts = in_millimetres_turned(mesh.verts, rng) if index == 1 else mesh.verts
        out = folder / f"{path.stem}.stl"
        trimesh.Trimesh(verts, mesh.faces, process=False).export(out)
        made.append(out)
    return made


def noisy_copies(meshes: list[Path], folder: Path, rng, kind: str) -> list[Path]:
    """Both meshes subdivided with ``NOISY_SHARE`` noise (original vertices first: same truth)."""
    import trimesh

    made = []
    for path in meshes:
        mesh = load_mesh(path)
        verts, faces = mesh.verts, mesh.faces
        for _ in range(NOISY_SUBDIVISIONS[kind]):
            verts, faces = trimesh.remesh.subdivide(verts, faces)
        diagonal = np.linalg.norm(np.ptp(verts, axis=0))
        noisy = verts + rng.normal(scale=NOISY_SHARE * diagonal, size=verts.shape)
        out = folder / f"{path.stem}_{kind}.off"
        save_mesh(Mesh(noisy, faces), out)
        made.append(out)
    return made


def needle_copies(meshes: list[Path], folder: Path) -> list[Path]:
    """Both meshes with the upper body's faces split ``NEEDLE_SPLITS`` times at their centroids."""
    made = []
    for path in meshes:
        mesh = load_mesh(path)
        verts, faces = mesh.verts, mesh.faces
        upper = verts[faces].mean(axis=1)[:, 1] > np.median(verts[:, 1])
        for _ in range(NEEDLE_SPLITS):
            verts, faces, upper = centroid_split(verts, faces, upper)
        out = folder / f"{path.stem}_needles.off"
        save_mesh(Mesh(verts, faces), out)
        made.append(out)
    return made


def scene_copies(meshes: list[Path], folder: Path, rng) -> list[Path]:
    """Both meshes as .glb scenes of ``SCENE_PARTS`` parts placed by node transforms (see the module)."""
    import trimesh

    made = []
    for index, path in enumerate(meshes):
        mesh = load_mesh(path)
        verts = in_millimetres_turned(mesh.verts, rng) if index == 1 else mesh.verts
        height = verts[mesh.faces].mean(axis=1)[:, 1]
        band = np.searchsorted(np.quantile(height, np.linspace(0, 1, SCENE_PARTS + 1)[1:-1]), height)
        scene = trimesh.Scene()
        for part in range(SCENE_PARTS):
            used, local = np.unique(mesh.faces[band == part], return_inverse=True)
            offset = rng.uniform(-5, 5, size=3) * np.ptp(verts, axis=0)  # where the part is stored
            stored = trimesh.Trimesh(verts[used] - offset, local.reshape(-1, 3), process=False)
            placement = trimesh.transformations.translation_matrix(offset)
            scene.add_geometry(stored, node_name=f"part{part}", geom_name=f"part{part}", transform=placement)
        out = folder / f"{path.stem}.glb"
        out.write_bytes(trimesh.exchange.gltf.export_glb(scene))
        np.save(out.with_suffix(".npy"), file_vertices_of(out, verts))
        made.append(out)
    return made


def file_vertices_of(path: Path, placed: np.ndarray) -> np.ndarray:
    """Original vertex (V_file,) at each vertex of the copy ``path`` as spidermatch reads it.

    ``placed`` (V, 3) holds the original vertices where the copy puts them.
    """
    from scipy.spatial import cKDTree

    copy = load_mesh(path, validate=False)
    distance, vertex = cKDTree(placed).query(copy.verts)
    assert distance.max() < 1e-6 * np.ptp(placed), f"{path}: a vertex lies off its original"
    return vertex


def holed_copies(meshes: list[Path], corr: list[Path], folder: Path, rng) -> tuple[list, list]:
    """Each mesh with ``SCAN_HOLES`` small holes cut, and its ground truth on the vertices left."""
    made_meshes, made_corr = [], []
    for path, truth, holes in zip(meshes, corr, SCAN_HOLES):
        mesh = load_mesh(path)
        holed = holed_copy(mesh, rng.choice(mesh.n_verts, size=holes, replace=False), HOLE_RINGS)
        out, out_corr = folder / f"{path.stem}_holes.off", folder / f"{path.stem}_holes.vts"
        save_mesh(holed, out)
        write_vts(nearest_vertices(holed.verts, mesh.verts[read_vts(truth)]), out_corr)
        made_meshes.append(out)
        made_corr.append(out_corr)
    return made_meshes, made_corr


def holed_copy(mesh: Mesh, centres: np.ndarray, rings: int) -> Mesh:
    """``mesh`` without the faces within ``rings`` rings of each centre vertex (its largest clean piece)."""
    inside = np.zeros(mesh.n_verts, dtype=bool)
    inside[centres] = True
    for _ in range(rings - 1):
        inside[mesh.faces[inside[mesh.faces].any(axis=1)]] = True
    return kept_part(mesh, ~inside[mesh.faces].any(axis=1), mesh.name, "holes").mesh


def decimated_copy(mesh: Mesh, truth: np.ndarray, vertices: int) -> tuple[Mesh, np.ndarray]:
    """``mesh`` decimated to about ``vertices`` vertices, and each truth vertex's nearest survivor."""
    low = decimate(mesh, 2 * vertices).mesh
    return Mesh(low.verts, low.faces, mesh.name), nearest_vertices(low.verts, mesh.verts[truth])


def run_match(args, source: Path, target: Path, run_dir: Path) -> dict:
    command = [
        str(Path(sys.executable).parent / "spidermatch-match"),
        f"source={source}",
        f"target={target}",
        f"hydra.run.dir={run_dir}",
        "output.png=false",
        *(["features=learned", f"checkpoint={args.checkpoint}"] if args.checkpoint else []),
        *([f"resolution={args.resolution}"] if args.resolution else []),
        *args.override,
    ]
    cap = int(args.memory_gib * 2**30)
    start = time.perf_counter()
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    with open(run_dir.with_suffix(".log"), "w") as log:
        process = subprocess.Popen(
            command,
            stdout=log,
            stderr=subprocess.STDOUT,
            preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (cap, cap)),
        )
        _, status, usage = os.wait4(process.pid, 0)
    report = json.loads((run_dir / "result.json").read_text()) if (run_dir / "result.json").is_file() else {}
    dense = (report.get("dense") or {}).get("dense") or {}
    return {
        "exit_code": os.waitstatus_to_exitcode(status),
        "status": report.get("status", "-"),
        "gap": report.get("gap"),
        "objective": report.get("objective"),
        "dense_tears": dense.get("tears"),
        "dense_flips": dense.get("flips"),
        "process_s": round(time.perf_counter() - start, 1),
        "peak_mib": round(usage.ru_maxrss / 1024, 1),
        **{f"{name}_s": value for name, value in (report.get("timings_s") or {}).items()},
        "error": report.get("error"),
    }


def measured_errors(
    run_dir: Path, meshes: list[Path], corr: list[Path], sample: np.ndarray, vertex_of=None
) -> dict:
    """Mean geodesic errors of the run's sparse map (all matches) and dense map (``sample`` points).

    ``vertex_of``: the run matched copies of ``meshes`` (STL files, scenes) whose outputs name the
    copies' own vertices; these two arrays (V_file,) give each one's vertex of ``meshes``, and the
    maps are told back in them (the image of a vertex is that of its first copy).
    """
    start = time.perf_counter()
    source, target = load_mesh(meshes[0]), load_mesh(meshes[1])
    src_corr, tgt_corr = read_vts(corr[0], source.n_verts), read_vts(corr[1], target.n_verts)
    source_vertex_of, target_vertex_of = vertex_of or (np.arange(source.n_verts), np.arange(target.n_verts))
    corners = vertex_of is not None
    geodesics = GeodesicDistances(target)
    errors = {"sparse_error": None, "dense_error": None}
    if (run_dir / "matches.csv").is_file():
        pairs = np.loadtxt(run_dir / "matches.csv", delimiter=",", skiprows=1, dtype=np.int64, ndmin=2)
        errors["sparse_error"] = sparse_map_errors(
            source_vertex_of[pairs[:, 0]],
            target_vertex_of[pairs[:, 1]],
            source,
            src_corr,
            tgt_corr,
            target,
            geodesics,
        ).mean
    if (run_dir / "dense_map.npz").is_file():
        vertex = np.load(run_dir / "dense_map.npz")["vertex"]
        if corners:  # the image of each source vertex's first copy
            first_corner = np.full(source.n_verts, -1)
            first_corner[source_vertex_of[::-1]] = np.arange(source_vertex_of.size)[::-1]
            vertex = target_vertex_of[vertex[first_corner]]
        errors["dense_error"] = dense_map_errors(
            vertex, src_corr[sample], tgt_corr[sample], target, geodesics
        ).mean
    return {**errors, "eval_s": round(time.perf_counter() - start, 1)}


def copied_vertices(kind: str, meshes: list[Path], copies: list[Path]) -> tuple[np.ndarray, np.ndarray]:
    """Each copy's vertices (V_file,) as vertices of ``meshes``: STL facet corners, a scene's saved map."""
    if kind == "stl":
        return tuple(load_mesh(path).faces.reshape(-1) for path in meshes)
    return tuple(np.load(path.with_suffix(".npy")) for path in copies)


def summary(rows: list[dict]) -> dict:
    """Per copy kind: the largest error difference against the clean pair, worst time and memory."""
    clean = {row["pair"]: row for row in rows if row["kind"] == "clean"}
    out = {}
    for kind in sorted({row["kind"] for row in rows} - {"clean"}):
        mine = [row for row in rows if row["kind"] == kind]
        figures = {
            "statuses": sorted({row["status"] for row in mine}),
            "worst_process_s": max(row["process_s"] for row in mine),
            "worst_peak_mib": max(row["peak_mib"] for row in mine),
        }
        for error in ("sparse_error", "dense_error"):
            differences = [
                row[error] - clean[row["pair"]][error]
                for row in mine
                if row["pair"] in clean and row[error] is not None and clean[row["pair"]][error] is not None
            ]
            if differences:
                figures[f"{error}_worst_increase"] = round(max(differences), 5)
        out[kind] = figures
    return out


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "FAUST_r"))
    parser.add_argument("--pairs", nargs="*", default=VALIDATION_PAIRS)
    parser.add_argument("--kinds", nargs="*", default=["scaled"], choices=KINDS[1:])
    parser.add_argument("--checkpoint", default=None)
    parser.add_argument("--resolution", type=int, default=None)
    parser.add_argument("--memory-gib", type=float, default=8.0)
    parser.add_argument(
        "--work", default=None, help="folder for the copies and runs (default: a new temp folder)"
    )
    parser.add_argument("--override", nargs="*", default=[])
    parser.add_argument(
        "--eval-points", type=int, default=500, help="reference points the dense error is measured at"
    )
    parser.add_argument("--out", default=str(ROOT / "bench" / "results" / "user_copies"))
    args = parser.parse_args()
    data, work = Path(args.data), Path(args.work or tempfile.mkdtemp(prefix="user_copies_"))
    rows = []
    for pair in args.pairs:
        names = pair.split(":")
        meshes = [data / "off" / f"{name}.off" for name in names]
        corr = [data / "corres" / f"{name}.vts" for name in names]
        references = len(read_vts(corr[0]))
        sample = np.sort(
            np.random.default_rng(0).choice(references, min(args.eval_points, references), replace=False)
        )
        for kind in ("clean", *args.kinds):
            pair_meshes, pair_corr = copies(kind, meshes, corr, work / "copies", seed=sum(map(ord, pair)))
            run_dir = work / "runs" / f"{pair.replace(':', '_')}_{kind}"
            row = {"pair": pair, "kind": kind, **run_match(args, *pair_meshes, run_dir)}
            if kind in ("stl", "scene"):  # scored on the meshes the copies were written from
                copied = copied_vertices(kind, meshes, pair_meshes)
                row.update(measured_errors(run_dir, meshes, corr, sample, copied))
            else:
                row.update(measured_errors(run_dir, pair_meshes, pair_corr, sample))
            print(json.dumps(row), flush=True)
            rows.append(row)
    write_rows(Path(args.out).with_suffix(".json"), rows, {"summary": summary(rows)})
    print(json.dumps(summary(rows), indent=2))


if __name__ == "__main__":
    main()
