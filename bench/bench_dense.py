"""Dense maps of every vertex from the certified low-resolution map: each method side by side.

    .venv/bin/python bench/bench_dense.py --data ../shared/data/FAUST_r --resolution 1000 \
        --features learned --checkpoint best.pt --out bench/results/dense_map_faust_val_1000

Each pair is certified once (decimation, SpiderMatch solve, check) and the solved
low-resolution map, the decimations and the features are cached in ``--cache``
(keyed by pair, resolution, features and checkpoint), so that densification can be
iterated on without re-solving (``--certify-only`` just fills the cache). Then, per
pair, every variant, the features' nearest-neighbour map and the ground truth are
measured: the mean geodesic error of the vertex map (``dense_matches.csv``) over all
reference points (dense Princeton protocol), and over the reference points whose truth
agrees with their neighbours' (``error_consistent_truth``; ``inconsistent_truth_points``
counts the others, see :func:`spidermatch.eval.metrics.inconsistent_truth`); tears,
flipped and degenerate triangles of the vertex map (``vertex_*``) and of the image points
(point form, ``point_*``; see :mod:`spidermatch.eval.metrics`); how far the certified
vertices' dense images lie from their certified images (``certified_distance``, in local
low-resolution edge lengths, and ``certified_within_edge``); the densification time
(``time_s``, wall clock: on a shared machine it includes waiting for the CPU) and its peak
memory (``peak_mib``: tracemalloc's peak of the allocations made during a second, untimed
call, numpy arrays included). The ground truth row (``truth``) scores the dataset's
correspondence the same way: each source vertex goes where the reference point on its
nearest reference vertex goes (the reference points cover about 70 % of a FAUST_r shape's
vertices). Prints a table; writes ``<out>.json`` and ``<out>.csv``.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
from feature_options import add_feature_options, load_pair_with_features, parse_checked
from scipy.spatial import cKDTree

from spidermatch.dense.densify import certified_agreement, densify
from spidermatch.dense.feature_search import feature_nearest_neighbours
from spidermatch.dense.settings import DenseSettings
from spidermatch.eval.errors import sparse_map_errors
from spidermatch.eval.metrics import consistency, geodesic_errors, inconsistent_truth, vertex_map_consistency
from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.remesh import Decimated
from spidermatch.pipeline import MatchError

VAL_PAIRS = [f"tr_reg_{i:03d}:tr_reg_{i + 1:03d}" for i in range(70, 80, 2)]

# Variant name -> DenseSettings keywords (the ones not given are DenseSettings' defaults). The
# variants before the deformation round to the nearest corner (unfold=False), as they did.
NARROW = dict(radius=1.0, distance_weight=1.0, n_neighbours=32, unfold=False)  # earlier interp_features
OLD = dict(unfold=False)
VARIANTS = {
    "deformation": dict(method="deformation"),
    "deformation_nearest": dict(method="deformation", unfold=False),
    "deformation_s0": dict(method="deformation", smoothing=0),
    "interp": dict(method="interp", smoothing=0, **OLD),
    "interp_s3": dict(method="interp", smoothing=3, **OLD),
    "interp_features": dict(method="interp_features", smoothing=0, **NARROW),
    "interp_features_s3": dict(method="interp_features", smoothing=3, **NARROW),
    "features_r2_s3": dict(method="interp_features", smoothing=3, **OLD),
    "features_r2_s3_unfolded": dict(method="interp_features", smoothing=3),
    "features_r3_s3": dict(method="interp_features", smoothing=3, radius=3.0, **OLD),
    "zoomout": dict(method="zoomout", smoothing=0, **OLD),
    "zoomout_local": dict(method="zoomout_local", smoothing=0, radius=1.0, n_neighbours=32, **OLD),
    "zoomout_local_s3": dict(method="zoomout_local", smoothing=3, radius=1.0, n_neighbours=32, **OLD),
    "zoomout_accept_s3": dict(method="zoomout_accept", smoothing=3, radius=1.0, **OLD),
    "zoomout_s3": dict(method="zoomout", smoothing=3, **OLD),
}
FIGURES = ("tears", "flipped", "degenerate")
CACHE_FORMAT = 2  # raised when what is cached changes: 2, decimation maps vertices along the surface
FIELDS = (
    "pair",
    "method",
    "geodesic_error",
    "error_consistent_truth",
    *(f"vertex_{name}" for name in FIGURES),
    *(f"point_{name}" for name in FIGURES),
    "certified_distance",
    "certified_within_edge",
    "time_s",
    "peak_mib",
)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", default="synthetic")
    parser.add_argument("--pairs", nargs="+", default=VAL_PAIRS, help="SOURCE:TARGET shape names")
    parser.add_argument("--resolution", type=int, default=1000)
    add_feature_options(parser, adaptation=True)
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument(
        "--set", nargs="*", default=[], metavar="KEY=VALUE", help="DenseSettings for all variants"
    )
    parser.add_argument("--cache", default=os.path.expanduser("~/.cache/spidermatch/bench_dense"))
    parser.add_argument("--certify-only", action="store_true", help="fill the cache and stop")
    parser.add_argument(
        "--time-limit", type=float, default=300.0, help="solver seconds per pair (a pair not certified stops)"
    )
    parser.add_argument("--strategy", default="colgen", help="solver strategy (MatchSettings.strategy)")
    parser.add_argument("--out", default=None, help="default: bench/results/dense_map_faust_val_<resolution>")
    args = parse_checked(parser, argv)
    overrides = {key: _number(value) for key, value in (item.split("=", 1) for item in args.set)}
    rows = []
    for text in args.pairs:
        pair = tuple(text.split(":"))
        try:
            certified = certified_pair(args, pair)
        except MatchError as error:
            print(f"{text}: skipped, no matching ({error})", flush=True)
            continue
        if args.certify_only:
            print(f"{text}: certified ({certified['status']}, {certified['solve_s']:.1f} s)", flush=True)
            continue
        rows += measure_pair(text, certified, args.variants, overrides)
    if not args.certify_only:
        write_results(args, rows, overrides)


def _number(text: str):
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def cache_path(args, pair: tuple[str, str]) -> Path:
    """One file per pair, resolution, feature type and checkpoint (path, size and time)."""
    checkpoint = ""
    if args.checkpoint:
        stat = Path(args.checkpoint).stat()
        checkpoint = f"{Path(args.checkpoint).resolve()}:{stat.st_size}:{stat.st_mtime_ns}"
    key = [os.path.abspath(args.data), pair, args.resolution, args.features, checkpoint, CACHE_FORMAT]
    if args.adapt_steps:
        key.append(args.adapt_steps)
    key = json.dumps(key)
    return (
        Path(args.cache)
        / f"{pair[0]}__{pair[1]}_{args.resolution}_{hashlib.sha1(key.encode()).hexdigest()[:12]}.npz"
    )


def certified_pair(args, pair: tuple[str, str]) -> dict:
    """The pair's meshes, features and certified low-resolution map, from the cache or solved now."""
    from spidermatch.data.datasets import open_dataset

    path = cache_path(args, pair)
    if not path.is_file():
        _certify(args, pair, path)
    dataset = open_dataset(args.data)
    with np.load(path) as data:
        return {
            "x": dataset.load(pair[0]),
            "y": dataset.load(pair[1]),
            "feat_x": data["feat_x"],
            "feat_y": data["feat_y"],
            "low_x": _restored(data, "x"),
            "low_y": _restored(data, "y"),
            "low_map": data["low_map"],
            "status": str(data["status"]),
            "solve_s": float(data["solve_s"]),
        }


