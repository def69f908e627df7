"""The clique search split by map region, for a frame of many candidates spread over several regions.

Two landmarks farther apart than compatibility's reach (the widest observation pair plus the widest
tolerance) are never compatible, so no clique spans two regions of the map that far apart. A building
of identical rooms keeps a copy of each candidate per room (a thousand rooms: 100,000 candidates, five
times `matching.max_candidates`), and one search over all of them expands every room's equally heavy
cliques. From `inliers.region_split_from` candidates (or beyond the cap) each region is searched alone,
the cap counted per region, and regions that are copies of one another (the same observations, scores,
landmark shapes and layout to a nanometre, positions relative to the region's first candidate) share
one search whose cliques are mapped onto every copy. A region's graph is tested on its own landmarks
exactly as the whole map's would be; where a test is decided by less than DECIDED_BY, its copies are
tested one by one. The heaviest cliques overall are merged in `cliquesearch`'s order (heavier first,
ties by the sorted member lists): the same cliques, with the same weights, as one search of the whole graph, when
no cap is hit. Only `reached` differs: it counts each region's own search.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from clipclique.config import InlierConfig
from clipclique.descriptors import matching
from clipclique.inliers import cliquesearch, compatibility
from clipclique.outcomes import RegionSplit
from clipclique.types import Ellipsoids

NANOMETRE = 1e-9  # the grain landmark positions are compared on when regions are matched as copies
DECIDED_BY = 1e-8  # metres: copies' pair distances agree to a few nanometres; a test this near its tolerance
# could go the other way in a copy, so the copies of such a region are tested one by one


@dataclass(frozen=True, kw_only=True)
class Regions:
    """The candidates split by map region, and the regions grouped into copies of one layout."""

    kept: np.ndarray  # rows of the matched candidates kept (all, unless a region held more than the cap)
    rows: list[np.ndarray]  # per region, its rows of the kept candidates (ascending); ordered by first row
    copies: list[list[int]]  # per distinct layout, the regions that have it (ascending); the first is searched
    capped: bool  # a region held more than max_candidates; its best-scored were kept (matching.cap)


@dataclass(frozen=True, kw_only=True)
class Layout:
    """One distinct region's search problem, in local indices, and where its copies' vertices are."""

    edges: np.ndarray  # (E, 2) local compatibility edges
    weights: np.ndarray  # (n,) candidate scores
    groups: np.ndarray  # (n,) the object each candidate's observation shows
    vertices: np.ndarray  # (copies, n) each copy's candidate rows, local order = ascending rows


def region_labels(points: np.ndarray, reach: float) -> np.ndarray:
    """(P,) a region per point: points within `reach` of each other share one (a grid of cells a hair wider
    than `reach`, touching occupied cells joined), numbered in the order of their first point."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    cells = np.floor(points / (reach * (1 + 1e-9) + 1e-9)).astype(np.int64)
    cells -= cells.min(axis=0) - 1
    span = cells.max(axis=0) + 2
    if float(np.prod(span.astype(np.float64))) > 2.0**62:  # a tiny reach over a huge map: one region
        return np.zeros(len(points), np.int64)
    keys = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
    touching = np.array([(dx * span[1] + dy) * span[2] + dz for dx, dy, dz in itertools.product((-1, 0, 1), repeat=3)
                         if (dx, dy, dz) > (0, 0, 0)], np.int64)  # key steps to the 13 cells after a cell
    return _joined_cells(keys, np.argsort(keys), touching)


@njit(cache=True)
def _joined_cells(keys: np.ndarray, order: np.ndarray, touching: np.ndarray) -> np.ndarray:
    """`region_labels` from the points' cell keys sorted by `order`: occupied cells, touching ones joined
    (union-find), regions numbered by first point. One compiled pass: numpy's unique, sparse graph and
    connected components took 24 ms for the 100,000 candidates of a building of a thousand rooms."""
    cell_of = np.empty(len(keys), np.int64)
    distinct = np.empty(len(keys), np.int64)
    count = 0
    for i in range(len(order)):
        if count == 0 or keys[order[i]] != distinct[count - 1]:
            distinct[count] = keys[order[i]]
            count += 1
        cell_of[order[i]] = count - 1
    distinct = distinct[:count]
    parent = np.arange(count)
    for c in range(count):
        for step in touching:
            j = np.searchsorted(distinct, distinct[c] + step)
            if j < count and distinct[j] == distinct[c] + step:
                a, b = c, j
                while parent[a] != a:
                    a = parent[a]
                while parent[b] != b:
                    b = parent[b]
                parent[max(a, b)] = min(a, b)
    label_of_root = np.full(count, -1, np.int64)
    labels = np.empty(len(keys), np.int64)
    regions = 0
    for i in range(len(keys)):
        root = cell_of[i]
        while parent[root] != root:
            root = parent[root]
        if label_of_root[root] < 0:
            label_of_root[root] = regions
            regions += 1
        labels[i] = label_of_root[root]
    return labels


