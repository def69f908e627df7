"""Reference only, not on the production path: every maximal clique (igraph), then ranked in Python.

`maximal_cliques` (igraph: Bron-Kerbosch with pivoting in C) enumerates all maximal cliques;
with `rank_cliques` it gives what `cliquesearch.top_cliques` must return (same cliques, same
order), which the tests and `tools/bench_core.py` (the previous implementation) compare against.
"""

from __future__ import annotations

import time

import igraph
import numpy as np

from clipclique.inliers.cliquesearch import clique_total
from clipclique.outcomes import CapHit

FIRST_ROUND = 1_000  # cliques asked for in the first enumeration round


def maximal_cliques(
    edges: np.ndarray, num_nodes: int, min_size: int = 3, max_cliques: int = 100_000, time_limit_s: float = 1.0
) -> tuple[list[np.ndarray], CapHit | None]:
    """Maximal cliques of at least `min_size` nodes of the graph `edges` (E, 2) on `num_nodes` nodes,
    and the cap that stopped enumeration early.

    Returns (cliques as sorted index arrays, cap) where cap is CapHit.MAX_CLIQUES, CapHit.TIME_LIMIT or None.
    """
    graph = igraph.Graph(n=num_nodes, edges=edges)
    start = time.perf_counter()
    wanted = min(FIRST_ROUND, max_cliques)
    while True:
        found = graph.maximal_cliques(min=min_size, max_results=wanted + 1)
        if len(found) <= wanted:
            return [np.array(sorted(c)) for c in found], None
        if wanted == max_cliques:
            return [np.array(sorted(c)) for c in found[:wanted]], CapHit.MAX_CLIQUES
        if time.perf_counter() - start > time_limit_s:
            return [np.array(sorted(c)) for c in found[:wanted]], CapHit.TIME_LIMIT
        wanted = min(2 * wanted, max_cliques)


def rank_cliques(cliques: list[np.ndarray], scores: np.ndarray) -> list[np.ndarray]:
    """Cliques sorted by summed similarity (`clique_total`), best first; ties by the sorted member
    lists, lexicographically smaller first: the order `top_cliques` returns."""
    if not cliques:
        return []
    totals = clique_total(cliques, scores)
    members = [np.sort(c) for c in cliques]
    longest = max(len(c) for c in members)
    padded = np.full((len(members), longest), -1)  # a shorter list that is a prefix ranks first
    padded[np.arange(longest) < np.array([len(c) for c in members])[:, None]] = np.concatenate(members)
    order = np.lexsort((*padded.T[::-1], -totals))
    return [members[i] for i in order]
