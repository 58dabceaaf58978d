"""Time and peak memory of building the full ILP: one-shot ``build_model`` against the blockwise
``LazyModel.full_model``, each in its own process.

Costs and constraint matrix only (the same for any features: R is random here); the
decimated meshes and SpiderCurve come from a dataset pair.

    .venv/bin/python bench/bench_model_build.py \
        --data ../shared/data/FAUST_r --pairs tr_reg_070:tr_reg_071 --faces 500 1000

Writes bench/results/model_build_faust.{json,csv} (``--out``).
"""

from __future__ import annotations

import argparse
import csv
import json
import multiprocessing as mp
import resource
import sys
import time
from pathlib import Path

METHODS = ("build_model", "blockwise")


def build_once(task: tuple) -> dict:
    """Decimate, trace, then build the full model with one method; figures of the build alone."""
    import numpy as np

    from spidermatch.data.datasets import open_dataset
    from spidermatch.geometry.remesh import decimate
    from spidermatch.model.costs import product_edge_costs
    from spidermatch.model.curve import spider_curve
    from spidermatch.model.ilp import build_model
    from spidermatch.model.lazy_model import LazyModel
    from spidermatch.model.product_graph import build_product_graph

    data, pair, faces, method = task
    dataset = open_dataset(data)
    low_x = decimate(dataset.load(pair[0]).mesh.centred(), faces).mesh
    low_y = decimate(dataset.load(pair[1]).mesh.centred(), faces).mesh
    curve = spider_curve(low_x)
    graph = build_product_graph(curve.length, low_y.n_verts, low_y.edges)
    vertex_costs = np.random.default_rng(0).uniform(size=(low_x.n_verts, low_y.n_verts))
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    start = time.perf_counter()
    if method == "build_model":
        costs = product_edge_costs(graph, curve.vertices, low_x.verts, low_y.verts, vertex_costs)
        model = build_model(graph, curve, costs)
    else:
        model = LazyModel(graph, curve, low_x.verts, low_y.verts, vertex_costs).full_model()
    seconds = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {
        "pair": f"{pair[0]}:{pair[1]}",
        "faces": faces,
        "method": method,
        "columns": model.n_vars,
        "rows": model.n_rows,
        "nonzeros": model.nnz,
        "index_dtype": str(model.matrix.indices.dtype),
        "costs_and_build_s": round(seconds, 2),
        "peak_mib": round(peak / 1024, 1),
        "build_extra_peak_mib": round((peak - before) / 1024, 1),
    }


def main(argv: list[str] | None = None) -> None:
    """Build every (pair, faces, method) in its own process and write the table."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", required=True, help="FAUST_r-style folder")
    parser.add_argument("--pairs", nargs="+", default=["tr_reg_070:tr_reg_071"])
    parser.add_argument("--faces", nargs="+", type=int, default=[500, 1000])
    parser.add_argument("--out", default="bench/results/model_build_faust.json")
    args = parser.parse_args(argv)
    out, rows = Path(args.out), []
    out.parent.mkdir(parents=True, exist_ok=True)
    context = mp.get_context("spawn")
    for pair_text in args.pairs:
        for faces in args.faces:
            for method in METHODS:
                with context.Pool(1) as pool:
                    row = pool.apply(build_once, ((args.data, tuple(pair_text.split(":")), faces, method),))
                rows.append(row)
                print(" | ".join(str(v) for v in row.values()), flush=True)
    out.write_text(json.dumps({"argv": sys.argv, "rows": rows}, indent=2) + "\n")
    with out.with_suffix(".csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"wrote {out} and {out.with_suffix('.csv')}")


if __name__ == "__main__":
    main()