def split(observed_centers: np.ndarray, landmarks: Ellipsoids, candidates: np.ndarray, scores: np.ndarray,
          objects: np.ndarray, settings: InlierConfig, max_candidates: int) -> Regions:
    """The candidates' regions, each region's best `max_candidates` kept, and their copies. The reach is
    taken with the widest slack the settings allow (wider only joins regions: no clique is lost)."""
    observed = np.linalg.norm(observed_centers[:, None] - observed_centers[None], axis=-1)
    widest = np.array([settings.max_slack if settings.partial_slack > 0 else 0.0])
    labels = region_labels(landmarks.centers[candidates[:, 1]],
                           compatibility.pair_reach(observed, settings.d_comp, widest))
    sizes = np.bincount(labels)
    order = _label_order(labels, sizes)
    bounds = np.concatenate(([0], np.cumsum(sizes)))
    rows = [order[start:end] for start, end in itertools.pairwise(bounds)]
    capped = bool(sizes.max() > max_candidates)
    kept = np.arange(len(candidates))
    if capped:
        rows = [matching.cap(region[:, None], scores[region], max_candidates)[0][:, 0] for region in rows]
        kept = np.sort(np.concatenate(rows))
        rows = [np.searchsorted(kept, region) for region in rows]
        candidates, scores = candidates[kept], scores[kept]
    return Regions(kept=kept, rows=rows, copies=_copies(rows, landmarks, candidates, scores, objects), capped=capped)


