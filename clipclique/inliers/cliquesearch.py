"""The N heaviest maximal cliques of a vertex-weighted graph, found by branch and bound (numba).

Bron-Kerbosch with Tomita pivoting, vertices taken one at a time, the most promising first (the
most a clique through it can weigh; each vertex `v` explores the cliques whose first vertex in
that order is `v`: P = its later neighbours, X = its earlier ones), run on bitsets of `v`'s
neighbourhood. A branch is cut when the weight of its clique plus the most its candidates can
still add cannot reach the current N-th best. Vertices carry a group (for the compatibility graph: the observation), no
edge joins two vertices of one group, so a clique holds at most one vertex per group and "the most it can
still add" is the sum over groups of each group's heaviest positive candidate: much tighter than
the sum of all candidates when an observation has several.

Exact: the result equals full enumeration ranked by `clique_total` (weights summed in ascending
vertex order), ties broken by the sorted member lists compared lexicographically (smaller
first). The cut keeps a branch whose bound ties the N-th best (within float round-off), so
equal-weight cliques are never lost to the order of the search.

The search runs in slices of `SLICE` branch steps; all its state lives in arrays owned by the
Python caller (`SearchArrays`: the graph, the scalar state, the scratch of the current first
vertex, the ranked top list; named tuples numba compiles like plain ones), which checks the time
limit between slices. numba compiles once per machine (`cache=True` keeps the machine code beside
the module).
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from clipclique.descriptors.graph import sort_span
from clipclique.outcomes import CapHit

SLICE = 50_000  # branch steps between time-limit checks (about a millisecond or two)
RUNNING, DONE, COUNT_CAP = 0, 1, 2  # search status (state[STATUS])
OUTER, LEVEL, REACHED, STATUS, FILLED, FRESH, STAMP = range(7)  # slots of the int state array
TOLERANCE = 1e-9  # relative slack of the cut against float round-off
NEGATIVE_GROUP = "groups must be non-negative"
INSERTION_SORT_UP_TO = 24  # values `_rank_descending` sorts in place (quadratic: the merge sort is faster beyond)


@dataclass(kw_only=True)
class TopCliques:
    """The heaviest maximal cliques, best first, and how the search ended."""

    members: np.ndarray  # int64, each clique's sorted vertex indices, clique after clique
    sizes: np.ndarray  # (C,) int64, how many vertices each clique holds
    totals: np.ndarray  # (C,) summed weight, by `clique_total`
    reached: int  # maximal cliques of at least `min_size` vertices the search reached (not cut)
    cap: CapHit | None  # MAX_CLIQUES, TIME_LIMIT or None

    @property
    def cliques(self) -> list[np.ndarray]:
        """Each clique's sorted vertex indices (views of `members`)."""
        ends = np.cumsum(self.sizes).tolist()
        return [self.members[end - size: end] for end, size in zip(ends, self.sizes.tolist())]

    def stacked(self, first: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """The members and sizes of the cliques from `first` on (the pose stage fits them as one stack, so the
        cliques never travel as a list of arrays rejoined)."""
        if first == 0:  # the first fit of a frame: the arrays as they are
            return self.members, self.sizes
        skipped = int(self.sizes[:first].sum())
        return self.members[skipped:], self.sizes[first:]

    @staticmethod
    def of(cliques: list[np.ndarray], totals: np.ndarray, reached: int, cap: CapHit | None) -> TopCliques:
        """The result of a list of cliques (each sorted), best first."""
        members = np.concatenate(cliques).astype(np.int64) if cliques else np.zeros(0, np.int64)
        return TopCliques(members=members, sizes=np.array([len(clique) for clique in cliques], np.int64),
                          totals=np.asarray(totals, np.float64), reached=reached, cap=cap)


class Problem(NamedTuple):
    """What is searched: the weighted, grouped graph's vertices and the search's bounds."""

    weights: np.ndarray  # (V,) float64
    groups: np.ndarray  # (V,) int64, vertices of one group pairwise non-adjacent
    min_size: int  # smallest clique reported
    max_cliques: int  # maximal cliques reached before the search stops (COUNT_CAP)


class Graph(NamedTuple):
    """The graph as CSR and the order its vertices are tried in."""

    indptr: np.ndarray  # (V + 1,) neighbours of v: indices[indptr[v]:indptr[v + 1]]
    indices: np.ndarray  # (2E,)
    order: np.ndarray  # (V,) vertices, most promising first
    position: np.ndarray  # (V,) rank of each vertex in `order`
    potential: np.ndarray  # (V,) the most a clique through each vertex can weigh (descending along `order`)


class Scratch(NamedTuple):
    """The current first vertex's neighbourhood as local vertices 0..d-1 (heaviest first) and the
    Bron-Kerbosch stack over them, one row per level (bitsets of `words` uint64)."""

    local_weight: np.ndarray  # (width,) weight of each local vertex
    local_group: np.ndarray  # (width,) group of each local vertex
    local_vertex: np.ndarray  # (width,) graph vertex of each local vertex
    local_of: np.ndarray  # (V,) local index of each graph vertex, 64 * words (the spare word's bit) outside
    adjacency: np.ndarray  # (width, words + 1) local adjacency bitsets, a spare word last that nothing reads: a
    # neighbour's neighbour outside the neighbourhood sets a bit there, without a branch the CPU cannot predict
    p_sets: np.ndarray  # (width + 1, words) candidates P per level
    x_sets: np.ndarray  # (width + 1, words) excluded X per level
    todo: np.ndarray  # (width + 1, words) P minus the pivot's neighbours: branches left per level
    members: np.ndarray  # (width + 1,) the clique being grown: the first vertex, then local vertices
    weight_so_far: np.ndarray  # (width + 1,) its weight per level
    group_stamp: np.ndarray  # (groups,) last bound computation that counted each group
    rank: np.ndarray  # (width,) an ordering of local vertices (`_rank_descending`)


class Ranked(NamedTuple):
    """The top list, best first: `filled` (state[FILLED]) entries of at most `count`."""

    total: np.ndarray  # (count,) summed weight
    size: np.ndarray  # (count,) members
    slot: np.ndarray  # (count,) the row of `members` each entry's clique is in (an insertion moves no row)
    members: np.ndarray  # (count, longest) sorted vertices, the first `size` valid


class SearchArrays(NamedTuple):
    """Everything the search reads and writes between slices."""

    graph: Graph
    state: np.ndarray  # (7,) int64, slots OUTER..STAMP
    scratch: Scratch
    best: Ranked


def top_cliques(
    edges: np.ndarray,
    num_nodes: int,
    weights: np.ndarray,
    count: int,
    groups: np.ndarray | None = None,
    min_size: int = 3,
    max_cliques: int = 100_000,
    time_limit_s: float = 1.0,
) -> TopCliques:
    """The `count` heaviest maximal cliques of at least `min_size` vertices of the graph `edges` (E, 2).

    `groups` (num_nodes,) int: vertices of one group must be pairwise non-adjacent (None: every
    vertex its own group). The search stops early after reaching `max_cliques` maximal cliques
    or after `time_limit_s`, and says which in `cap`; what it returns then is the best so far.
    """
    weights = np.ascontiguousarray(weights, dtype=np.float64)
    groups = np.arange(num_nodes) if groups is None else np.ascontiguousarray(groups, dtype=np.int64)
    edges = np.ascontiguousarray(edges, dtype=np.int64).reshape(-1, 2)
    if count < 1 or num_nodes < min_size:
        if len(groups) and groups.min() < 0:
            raise ValueError(NEGATIVE_GROUP)
        return TopCliques.of([], np.zeros(0), 0, None)
    deadline = time.perf_counter() + time_limit_s
    state, members, sizes, totals, arrays = _start(weights, groups, min_size, max_cliques, edges, num_nodes, count)
    cap = None
    problem = None if arrays is None else Problem(weights, groups, min_size, max_cliques)
    while True:
        if state[STATUS] == COUNT_CAP:
            cap = CapHit.MAX_CLIQUES
        if state[STATUS] != RUNNING:
            break
        if time.perf_counter() > deadline:
            cap = CapHit.TIME_LIMIT
            break
        _search(problem, arrays, SLICE)
    if arrays is not None:  # the search ran past its first slice: its top list as it ended
        members, sizes, totals = _stacked_best(arrays.best, state[FILLED])
    return TopCliques(members=members, sizes=sizes, totals=totals, reached=int(state[REACHED]), cap=cap)


def clique_total(cliques: list[np.ndarray], weights: np.ndarray) -> np.ndarray:
    """(M,) summed weight per clique, added in ascending vertex order (the search's exact order)."""
    if not cliques:
        return np.zeros(0)
    sizes = np.fromiter(map(len, cliques), np.int64, len(cliques))
    padded = np.full((len(cliques), sizes.max()), len(weights))  # pad with a vertex of weight 0
    padded[np.arange(sizes.max()) < sizes[:, None]] = np.fromiter(itertools.chain.from_iterable(cliques), np.int64)
    padded.sort(axis=1)
    return np.cumsum(np.append(weights, 0.0)[padded], axis=1)[:, -1]  # cumsum adds left to right, as the search


@njit(cache=True)
def _start(weights, groups, min_size, max_cliques, edges, num_nodes, count):
    """`_prepare` and the search's first slice in one call, the `Problem` given as plain arguments (numba types a
    named tuple argument in Python, slowly): the state, the top list stacked (`_stacked_best`), and the search's
    arrays only while it runs on (None once it ended: most searches end within the first slice, and handing the graph
    and scratch back to Python costs more than a small search)."""
    problem = Problem(weights, groups, min_size, max_cliques)
    arrays = _prepare(edges, num_nodes, weights, groups, count)
    _search(problem, arrays, SLICE)
    members, sizes, totals = _stacked_best(arrays.best, arrays.state[FILLED])
    return arrays.state, members, sizes, totals, arrays if arrays.state[STATUS] == RUNNING else None


@njit(cache=True)
def _stacked_best(best, filled):
    """The top list's first `filled` cliques as `TopCliques` holds them: members clique after clique, sizes, totals."""
    sizes, totals = best.size[:filled].copy(), best.total[:filled].copy()
    members = np.empty(sizes.sum(), np.int64)
    at = 0
    for i in range(filled):
        for k in range(sizes[i]):
            members[at] = best.members[best.slot[i], k]
            at += 1
    return members, sizes, totals


@njit(cache=True)
def _prepare(edges, num_nodes, weights, groups, count):
    """The search's arrays: the graph as CSR, the vertex order, scratch and the ranked top list;
    ValueError when a group is negative or an edge joins two vertices of one group (the groups checked here, where
    numpy's minimum cost a small search a tenth of its time)."""
    for v in range(len(groups)):
        if groups[v] < 0:
            raise ValueError(NEGATIVE_GROUP)
    degree = np.zeros(num_nodes, np.int64)
    for e in range(len(edges)):
        if groups[edges[e, 0]] == groups[edges[e, 1]]:
            raise ValueError("an edge joins two vertices of one group")
        degree[edges[e, 0]] += 1
        degree[edges[e, 1]] += 1
    indptr = np.zeros(num_nodes + 1, np.int64)
    indptr[1:] = np.cumsum(degree)
    fill = indptr[:-1].copy()
    indices = np.empty(2 * len(edges), np.int64)
    for e in range(len(edges)):
        a, b = edges[e, 0], edges[e, 1]
        indices[fill[a]] = b
        fill[a] += 1
        indices[fill[b]] = a
        fill[b] += 1
    # Most promising first: the weight a vertex's cliques can reach at most, heaviest first, so
    # that the N-th best rises early and later vertices are cut before their neighbourhood is built.
    potential = np.zeros(num_nodes)
    best_in_group = np.zeros(groups.max() + 1 if num_nodes else 1)
    for v in range(num_nodes):
        potential[v] = max(weights[v], 0.0)
        for k in range(indptr[v], indptr[v + 1]):
            g = groups[indices[k]]
            best_in_group[g] = max(best_in_group[g], weights[indices[k]])
        for k in range(indptr[v], indptr[v + 1]):
            g = groups[indices[k]]
            potential[v] += best_in_group[g]
            best_in_group[g] = 0.0
    order = np.empty(num_nodes, np.int64)
    _rank_descending(potential, num_nodes, order)  # np.argsort(-potential, kind="mergesort"), a small graph's in place
    position = np.empty(num_nodes, np.int64)
    position[order] = np.arange(num_nodes)
    width = degree.max() + 1 if num_nodes else 1
    words = (width + 63) // 64
    state = np.zeros(7, np.int64)
    state[LEVEL] = -1
    longest = max(1, min(width, groups.max() + 1))
    scratch = Scratch(np.zeros(width), np.zeros(width, np.int64), np.zeros(width, np.int64),
                      np.full(num_nodes, 64 * words, np.int64), np.zeros((width, words + 1), np.uint64),
                      np.zeros((width + 1, words), np.uint64), np.zeros((width + 1, words), np.uint64),
                      np.zeros((width + 1, words), np.uint64), np.zeros(width + 1, np.int64), np.zeros(width + 1),
                      np.zeros(groups.max() + 1, np.int64), np.zeros(width, np.int64))
    best = Ranked(np.zeros(count), np.zeros(count, np.int64), np.arange(count), np.zeros((count, longest), np.int64))
    return SearchArrays(Graph(indptr, indices, order, position, potential), state, scratch, best)


@intrinsic
def _lowest_bit(typing_context, word):
    """Index of the lowest set bit of a non-zero word (LLVM's cttz: one instruction)."""
    if word != types.uint64:
        return None

    def codegen(context, builder, signature, arguments):
        return builder.cttz(arguments[0], ir.Constant(ir.IntType(1), 0))

    return types.int64(word), codegen


@intrinsic
def _popcount(typing_context, word):
    """Set bits of a word (LLVM's ctpop: one instruction)."""
    if word != types.uint64:
        return None

    def codegen(context, builder, signature, arguments):
        return builder.ctpop(arguments[0])

    return types.int64(word), codegen


@njit(cache=True)
def _rank_descending(values: np.ndarray, count: int, rank: np.ndarray) -> None:
    """rank[:count] = np.argsort(-values[:count], kind="mergesort"): largest first, NaN last, ties in index order;
    up to INSERTION_SORT_UP_TO values in place (an insertion sort, quicker on a short run than the merge sort's
    allocations), more by the merge sort."""
    if count > INSERTION_SORT_UP_TO:
        rank[:count] = np.argsort(-values[:count], kind="mergesort")
        return
    for i in range(count):
        value = values[i]
        j = i
        while j > 0 and (value > values[rank[j - 1]] or (np.isnan(values[rank[j - 1]]) and not np.isnan(value))):
            rank[j] = rank[j - 1]
            j -= 1
        rank[j] = i


@njit(cache=True, inline="always")
def _offer(clique: np.ndarray, size: int, weights: np.ndarray, state: np.ndarray, best_total: np.ndarray,
           best_size: np.ndarray, best_slot: np.ndarray, best_members: np.ndarray) -> None:
    """Insert a maximal clique into the ranked top list if it ranks high enough. Written out without helper calls
    or views (the sort, `sort_span`, is inlined), and itself inlined into `_search` (as `_threshold` is): each array
    handed to a compiled call, or sliced, is reference-counted by two atomic operations, which cost a desk search a
    quarter of its time when the comparison was a function and the sort a view's sort, and a small frame's search
    a quarter when these two were calls."""
    sort_span(clique, 0, size)
    total = 0.0
    for k in range(size):
        total += weights[clique[k]]
    filled = state[FILLED]
    at = filled
    while at > 0:  # ranks before entry at - 1: heavier, or as heavy and lexicographically smaller
        i = at - 1
        if total != best_total[i]:
            if not total > best_total[i]:  # NaN ranks before nothing
                break
        else:
            k = 0
            shorter = min(size, best_size[i])
            while k < shorter and clique[k] == best_members[best_slot[i], k]:
                k += 1
            if not (clique[k] < best_members[best_slot[i], k] if k < shorter else size < best_size[i]):
                break
        at -= 1
    capacity = len(best_total)
    if at >= capacity:
        return
    last = min(filled, capacity - 1)
    row = best_slot[last]  # a free row, or the one the last entry leaves
    for i in range(last, at, -1):
        best_total[i] = best_total[i - 1]
        best_size[i] = best_size[i - 1]
        best_slot[i] = best_slot[i - 1]
    best_total[at] = total
    best_size[at] = size
    best_slot[at] = row
    for k in range(size):
        best_members[row, k] = clique[k]
    state[FILLED] = min(filled + 1, capacity)


@njit(cache=True, inline="always")
def _threshold(state: np.ndarray, best_total: np.ndarray) -> float:
    """The weight a branch must be able to reach (minus round-off slack) to be explored."""
    if state[FILLED] < len(best_total):
        return -np.inf
    worst = best_total[len(best_total) - 1]
    return worst - TOLERANCE * max(1.0, abs(worst))


@njit(cache=True)
def _search(problem, arrays, budget):
    """Advance the search by up to `budget` branch steps; all state is in `arrays` (see top_cliques)."""
    weights, groups, min_size, max_cliques = problem
    indptr, indices, order, position, potential = arrays.graph
    state = arrays.state
    (local_weight, local_group, local_vertex, local_of, adjacency, p_sets, x_sets, todo, members, weight_so_far,
     group_stamp, rank) = arrays.scratch
    best_total, best_size, best_slot, best_members = arrays.best
    words = p_sets.shape[1]
    clique = np.zeros(members.shape[0], np.int64)
    while budget > 0:
        level = state[LEVEL]
        if level < 0:  # the next first vertex
            if state[OUTER] >= len(order):
                state[STATUS] = DONE
                return
            v = order[state[OUTER]]
            threshold = _threshold(state, best_total)
            if potential[v] + TOLERANCE * max(1.0, abs(potential[v])) < threshold:
                # v's outer bound (its later neighbours) is at most its potential, and every vertex after it
                # in `order` has a potential no larger: all of them would be cut one by one below.
                state[STATUS] = DONE
                return
            state[OUTER] += 1
            budget -= 1
            later = 0
            for k in range(indptr[v], indptr[v + 1]):
                later += position[indices[k]] > position[v]
            if 1 + later < min_size:
                continue
            # The outer bound, from v's later neighbours: heaviest positive weight per group.
            if threshold > -np.inf:
                state[STAMP] += 1
                bound = weights[v]
                group_best = local_weight  # scratch, indexed by neighbour order (rebuilt below)
                count = 0
                for k in range(indptr[v], indptr[v + 1]):
                    u = indices[k]
                    if position[u] > position[v] and weights[u] > 0:
                        group_best[count] = weights[u]
                        local_group[count] = groups[u]
                        count += 1
                _rank_descending(group_best, count, rank)  # any order of equal values adds the same
                for at in range(count):  # no view of rank (a view is reference-counted)
                    k = rank[at]
                    if group_stamp[local_group[k]] != state[STAMP]:
                        group_stamp[local_group[k]] = state[STAMP]
                        bound += group_best[k]
                if bound < threshold:
                    continue
            # v's neighbourhood as local vertices 0..d-1, heaviest first (ties by index).
            d = indptr[v + 1] - indptr[v]
            first = indptr[v]  # v's neighbours: indices[first: first + d]
            for i in range(d):
                local_weight[i] = weights[indices[first + i]]
            _rank_descending(local_weight, d, rank)
            for i in range(d):
                u = indices[first + rank[i]]
                local_vertex[i] = u
                local_weight[i] = weights[u]
                local_group[i] = groups[u]
                local_of[u] = i
            adjacency[:d, :] = 0
            p_sets[0, :] = 0
            x_sets[0, :] = 0
            for i in range(d):
                u = local_vertex[i]
                for k in range(indptr[u], indptr[u + 1]):
                    j = local_of[indices[k]]  # outside the neighbourhood: the spare word's bit, never read
                    adjacency[i, j >> 6] |= np.uint64(1) << np.uint64(j & 63)
                if position[u] > position[v]:
                    p_sets[0, i >> 6] |= np.uint64(1) << np.uint64(i & 63)
                else:
                    x_sets[0, i >> 6] |= np.uint64(1) << np.uint64(i & 63)
            for i in range(d):
                local_of[local_vertex[i]] = 64 * words
            members[0] = v
            weight_so_far[0] = weights[v]
            state[LEVEL] = 0
            state[FRESH] = 1
            continue
        if state[FRESH]:  # evaluate the node just entered: a leaf, a cut, or its branches
            state[FRESH] = 0
            p_count = 0
            x_empty = True
            for w in range(words):
                p_count += _popcount(p_sets[level, w])
                x_empty &= x_sets[level, w] == 0
            if p_count == 0:
                if x_empty and level + 1 >= min_size:
                    size = level + 1
                    clique[0] = members[0]
                    for k in range(1, size):
                        clique[k] = local_vertex[members[k]]
                    _offer(clique, size, weights, state, best_total, best_size, best_slot, best_members)
                    state[REACHED] += 1
                    if state[REACHED] >= max_cliques:
                        state[STATUS] = COUNT_CAP
                        return
                state[LEVEL] = level - 1
                continue
            if level + 1 + p_count < min_size:
                state[LEVEL] = level - 1
                continue
            threshold = _threshold(state, best_total)
            if threshold > -np.inf:
                need = threshold - weight_so_far[level]
                gained = 0.0
                state[STAMP] += 1
                for w in range(words):  # local order is heaviest first: a group's first is its best
                    bits = p_sets[level, w]
                    while bits and gained < need:
                        i = (w << 6) + _lowest_bit(bits)
                        bits &= bits - np.uint64(1)
                        if local_weight[i] <= 0:
                            break
                        if group_stamp[local_group[i]] != state[STAMP]:
                            group_stamp[local_group[i]] = state[STAMP]
                            gained += local_weight[i]
                if gained < need:
                    state[LEVEL] = level - 1
                    continue
            # Tomita pivot: the vertex of P u X with the most neighbours in P.
            pivot, most = -1, -1
            for w in range(words):
                bits = p_sets[level, w] | x_sets[level, w]
                while bits:
                    u = (w << 6) + _lowest_bit(bits)
                    bits &= bits - np.uint64(1)
                    common = 0
                    for z in range(words):
                        common += _popcount(p_sets[level, z] & adjacency[u, z])
                    if common > most:
                        pivot, most = u, common
            for w in range(words):
                todo[level, w] = p_sets[level, w] & ~adjacency[pivot, w]
            continue
        # Branch on the next vertex of todo (lowest local index = heaviest).
        t = -1
        for w in range(words):
            if todo[level, w]:
                t = (w << 6) + _lowest_bit(todo[level, w])
                break
        if t < 0:
            state[LEVEL] = level - 1
            continue
        bit = np.uint64(1) << np.uint64(t & 63)
        todo[level, t >> 6] &= ~bit
        for w in range(words):
            p_sets[level + 1, w] = p_sets[level, w] & adjacency[t, w]
            x_sets[level + 1, w] = x_sets[level, w] & adjacency[t, w]
        p_sets[level, t >> 6] &= ~bit
        x_sets[level, t >> 6] |= bit
        members[level + 1] = t
        weight_so_far[level + 1] = weight_so_far[level] + local_weight[t]
        state[LEVEL] = level + 1
        state[FRESH] = 1
        budget -= 1
