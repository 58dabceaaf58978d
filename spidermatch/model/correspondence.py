"""From a 0/1 solution to a cyclic path, point maps, and an independent solution checker."""

from __future__ import annotations

import logging
from collections import Counter, defaultdict
from dataclasses import dataclass

import numpy as np

from spidermatch.model.product_graph import INTRA, STAY, ProductGraph
from spidermatch.model.solution import used_columns

logger = logging.getLogger(__name__)


class SolutionError(RuntimeError):
    """A solver's solution is not a valid SpiderMatch path (a bug or numerical trouble)."""


@dataclass(frozen=True)
class MatchingPath:
    """The active product edges of a solution.

    Attributes
    ----------
    edges : np.ndarray, shape (N, 5)
        (layer, y_from, next_layer, y_to, kind) of each active edge, in walk order
        starting with the edge that enters layer 0.
    entry : np.ndarray, shape (L,)
        Target vertex at which the path enters each layer.

    """

    edges: np.ndarray
    entry: np.ndarray

    def layer_vertex_pairs(self) -> np.ndarray:
        """Unique (layer, target vertex) pairs the path visits, shape (M, 2)."""
        visits = np.concatenate([self.edges[:, [0, 1]], self.edges[:, [2, 3]]])
        return np.unique(visits, axis=0)


def active_edges(graph: ProductGraph, x: np.ndarray) -> np.ndarray:
    """(layer, y_from, next_layer, y_to, kind) of the edges x uses (:func:`used_columns`), shape (N, 5)."""
    if x.shape != (graph.n_edges,):
        raise SolutionError(f"solution has {x.shape[0]} entries, product graph {graph.n_edges} edges")
    return graph.edge_tuples(used_columns(x))


def extract_path(graph: ProductGraph, x: np.ndarray) -> MatchingPath:
    """Order the active edges of ``x`` into the closed walk through all layers.

    Raises
    ------
    SolutionError
        If the active edges do not form one closed walk that crosses every layer boundary once.

    """
    tuples = active_edges(graph, x)
    entry = _layer_entries(graph, tuples)
    walk = _euler_walk(tuples, start=(0, int(entry[0])))
    if len(walk) != len(tuples):
        raise SolutionError(
            f"the active edges are not one closed path: {len(tuples) - len(walk)} edges form separate cycles"
        )
    return MatchingPath(tuples[walk], entry)


def entries_without_flow(graph: ProductGraph, x: np.ndarray) -> MatchingPath:
    """The layer entries of a solution of a model without flow conservation (an ablation without CON).

    Such a solution is one crossing edge per layer (CYC), not a walk; each layer is matched
    to the target vertex its crossing edge enters.

    Raises
    ------
    SolutionError
        If some layer boundary is not crossed exactly once.

    """
    tuples = active_edges(graph, x)
    return MatchingPath(tuples, _layer_entries(graph, tuples))


def _layer_entries(graph: ProductGraph, tuples: np.ndarray) -> np.ndarray:
    """Target vertex (L,) where the solution enters each layer; each boundary must be crossed once."""
    crossing = tuples[tuples[:, 4] != INTRA]
    if len(crossing) != graph.n_layers or set(crossing[:, 2].tolist()) != set(range(graph.n_layers)):
        raise SolutionError(
            f"the path crosses {len(crossing)} layer boundaries, expected each of the {graph.n_layers} once"
        )
    entry = np.empty(graph.n_layers, dtype=np.int64)
    entry[crossing[:, 2]] = crossing[:, 3]
    return entry


def _euler_walk(tuples: np.ndarray, start: tuple[int, int]) -> list[int]:
    """Hierholzer's algorithm: indices of ``tuples`` in closed-walk order from node ``start``."""
    outgoing: dict[tuple[int, int], list[int]] = defaultdict(list)
    for index in range(len(tuples) - 1, -1, -1):  # reversed so that pop() keeps input order
        outgoing[(int(tuples[index, 0]), int(tuples[index, 1]))].append(index)
    stack, circuit, node = [], [], start
    stack.append((node, None))
    while stack:
        node, via = stack[-1]
        if outgoing[node]:
            index = outgoing[node].pop()
            stack.append(((int(tuples[index, 2]), int(tuples[index, 3])), index))
        else:
            stack.pop()
            if via is not None:
                circuit.append(via)
    circuit.reverse()
    return circuit


def canonical_point_map(path: MatchingPath, curve_vertices: np.ndarray, n_source: int) -> np.ndarray:
    """Target vertex of each source vertex: where the path enters its first layer, shape (V_X,)."""
    first_layer = np.full(n_source, -1, dtype=np.int64)
    for layer in range(len(curve_vertices) - 1, -1, -1):
        first_layer[curve_vertices[layer]] = layer
    if (first_layer < 0).any():
        raise SolutionError("the curve does not cover every source vertex")
    return path.entry[first_layer]