@njit(cache=True)
def _label_order(labels: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """Indices sorted by label, ascending within a label (a counting sort)."""
    at = np.zeros(len(sizes), np.int64)
    at[1:] = np.cumsum(sizes)[:-1]
    order = np.empty(len(labels), np.int64)
    for i in range(len(labels)):
        order[at[labels[i]]] = i
        at[labels[i]] += 1
    return order


def _copies(rows: list[np.ndarray], landmarks: Ellipsoids, candidates: np.ndarray, scores: np.ndarray,
            objects: np.ndarray) -> list[list[int]]:
    """The regions grouped by layout: a region's candidates, in row order, as (observation's object,
    observation, score, landmark semi-axes (the slack's input), which of the region's landmarks, its
    position relative to the region's first candidate's landmark in nanometres); equal records, one
    layout. Built for all regions at once (one region at a time cost 80 us each)."""
    sizes = np.fromiter(map(len, rows), np.int64, len(rows))
    starts = np.concatenate(([0], np.cumsum(sizes)))
    order = np.concatenate(rows)
    obs, lm = candidates[order, 0], candidates[order, 1]
    region = np.repeat(np.arange(len(rows)), sizes)
    relative = np.rint((landmarks.centers[lm] - landmarks.centers[lm[starts[:-1]]][region]) / NANOMETRE)
    bits = lambda values: np.ascontiguousarray(values, np.float64).view(np.int64).reshape(len(order), -1)  # noqa: E731
    record = np.column_stack((objects[obs], obs, bits(scores[order]), bits(landmarks.axes[lm]),
                              _first_seen(lm, starts, len(landmarks.centers)), relative.astype(np.int64)))
    layouts: dict[bytes, list[int]] = {}
    for r, (start, end) in enumerate(itertools.pairwise(starts)):
        layouts.setdefault(record[start:end].tobytes(), []).append(r)
    return list(layouts.values())


@njit(cache=True)
def _first_seen(landmarks: np.ndarray, starts: np.ndarray, num_landmarks: int) -> np.ndarray:
    """Per row, its landmark numbered within its region (rows starts[r]:starts[r + 1]) by first appearance."""
    local = np.empty(len(landmarks), np.int64)
    seen = np.full(num_landmarks, -1, np.int64)
    stamp = np.full(num_landmarks, -1, np.int64)
    for r in range(len(starts) - 1):
        count = 0
        for i in range(starts[r], starts[r + 1]):
            if stamp[landmarks[i]] != r:
                stamp[landmarks[i]] = r
                seen[landmarks[i]] = count
                count += 1
            local[i] = seen[landmarks[i]]
    return local


def layouts(regions: Regions, observations: Ellipsoids, landmarks: Ellipsoids, candidates: np.ndarray,
            scores: np.ndarray, objects: np.ndarray, settings: InlierConfig) -> tuple[list[Layout], bool]:
    """Each distinct region's compatibility graph, tested on its own landmarks exactly as the whole map's
    graph would be, and whether `inliers.max_pairs` cut one. A layout whose first region has a pair test
    decided by less than DECIDED_BY (its copies' distances agree only to a few nanometres) is split back
    into its regions, each tested on its own."""
    found, pairs_capped = [], False
    for copies in regions.copies:
        edges, capped, close = _graph(regions.rows[copies[0]], observations, landmarks, candidates, objects, settings,
                                      scores, check=len(copies) > 1)
        pairs_capped |= capped
        found.append(_layout(regions, copies[:1] if close else copies, edges, candidates, scores, objects))
        for r in copies[1:] if close else []:
            edges, capped, _ = _graph(regions.rows[r], observations, landmarks, candidates, objects, settings, scores,
                                      check=False)
            pairs_capped |= capped
            found.append(_layout(regions, [r], edges, candidates, scores, objects))
    return found, pairs_capped


def _layout(regions: Regions, copies: list[int], edges: np.ndarray, candidates: np.ndarray, scores: np.ndarray,
            objects: np.ndarray) -> Layout:
    region = regions.rows[copies[0]]
    return Layout(edges=edges, weights=scores[region], groups=objects[candidates[region, 0]],
                  vertices=np.stack([regions.rows[r] for r in copies]))


def _graph(region: np.ndarray, observations: Ellipsoids, landmarks: Ellipsoids, candidates: np.ndarray,
           objects: np.ndarray, settings: InlierConfig, scores: np.ndarray, *, check: bool
           ) -> tuple[np.ndarray, bool, bool]:
    """(local edges, whether max_pairs cut the region, whether `check` found a test decided by less than
    DECIDED_BY: one the graph with d_comp DECIDED_BY wider has and the one DECIDED_BY narrower lacks):
    the pipeline's compatibility graph of one region's candidates."""
    obs, lm = candidates[region, 0], candidates[region, 1]
    unique, local_landmark = np.unique(lm, return_inverse=True)
    points, local = landmarks.centers[unique], np.column_stack((obs, local_landmark.ravel()))
    slack = compatibility.candidate_slack(observations.axes, landmarks.axes, candidates[region], settings.partial_slack,
                                          settings.max_slack, settings.slack_min_deficit)
    kept = compatibility.affordable_candidates(observations.centers, points, local, scores[region],
                                               settings.d_comp, slack, max_pairs=settings.max_pairs)
    graph = lambda d_comp: compatibility.compatibility_graph(  # noqa: E731
        observations.centers, points, local[kept], d_comp, slack[kept], objects)
    close = check and len(graph(settings.d_comp + DECIDED_BY)) != len(graph(settings.d_comp - DECIDED_BY))
    return kept[graph(settings.d_comp)], len(kept) < len(region), close


def top_cliques(found: list[Layout], count: int, settings: InlierConfig) -> cliquesearch.TopCliques:
    """The `count` heaviest maximal cliques over all regions, as candidate rows, ranked as
    `cliquesearch.top_cliques` ranks them: each layout searched once, its cliques mapped onto its copies
    (equally heavy there; among copies the smaller rows first). `reached` counts every copy's cliques;
    the time limit is shared by all the searches."""
    deadline = time.perf_counter() + settings.time_limit_s
    ranked: list[tuple[float, tuple[int, ...]]] = []
    reached, cap = 0, None
    for layout in found:
        if len(layout.weights) < settings.min_clique_size:
            continue
        left = max(deadline - time.perf_counter(), 1e-6)
        local = cliquesearch.top_cliques(layout.edges, len(layout.weights), layout.weights, count, layout.groups,
                                         settings.min_clique_size, settings.max_cliques, left)
        reached += local.reached * len(layout.vertices)
        cap = cap or local.cap
        for members, total in zip(local.cliques, local.totals):
            images = layout.vertices[:, members]  # (copies, size), rows ascending: local order is row order
            first = np.lexsort(images.T[::-1])[:count]
            ranked.extend((-float(total), tuple(image)) for image in images[first].tolist())
    ranked.sort()
    best = ranked[:count]
    return cliquesearch.TopCliques.of([np.array(members, np.int64) for _, members in best],
                                      np.array([-negated for negated, _ in best]), reached, cap)


def summary(regions: Regions, found: list[Layout], best: cliquesearch.TopCliques) -> RegionSplit:
    """The split's counts, and how many regions hold the heaviest clique (its region and that region's copies)."""
    tied = 0
    if len(best.sizes):
        tied = next(len(layout.vertices) for layout in found if np.any(layout.vertices == best.members[0]))
    return RegionSplit(regions=len(regions.rows), layouts=len(regions.copies), tied_regions=tied)
