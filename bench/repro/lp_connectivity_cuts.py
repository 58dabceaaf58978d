"""How much connectivity cuts in colgen's LP would raise its bound (a probe, not part of the product).

colgen's LP relaxation has no connectivity cuts: its solution may hold detached cycles, and
on hard pairs the cheapest connected closed path lies several per cent above the LP's value
(FAUST_r 076->077 at 4000 faces: LP 2.3311, no closed path below 2.4057). This probe solves
the LP by column generation, then re-solves the *restricted* LP over its columns with cuts
separated on the LP solution: per layer, the components of the support's intra edges whose
largest edge value exceeds the value leaving the component (the cut of
``spidermatch.solve.connectivity`` is violated). A restricted LP's value bounds the full
LP-with-cuts from above, so the rise printed is the most such cuts could give.

    python bench/repro/lp_connectivity_cuts.py --data ../shared/data/FAUST_r \
        --checkpoint ../runs/faust_unsup_seed0/best.pt --pair tr_reg_076:tr_reg_077 --faces 4000
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from feature_options import load_pair_with_features  # noqa: E402


def violated_components(graph, columns: np.ndarray, x: np.ndarray) -> list[np.ndarray]:
    """Product-vertex sets (layer * V_Y + y) of support components that violate a connectivity cut."""
    from spidermatch.model.product_graph import INTRA

    used = x > 1e-6
    tuples, values = graph.edge_tuples(columns[used]), x[used]
    intra = tuples[:, 4] == INTRA
    tails = tuples[:, 0] * graph.n_target + tuples[:, 1]
    heads = tuples[:, 2] * graph.n_target + tuples[:, 3]
    nodes, index = np.unique(np.concatenate([tails[intra], heads[intra]]), return_inverse=True)
    m = int(intra.sum())
    adjacency = sp.coo_matrix((np.ones(m), (index[:m], index[m:])), shape=(nodes.size, nodes.size))
    n_components, labels = connected_components(adjacency, directed=False)
    position = np.minimum(np.searchsorted(nodes, tails), nodes.size - 1)
    in_component = nodes[position] == tails
    component = np.where(in_component, labels[position], -1)
    out = in_component & ~intra
    leaving = np.bincount(component[out], weights=values[out], minlength=n_components)
    inside = np.zeros(n_components)
    np.maximum.at(inside, component[in_component & intra], values[in_component & intra])
    return [nodes[labels == c] for c in np.flatnonzero(inside - leaving > 1e-6)]


def main() -> None:
    from spidermatch.pipeline import MatchSettings, prepare
    from spidermatch.solve.colgen import generate_columns
    from spidermatch.solve.connectivity import connectivity_cuts
    from spidermatch.solve.highs import HighsSession
    from spidermatch.solve.seeds import path_band_seed, stay_seed
    from spidermatch.solve.types import SolverOptions

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", required=True)
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--pair", default="tr_reg_076:tr_reg_077")
    parser.add_argument("--faces", type=int, default=4000)
    parser.add_argument("--rounds", type=int, default=30)
    args = parser.parse_args()
    pair = tuple(args.pair.split(":"))
    x, y, fx, fy = load_pair_with_features(args.data, pair, "learned", args.checkpoint)
    settings = MatchSettings(resolution=args.faces, strategy="colgen")
    _, _, _, graph, lazy = prepare(x.mesh, y.mesh, fx, fy, settings, {})
    lp = generate_columns(lazy, np.union1d(path_band_seed(lazy), stay_seed(lazy)), SolverOptions(600.0))
    print(f"column generation: LP {lp.value:.6f}, bound {lp.bound:.6f}, {lp.columns.size} columns")
    session = HighsSession(lazy.compact_submodel(lp.columns), SolverOptions(600.0), relax=True)
    result = session.run()
    for round_number in range(1, args.rounds + 1):
        components = violated_components(graph, lp.columns, np.asarray(result.x)[: lp.columns.size])
        if not components:
            print("no violated cut left")
            break
        rows, lower, upper = connectivity_cuts(graph, components)
        session.add_rows(rows[:, lp.columns], lower, upper)
        result = session.run()
        found = f"{len(components)} components, {rows.shape[0]} cuts"
        print(f"round {round_number}: {found}, LP {result.objective:.6f}")


if __name__ == "__main__":
    main()