@dataclass(frozen=True)
class CheckReport:
    """Result of :func:`check_solution`: ``ok`` and the list of violated properties."""

    ok: bool
    problems: tuple[str, ...]


def check_solution(
    curve_vertices: np.ndarray,
    target_edges: np.ndarray,
    n_target: int,
    tuples: np.ndarray,
    families: tuple = ("CYC", "CON", "PES", "ANS"),
) -> CheckReport:
    """Verify a solution from first principles, without the constraint matrix.

    Parameters
    ----------
    curve_vertices : np.ndarray, shape (L,)
    target_edges : np.ndarray, shape (E, 2)
        Undirected target edges the product graph was built from.
    n_target : int
    tuples : np.ndarray, shape (N, 5)
        Active edges as (layer, y_from, next_layer, y_to, kind).
    families : tuple of str
        The constraint families the model imposed (an ablation is checked against its own).

    Checks: every edge exists in the product graph; each layer boundary is crossed
    once (CYC); in-flow equals out-flow everywhere and the edges form one closed walk
    (CON); layers of one self-intersection visit the same target vertices (PES); no
    target vertex is entered twice by non-degenerate edges outside self-intersection
    layers (ANS).

    """
    n_layers = len(curve_vertices)
    problems: list[str] = []
    problems += _check_edges_exist(tuples, target_edges, n_layers, n_target)
    crossings = Counter(int(t[0]) for t in tuples if t[4] != INTRA)
    wrong = [layer for layer in range(n_layers) if crossings.get(layer, 0) != 1]
    if wrong and "CYC" in families:
        problems.append(f"layer boundaries not crossed exactly once: {wrong[:10]}")
    if "CON" in families:
        problems += _check_balance_and_connectivity(tuples)
    if "PES" in families:
        problems += _check_intersections_preserved(curve_vertices, tuples)
    if "ANS" in families:
        problems += _check_no_new_intersections(curve_vertices, tuples)
    return CheckReport(not problems, tuple(problems))


def _check_edges_exist(
    tuples: np.ndarray, target_edges: np.ndarray, n_layers: int, n_target: int
) -> list[str]:
    edge_set = {(int(a), int(b)) for a, b in target_edges} | {(int(b), int(a)) for a, b in target_edges}
    bad = []
    for layer, a, nxt, b, kind in tuples.tolist():
        same_layer = nxt == layer
        next_layer = nxt == (layer + 1) % n_layers
        valid = (
            0 <= a < n_target
            and 0 <= b < n_target
            and (
                (kind == INTRA and same_layer and (a, b) in edge_set)
                or (kind == STAY and next_layer and a == b)
                or (kind not in (INTRA, STAY) and next_layer and (a, b) in edge_set)
            )
        )
        if not valid:
            bad.append((layer, a, nxt, b, kind))
    return [f"{len(bad)} active edges are not product-graph edges (first: {bad[0]})"] if bad else []


def _check_balance_and_connectivity(tuples: np.ndarray) -> list[str]:
    balance: Counter = Counter()
    for layer, a, nxt, b, _ in tuples.tolist():
        balance[(layer, a)] += 1
        balance[(nxt, b)] -= 1
    unbalanced = [node for node, value in balance.items() if value != 0]
    if unbalanced:
        return [f"{len(unbalanced)} product vertices with in-flow != out-flow (first: {unbalanced[0]})"]
    if len(tuples) and len(_euler_walk(tuples, (int(tuples[0, 0]), int(tuples[0, 1])))) != len(tuples):
        return ["the active edges form several disjoint cycles, not one closed path"]
    return []


def _check_intersections_preserved(curve_vertices: np.ndarray, tuples: np.ndarray) -> list[str]:
    out_visits: dict[int, Counter] = defaultdict(Counter)
    for layer, a, *_ in tuples.tolist():
        out_visits[layer][a] += 1
    layers_of: dict[int, list[int]] = defaultdict(list)
    for layer, vertex in enumerate(curve_vertices.tolist()):
        layers_of[vertex].append(layer)
    broken = [
        vertex
        for vertex, layers in layers_of.items()
        if len(layers) > 1 and any(out_visits[other] != out_visits[layers[0]] for other in layers[1:])
    ]
    return (
        [f"{len(broken)} self-intersections not preserved (first: source vertex {broken[0]})"]
        if broken
        else []
    )


def _check_no_new_intersections(curve_vertices: np.ndarray, tuples: np.ndarray) -> list[str]:
    counts = Counter(curve_vertices.tolist())
    free = [counts[v] == 1 for v in curve_vertices.tolist()]
    entered = Counter(
        b
        for layer, a, nxt, b, kind in tuples.tolist()
        if kind != STAY and a != b and free[layer] and free[nxt]
    )
    twice = [y for y, n in entered.items() if n > 1]
    return [f"{len(twice)} target vertices entered more than once (first: {twice[0]})"] if twice else []
