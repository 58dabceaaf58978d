"""Can the cheap closed path of the seed be repaired into a feasible start? (a probe, not part of the product)

Column generation seeds its LP with a band around the cheapest closed path through the product
graph without PES and ANS (``spidermatch.solve.path_seed``). Where no restricted MIP finds a
closed path but the stay path (FAUST_r 078->079 at 4000 faces), that path would be a natural
start if it could be made feasible. This probe counts the rows of the full model the path
violates (PES: a self-intersection's passes land on different target vertices; ANS: a target
vertex entered twice), frees the layers of those rows, and runs the nearby-columns repair
(``spidermatch.solve.repair.repair_with_nearby_columns``: the full model's columns within two
target rings of the path in windows of 3, then 12 layers) with the given time limit. It prints
the violations, the repair's result and, if one is found, that it violates no row and has no
detached cycle.

    python bench/repro/path_seed_repair.py --data ../shared/data/FAUST_r \
        --checkpoint ../runs/faust_unsup_seed0/best.pt --pair tr_reg_078:tr_reg_079 --faces 4000
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from feature_options import load_pair_with_features  # noqa: E402


def violated_rows(lazy, edges: np.ndarray) -> np.ndarray:
    """Rows of the full model the solution using exactly ``edges`` (k,) violates, sorted."""
    activity = lazy.submodel(edges).matrix @ np.ones(edges.size)
    lower, upper = lazy.row_bounds
    return np.flatnonzero((activity < lower - 1e-9) | (activity > upper + 1e-9))


def layers_of_violations(lazy, curve, graph, edges: np.ndarray, rows: np.ndarray) -> set:
    """Layers a violated PES row ties, and the layers of the edges entering an ANS-violating vertex."""
    families, n = lazy.row_families, graph.n_target
    duplicates = curve.duplicate_layers
    first = curve.first_layer[duplicates]
    layers = set()
    start, stop = families["PES"]
    for row in rows[(rows >= start) & (rows < stop)] - start:
        layers |= {int(duplicates[row // n]), int(first[row // n])}
    start, stop = families["ANS"]
    tuples = graph.edge_tuples(edges)
    for vertex in rows[(rows >= start) & (rows < stop)] - start:
        layers |= set(tuples[tuples[:, 3] == vertex, 0].tolist())
    return layers


def main() -> None:
    from spidermatch.pipeline import MatchSettings, prepare
    from spidermatch.solve.colgen import objective_of
    from spidermatch.solve.connectivity import detached_components
    from spidermatch.solve.cuts import CutPool
    from spidermatch.solve.path_seed import cheapest_closed_path
    from spidermatch.solve.repair import repair_with_nearby_columns
    from spidermatch.solve.types import SolverOptions

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", required=True)
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--pair", default="tr_reg_078:tr_reg_079")
    parser.add_argument("--faces", type=int, default=4000)
    parser.add_argument("--time-limit", type=float, default=120.0, help="seconds for the repair")
    args = parser.parse_args()
    pair = tuple(args.pair.split(":"))
    x, y, fx, fy = load_pair_with_features(args.data, pair, "learned", args.checkpoint)
    settings = MatchSettings(resolution=args.faces, strategy="colgen")
    _, _, curve, graph, lazy = prepare(x.mesh, y.mesh, fx, fy, settings, {})
    path, cost = cheapest_closed_path(lazy)
    rows = violated_rows(lazy, path)
    for name, (start, stop) in lazy.row_families.items():
        print(f"{name}: {int(((rows >= start) & (rows < stop)).sum())} rows violated")
    layers = layers_of_violations(lazy, curve, graph, path, rows)
    print(f"seed path: {path.size} edges, cost {cost:.6f}; {len(layers)} of {graph.n_layers} layers affected")
    started = time.perf_counter()
    pool = CutPool(first_layer=curve.first_layer)
    repaired = repair_with_nearby_columns(
        lazy, path, path, sorted(layers), pool, SolverOptions(args.time_limit)
    )
    seconds = time.perf_counter() - started
    if repaired is None:
        print(f"repair: no closed path ({seconds:.1f} s)")
        return
    used = np.flatnonzero(repaired > 0.5)
    cycles = len(detached_components(graph, repaired))
    print(
        f"repair: cost {objective_of(lazy, repaired):.6f} ({seconds:.1f} s); "
        f"{violated_rows(lazy, used).size} rows violated, {cycles} detached cycles"
    )


if __name__ == "__main__":
    main()
