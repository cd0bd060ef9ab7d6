"""Edges between the per-terrain place graphs, so the places graph is one connected graph.

1. Cross-terrain links (the paper): every dead end (a place with at most one GVD edge) links to the
   nearest place of another terrain within `max_link_distance`, trying the nearest candidates
   first and taking the first whose straight line crosses only traversable cells.
2. Strip links: a strip of one terrain often reaches the map in pieces (a few metres of sidewalk
   that the cameras took for asphalt, a gap in the scan). Every dead end of a terrain's places
   links to the nearest place of the same terrain in another piece within `max_distance`, when
   the straight line crosses only traversable cells and at most `max_gap` metres of them belong
   to another terrain: the strip continues, so the route on that terrain continues.
3. Bridges: while the graph has several components, each component joins its closest other
   component (Boruvka rounds, so at most log2(components) rounds). A bridge whose line crosses
   only traversable cells costs its length; otherwise it costs length * `bridge_penalty`.
   Nothing is dropped.

Positions are (P, 3) metres in the map frame; costs are metres.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

ClearFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""clear(a_xy (n, 2), b_xy (n, 2)) -> (n,) bool: the straight segment crosses only traversable cells."""


def always_clear(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.ones(len(a), dtype=bool)


def _segment_samples(a: np.ndarray, b: np.ndarray, cell_size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points every half cell along each segment a[i] -> b[i] (both ends included): (xy (m, 2),
    owner (m,) segment index, step (m,) metres each sample stands for)."""
    a, b = np.asarray(a, dtype=np.float64)[:, :2], np.asarray(b, dtype=np.float64)[:, :2]
    length = np.linalg.norm(b - a, axis=1)
    steps = np.maximum(np.ceil(length / (0.5 * cell_size)).astype(np.int64), 1) + 1
    owner = np.repeat(np.arange(len(a)), steps)
    t = (np.arange(steps.sum()) - np.repeat(np.cumsum(steps) - steps, steps)) / np.repeat(steps - 1, steps)
    return a[owner] + t[:, None] * (b - a)[owner], owner, (length / steps)[owner]


GapFn = Callable[[np.ndarray, np.ndarray, int], np.ndarray]
"""gap(a_xy (n, 2), b_xy (n, 2), terrain) -> (n,) metres of each straight segment that lie on
cells of another terrain than `terrain`."""


def grid_gap_length(label: np.ndarray, origin: np.ndarray, cell_size: float) -> GapFn:
    """A GapFn over a terrain label grid (H, W) (grid.py convention; -1 counts as another
    terrain), sampling each segment every half cell."""

    def gap(a: np.ndarray, b: np.ndarray, terrain: int) -> np.ndarray:
        return _length_on(label != terrain, a, b, origin, cell_size)

    return gap


def grid_line_passable(blocked: np.ndarray, origin: np.ndarray, cell_size: float, max_blocked: float) -> ClearFn:
    """A ClearFn: the segment crosses at most `max_blocked` metres of blocked cells (H, W) (a
    post or a trunk standing on a strip, which a robot steps around) and stays inside the grid."""

    def clear(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        outside = _length_on(None, a, b, origin, cell_size, blocked.shape)
        return (_length_on(blocked, a, b, origin, cell_size) <= max_blocked) & (outside == 0)

    return clear


def _length_on(cells: np.ndarray | None, a: np.ndarray, b: np.ndarray, origin: np.ndarray, cell_size: float,
               shape: tuple[int, int] | None = None) -> np.ndarray:
    """(n,) metres of each segment a[i] -> b[i] on True cells of `cells` (H, W), or, with
    cells None, outside a grid of `shape`."""
    if len(a) == 0:
        return np.zeros(0)
    xy, owner, step = _segment_samples(a, b, cell_size)
    H, W = cells.shape if cells is not None else shape
    rc = np.floor((xy - origin) / cell_size).astype(np.int64)
    if cells is None:
        hit = (rc[:, 1] < 0) | (rc[:, 1] >= H) | (rc[:, 0] < 0) | (rc[:, 0] >= W)
    else:
        hit = cells[np.clip(rc[:, 1], 0, H - 1), np.clip(rc[:, 0], 0, W - 1)]
    return np.bincount(owner, weights=hit * step, minlength=len(a))


def grid_line_clear(traversable: np.ndarray, origin: np.ndarray, cell_size: float) -> ClearFn:
    """A ClearFn over a boolean (H, W) grid (grid.py convention), sampling each segment every
    half cell."""

    def clear(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        a, b = np.asarray(a, dtype=np.float64)[:, :2], np.asarray(b, dtype=np.float64)[:, :2]
        if len(a) == 0:
            return np.zeros(0, dtype=bool)
        steps = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / (0.5 * cell_size)).astype(np.int64), 1) + 1
        owner = np.repeat(np.arange(len(a)), steps)
        t = (np.arange(steps.sum()) - np.repeat(np.cumsum(steps) - steps, steps)) / np.repeat(steps - 1, steps)
        xy = a[owner] + t[:, None] * (b - a)[owner]
        rc = np.floor((xy - origin) / cell_size).astype(np.int64)
        H, W = traversable.shape
        inside = (rc[:, 1] >= 0) & (rc[:, 1] < H) & (rc[:, 0] >= 0) & (rc[:, 0] < W)
        ok = inside & traversable[np.clip(rc[:, 1], 0, H - 1), np.clip(rc[:, 0], 0, W - 1)]
        return np.bincount(owner, weights=~ok, minlength=len(a)) == 0

    return clear


def link_dead_ends(
    position: np.ndarray,
    terrain: np.ndarray,
    edges: np.ndarray,
    max_distance: float,
    candidates: int = 8,
    clear: ClearFn = always_clear,
) -> tuple[np.ndarray, np.ndarray]:
    """Cross-terrain links (k, 2) (i < j, unique) and their lengths (k,) in metres."""
    position = np.asarray(position, dtype=np.float64)
    terrain = np.asarray(terrain)
    degree = np.bincount(np.asarray(edges, dtype=np.int64).ravel(), minlength=len(position))
    found_pairs, found_len = [], []
    for t in np.unique(terrain):
        ends = np.flatnonzero((terrain == t) & (degree <= 1))
        others = np.flatnonzero(terrain != t)
        if ends.size == 0 or others.size == 0:
            continue
        k = min(candidates, others.size)
        dist, idx = cKDTree(position[others, :2]).query(position[ends, :2], k=k, distance_upper_bound=max_distance)
        dist, idx = dist.reshape(len(ends), k), idx.reshape(len(ends), k)
        valid = np.isfinite(dist)
        rows, cols = np.nonzero(valid)
        ok = np.zeros_like(valid)
        ok[rows, cols] = clear(position[ends[rows], :2], position[others[idx[rows, cols]], :2])
        first = np.argmax(ok, axis=1)
        has = ok[np.arange(len(ends)), first]
        a = ends[has]
        b = others[idx[has, first[has]]]
        found_pairs.append(np.stack([a, b], axis=1))
        found_len.append(np.linalg.norm(position[a] - position[b], axis=1))
    if not found_pairs:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    pairs = np.sort(np.vstack(found_pairs), axis=1)
    lengths = np.concatenate(found_len)
    pairs, first = np.unique(pairs, axis=0, return_index=True)
    return pairs.astype(np.int64), lengths[first]


def link_strip_gaps(
    position: np.ndarray,
    terrain: np.ndarray,
    edges: np.ndarray,
    max_distance: float,
    candidates: int = 8,
    clear: ClearFn = always_clear,
    gap: GapFn | None = None,
    max_gap: float = np.inf,
) -> tuple[np.ndarray, np.ndarray]:
    """Same-terrain links (k, 2) (i < j, unique) across gaps between pieces of one terrain's places
    graph, and their lengths (k,) in metres (see the module docstring).

    gap: metres of a segment on cells of another terrain (see GapFn); None skips the `max_gap` test. Pieces are the connected components of the graph restricted to
    same-terrain edges; links join dead ends (at most one same-terrain edge) to other pieces.
    """
    position = np.asarray(position, dtype=np.float64)
    terrain = np.asarray(terrain)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    P = len(position)
    same = edges[terrain[edges[:, 0]] == terrain[edges[:, 1]]] if len(edges) else edges
    graph = sp.coo_matrix((np.ones(len(same)), (same[:, 0], same[:, 1])), shape=(P, P))
    _, piece = connected_components(graph, directed=False)
    degree = np.bincount(same.ravel(), minlength=P)
    found_pairs, found_len = [], []
    for t in np.unique(terrain):
        mine = np.flatnonzero(terrain == t)
        ends = mine[degree[mine] <= 1]
        if ends.size == 0 or len(np.unique(piece[mine])) < 2:
            continue
        k = min(candidates + 1, mine.size)
        dist, idx = cKDTree(position[mine, :2]).query(position[ends, :2], k=k, distance_upper_bound=max_distance)
        dist, idx = dist.reshape(len(ends), k), idx.reshape(len(ends), k)
        valid = np.isfinite(dist)
        valid[valid] &= piece[mine[idx[valid]]] != np.repeat(piece[ends], k).reshape(len(ends), k)[valid]
        rows, cols = np.nonzero(valid)
        a, b = position[ends[rows], :2], position[mine[idx[rows, cols]], :2]
        ok = np.zeros_like(valid)
        good = clear(a, b)
        if gap is not None and len(a):
            good &= gap(a, b, int(t)) <= max_gap
        ok[rows, cols] = good
        first = np.argmax(ok, axis=1)
        has = ok[np.arange(len(ends)), first]
        a_idx, b_idx = ends[has], mine[idx[has, first[has]]]
        found_pairs.append(np.stack([a_idx, b_idx], axis=1))
        found_len.append(np.linalg.norm(position[a_idx] - position[b_idx], axis=1))
    if not found_pairs:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    pairs = np.sort(np.vstack(found_pairs), axis=1)
    lengths = np.concatenate(found_len)
    pairs, first = np.unique(pairs, axis=0, return_index=True)
    return pairs.astype(np.int64), lengths[first]


def bridge_components(
    position: np.ndarray,
    edges: np.ndarray,
    penalty: float,
    candidates: int = 8,
    clear: ClearFn = always_clear,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bridges (k, 2) that connect every component, their costs (k,) in metres (length, times
    `penalty` where the line is not clear) and whether each is clear (k,)."""
    position = np.asarray(position, dtype=np.float64)
    P = len(position)
    all_edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    out_pairs, out_cost, out_clear = [], [], []
    while P > 1:
        graph = sp.coo_matrix((np.ones(len(all_edges)), (all_edges[:, 0], all_edges[:, 1])), shape=(P, P))
        n_comp, comp = connected_components(graph, directed=False)
        if n_comp == 1:
            break
        round_pairs, round_cost, round_clear = [], [], []
        for c in range(n_comp):
            mine, rest = np.flatnonzero(comp == c), np.flatnonzero(comp != c)
            k = min(candidates, rest.size)
            dist, idx = cKDTree(position[rest, :2]).query(position[mine, :2], k=k)
            dist, idx = dist.reshape(len(mine), k), idx.reshape(len(mine), k)
            a = np.repeat(mine, k)
            b = rest[idx.ravel()]
            length = np.linalg.norm(position[a] - position[b], axis=1)
            # Only the closest candidates can win; test lines for those within penalty * best.
            near = length <= length.min() * penalty
            ok = np.zeros(len(a), dtype=bool)
            ok[near] = clear(position[a[near], :2], position[b[near], :2])
            cost = np.where(ok, length, length * penalty)
            best = np.lexsort((b, a, cost))[0]
            round_pairs.append(sorted((int(a[best]), int(b[best]))))
            round_cost.append(cost[best])
            round_clear.append(ok[best])
        pairs = np.asarray(round_pairs, dtype=np.int64)
        pairs, first = np.unique(pairs, axis=0, return_index=True)
        out_pairs.append(pairs)
        out_cost.append(np.asarray(round_cost)[first])
        out_clear.append(np.asarray(round_clear)[first])
        all_edges = np.vstack([all_edges, pairs])
    if not out_pairs:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0), np.zeros(0, dtype=bool)
    return np.vstack(out_pairs), np.concatenate(out_cost), np.concatenate(out_clear)