def _certify(args, pair: tuple[str, str], path: Path) -> None:
    """Features, decimation and the certified solve of one pair, saved to ``path``."""
    from spidermatch.pipeline import MatchSettings, match
    from spidermatch.solve.types import SolverOptions

    x, y, feat_x, feat_y = load_pair_with_features(
        args.data, pair, args.features, args.checkpoint, args.adapt_steps
    )
    settings = MatchSettings(
        resolution=args.resolution,
        dense=None,
        strategy=args.strategy,
        solver=SolverOptions(time_limit=args.time_limit),
    )
    result = match(x.mesh, y.mesh, feat_x, feat_y, settings)
    result.raise_for_status()
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(
        path,
        feat_x=feat_x,
        feat_y=feat_y,
        low_map=result.low_map,
        status=result.solve.status,
        solve_s=result.timings["solve"],
        gap=result.solve.gap,
        **_decimated("x", result.source),
        **_decimated("y", result.target),
    )


def _decimated(tag: str, decimated: Decimated) -> dict:
    mesh = decimated.mesh
    return {f"{tag}_verts": mesh.verts, f"{tag}_faces": mesh.faces, f"{tag}_to_full": decimated.to_full}


def _restored(data, tag: str) -> Decimated:
    return Decimated(Mesh(data[f"{tag}_verts"], data[f"{tag}_faces"], tag), data[f"{tag}_to_full"])


def measure_pair(text: str, certified: dict, variants: list[str], overrides: dict) -> list[dict]:
    """One row per variant plus the nearest-neighbour map, the ground truth and the sparse certified map."""
    x, y = certified["x"], certified["y"]
    source, target = x.mesh.centred(), y.mesh.centred()
    low = (certified["low_x"], certified["low_y"], certified["low_map"])
    maps, rows = {}, []
    for name in variants:
        settings = DenseSettings(**{**VARIANTS[name], **overrides})
        inputs = (source, target, *low, certified["feat_x"], certified["feat_y"], settings)
        start = time.perf_counter()
        dense = densify(*inputs)
        seconds = time.perf_counter() - start
        tracemalloc.start()  # a second, traced run: tracing slows allocations, so it is not timed
        densify(*inputs)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        maps[name] = dense.vertex
        point_form = consistency(source, target, dense.points(target), dense.face, dense.bary)
        agreement = certified_agreement(dense, target, *low)
        rows.append(
            {
                "pair": text,
                "method": name,
                **_prefixed("vertex", vertex_map_consistency(source, target, dense.vertex)),
                **_prefixed("point", point_form),
                "certified_distance": agreement["mean_distance"],
                "certified_within_edge": agreement["within_one_edge"],
                "time_s": seconds,
                "peak_mib": peak,
            }
        )
    maps["nearest_neighbour"] = feature_nearest_neighbours(certified["feat_x"], certified["feat_y"])
    maps["truth"] = truth_vertex_map(source, x.corr, y.corr)
    for name in ("nearest_neighbour", "truth"):
        figures = vertex_map_consistency(source, target, maps[name])
        rows.append({"pair": text, "method": name, **_prefixed("vertex", figures)})
    errors = geodesic_errors(maps, x.corr, y.corr, target)
    consistent = ~inconsistent_truth(source, target, x.corr, y.corr)
    for row in rows:
        row["geodesic_error"] = float(errors[row["method"]].mean())
        row["error_consistent_truth"] = float(errors[row["method"]][consistent].mean())
        row["inconsistent_truth_points"] = int((~consistent).sum())
    rows.append({"pair": text, "method": "sparse_certified", "geodesic_error": _sparse_error(certified)})
    for row in rows:
        print(_format(row), flush=True)
    return rows


def _prefixed(form: str, figures) -> dict:
    return {f"{form}_{name}": getattr(figures, name) for name in FIGURES}


def truth_vertex_map(source: Mesh, source_corr: np.ndarray, target_corr: np.ndarray) -> np.ndarray:
    """The ground truth as a map of every source vertex (V_X,): the image of its nearest reference vertex.

    A source vertex that is a reference point's goes to that point's target vertex (the
    first such point); any other vertex goes where its nearest reference vertex goes.
    """
    source_corr = np.asarray(source_corr, dtype=np.int64)
    vertices, first_row = np.unique(source_corr, return_index=True)
    nearest = cKDTree(source.verts[vertices]).query(source.verts)[1]
    return np.asarray(target_corr, dtype=np.int64)[first_row[nearest]]


def _sparse_error(certified: dict) -> float:
    """Error of the certified low-resolution map at its own vertices (the match command's figure)."""
    x, y = certified["x"], certified["y"]
    pairs_x = certified["low_x"].to_full
    pairs_y = certified["low_y"].to_full[certified["low_map"]]
    return sparse_map_errors(pairs_x, pairs_y, x.mesh, x.corr, y.corr, y.mesh).mean


def _format(row: dict) -> str:
    cells = [f"{row['pair']:<22}", f"{row['method']:<20}"]
    for name in FIELDS[2:]:
        value = row.get(name)
        short = name.replace("vertex_", "v_").replace("point_", "p_").replace("certified_", "cert_")
        cells.append(f"{short} {value:.4f}" if isinstance(value, float) else f"{short} -")
    return " ".join(cells)


def write_results(args, rows: list[dict], overrides: dict) -> None:
    """Print per-method means, write the JSON (rows + means) and the CSV (rows)."""
    methods = list(dict.fromkeys(row["method"] for row in rows))
    means = []
    for method in methods:
        mine = [row for row in rows if row["method"] == method]
        mean = {"pair": "mean", "method": method}
        for name in FIELDS[2:]:
            values = [row[name] for row in mine if row.get(name) is not None]
            mean[name] = float(np.mean(values)) if values else None
        if mine[0].get("time_s") is not None:
            mean["time_s_max"] = float(max(row["time_s"] for row in mine))
            mean["peak_mib_max"] = float(max(row["peak_mib"] for row in mine))
        means.append(mean)
        print(_format(mean))
    out = Path(args.out or f"bench/results/dense_map_faust_val_{args.resolution}")
    out.parent.mkdir(parents=True, exist_ok=True)
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    payload = {
        "argv": [_without_machine_path(item) for item in [Path(sys.argv[0]).name, *sys.argv[1:]]],
        "resolution": args.resolution,
        "features": args.features,
        "checkpoint": _without_machine_path(args.checkpoint),
        "adapt_steps": args.adapt_steps,
        "settings": overrides,
        "variants": {v: VARIANTS[v] for v in args.variants},
        "process_peak_rss_gib": peak_rss,
        "rows": rows,
        "means": means,
    }
    out.with_suffix(".json").write_text(json.dumps(payload, indent=2) + "\n")
    with out.with_suffix(".csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(FIELDS), extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows + means)
    print(f"wrote {out.with_suffix('.json')} and {out.with_suffix('.csv')}")


def _without_machine_path(text: str | None) -> str | None:
    """An absolute path shortened to its last two parts (the results must not name one machine's folders)."""
    if text is None or not os.path.isabs(text):
        return text
    return ".../" + "/".join(Path(text).parts[-2:])


if __name__ == "__main__":
    main()
