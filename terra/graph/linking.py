"""Edges between the per-terrain place graphs, so the places graph is one connected graph.

1. Cross-terrain links (the paper): every dead end (a place with at most one GVD edge) links to the
   nearest place of another terrain within `max_link_distance`, trying the nearest candidates
   first and taking the first whose straight line crosses only traversable cells.
2. Strip links: a strip of one terrain often reaches the map in pieces (a few metres of sidewalk
   that the cameras took for asphalt, a gap in the scan). Every dead end of a terrain's places
   links to the nearest place of the same terrain in another piece within `max_distance`, when
   the straight line crosses only traversable cells and at most `max_gap` metres of them belong
   to another terrain: the strip continues, so the route on that terrain continues.
   Pieces that straight lines cannot join (a car between them) are then joined along grid
   paths (terra.graph.grid_links).
3. Bridges: while the graph has several components, each component joins its closest other
   component (Boruvka rounds, so at most log2(components) rounds). A bridge whose line crosses
   only traversable cells costs its length; otherwise it costs length * `bridge_penalty`.
   Nothing is dropped.

Lines are tested lazily, nearest candidate first, and only as far as a candidate can still win
(`first_passing`, `_cheapest_per_group`): a dead end whose nearest candidate is clear costs one
line test, not `candidates`; a component costs a few, not `candidates` per place. Line samples
are taken in bounded chunks (`_SAMPLES_PER_CHUNK`), so memory does not grow with the map.

Positions are (P, 3) metres in the map frame; costs are metres.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

ClearFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""clear(a_xy (n, 2), b_xy (n, 2)) -> (n,) bool: the straight segment crosses only traversable cells."""


def always_clear(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.ones(len(a), dtype=bool)


_SAMPLES_PER_CHUNK = 1 << 18
"""Line samples processed at once (each costs about 60 bytes of temporaries: ~16 MB)."""


def _segment_chunks(a: np.ndarray, b: np.ndarray, cell_size: float):
    """Slices of the segments a[i] -> b[i] whose half-cell samples number about _SAMPLES_PER_CHUNK."""
    a, b = np.asarray(a, dtype=np.float64)[:, :2], np.asarray(b, dtype=np.float64)[:, :2]
    steps = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / (0.5 * cell_size)).astype(np.int64), 1) + 1
    bounds = np.searchsorted(
        np.cumsum(steps), np.arange(1, int(steps.sum() // _SAMPLES_PER_CHUNK) + 1) * _SAMPLES_PER_CHUNK
    )
    edges = np.unique(np.concatenate([[0], bounds, [len(a)]]))
    return [slice(int(lo), int(hi)) for lo, hi in zip(edges[:-1], edges[1:])]


def _segment_samples(
    a: np.ndarray, b: np.ndarray, cell_size: float, stride: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points every half cell along each segment a[i] -> b[i] (both ends included): (xy (m, 2),
    owner (m,) segment index, step (m,) metres each sample stands for). With `stride` s > 1 only
    every s-th of those same points (from the first): a subset for a quick rejection."""
    a, b = np.asarray(a, dtype=np.float64)[:, :2], np.asarray(b, dtype=np.float64)[:, :2]
    length = np.linalg.norm(b - a, axis=1)
    steps = np.maximum(np.ceil(length / (0.5 * cell_size)).astype(np.int64), 1) + 1
    taken = (steps + stride - 1) // stride
    owner = np.repeat(np.arange(len(a)), taken)
    index = (np.arange(taken.sum()) - np.repeat(np.cumsum(taken) - taken, taken)) * stride
    t = index / np.repeat(steps - 1, taken)
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


def _length_on(
    cells: np.ndarray | None,
    a: np.ndarray,
    b: np.ndarray,
    origin: np.ndarray,
    cell_size: float,
    shape: tuple[int, int] | None = None,
) -> np.ndarray:
    """(n,) metres of each segment a[i] -> b[i] on True cells of `cells` (H, W), or, with
    cells None, outside a grid of `shape`."""
    out = np.zeros(len(a))
    grid_shape = cells.shape if cells is not None else shape
    if grid_shape is None:
        raise ValueError("the segments' lengths need the cells or the shape of the grid")
    H, W = grid_shape
    for part in _segment_chunks(a, b, cell_size):
        xy, owner, step = _segment_samples(a[part], b[part], cell_size)
        rc = np.floor((xy - origin) / cell_size).astype(np.int64)
        if cells is None:
            hit = (rc[:, 1] < 0) | (rc[:, 1] >= H) | (rc[:, 0] < 0) | (rc[:, 0] >= W)
        else:
            hit = cells[np.clip(rc[:, 1], 0, H - 1), np.clip(rc[:, 0], 0, W - 1)]
        out[part] = np.bincount(owner, weights=hit * step, minlength=part.stop - part.start)
    return out


def grid_line_crosses(cells: np.ndarray, origin: np.ndarray, cell_size: float) -> ClearFn:
    """A ClearFn that passes the segments touching a True cell of `cells` (H, W) (a line of
    steps), sampling each every half cell."""

    def crosses(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return _length_on(cells, a, b, origin, cell_size) > 0

    return crosses


def grid_line_clear(traversable: np.ndarray, origin: np.ndarray, cell_size: float) -> ClearFn:
    """A ClearFn over a boolean (H, W) grid (grid.py convention), sampling each segment every
    half cell."""

    H, W = traversable.shape

    def all_ok(a: np.ndarray, b: np.ndarray, stride: int) -> np.ndarray:
        out = np.zeros(len(a), dtype=bool)
        for part in _segment_chunks(a, b, cell_size * stride):
            xy, owner, _ = _segment_samples(a[part], b[part], cell_size, stride)
            rc = np.floor((xy - origin) / cell_size).astype(np.int64)
            inside = (rc[:, 1] >= 0) & (rc[:, 1] < H) & (rc[:, 0] >= 0) & (rc[:, 0] < W)
            ok = inside & traversable[np.clip(rc[:, 1], 0, H - 1), np.clip(rc[:, 0], 0, W - 1)]
            out[part] = np.bincount(owner, weights=~ok, minlength=part.stop - part.start) == 0
        return out

    def clear(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        # Long lines that fail usually fail early: every 8th sample first rejects most of them
        # (a subset of the same samples, so the answer is unchanged), then the rest in full.
        a, b = np.asarray(a, dtype=np.float64)[:, :2], np.asarray(b, dtype=np.float64)[:, :2]
        out = all_ok(a, b, 8)
        if out.any():
            out[out] = all_ok(a[out], b[out], 1)
        return out

    return clear


def first_passing(valid: np.ndarray, test: Callable[[np.ndarray, int], np.ndarray]) -> np.ndarray:
    """(n,) index of the first column c of each row of `valid` (n, k) bool whose candidate passes
    `test(rows, c) -> (len(rows),) bool`, or -1: columns are tried in order, each only for the rows
    still without a winner (one batched call per column)."""
    first = np.full(valid.shape[0], -1, dtype=np.int64)
    for c in range(valid.shape[1]):
        rows = np.flatnonzero((first < 0) & valid[:, c])
        if rows.size:
            first[rows[test(rows, c)]] = c
    return first


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
        # The test runs inside first_passing, in this iteration; the defaults bind its arrays anyway.
        first = first_passing(
            np.isfinite(dist),
            lambda rows, c, ends=ends, others=others, idx=idx: clear(
                position[ends[rows], :2], position[others[idx[rows, c]], :2]
            ),
        )
        has = first >= 0
        a = ends[has]
        b = others[idx[has, first[has]]]
        found_pairs.append(np.stack([a, b], axis=1))
        found_len.append(np.linalg.norm(position[a] - position[b], axis=1))
    return _unique_links(found_pairs, found_len)


def link_across(
    position: np.ndarray,
    max_distance: float,
    candidates: int,
    across: ClearFn,
    clear: ClearFn = always_clear,
) -> tuple[np.ndarray, np.ndarray]:
    """Links (k, 2) (i < j, unique) and their lengths (k,) metres: each place at `position`
    (P, 2+) metres to the nearest of its `candidates` nearest places within `max_distance` metres
    whose straight line passes `across` (it crosses what the links are for) and `clear`."""
    position = np.asarray(position, dtype=np.float64)
    n = len(position)
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    k = min(candidates + 1, n)  # the place itself comes first
    dist, idx = cKDTree(position[:, :2]).query(position[:, :2], k=k, distance_upper_bound=max_distance)
    dist, idx = dist.reshape(n, k), idx.reshape(n, k)
    valid = np.isfinite(dist) & (idx != np.arange(n)[:, None])

    def passes(rows: np.ndarray, c: int) -> np.ndarray:
        a, b = position[rows, :2], position[idx[rows, c], :2]
        return across(a, b) & clear(a, b)

    first = first_passing(valid, passes)
    has = first >= 0
    a, b = np.flatnonzero(has), idx[has, first[has]]
    return _unique_links([np.stack([a, b], axis=1)], [np.linalg.norm(position[a] - position[b], axis=1)])


def _unique_links(found_pairs: list[np.ndarray], found_len: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Sorted unique (i < j) pairs (k, 2) and the length of each pair's first occurrence (k,)."""
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

    gap: metres of a segment on cells of another terrain (see GapFn); None skips the `max_gap`
    test. Pieces are the connected components of the graph restricted to same-terrain edges;
    links join dead ends (at most one same-terrain edge) to other pieces.
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

        def passes(
            rows: np.ndarray,
            c: int,
            t: int = int(t),
            mine: np.ndarray = mine,
            ends: np.ndarray = ends,
            idx: np.ndarray = idx,
        ) -> np.ndarray:
            a, b = position[ends[rows], :2], position[mine[idx[rows, c]], :2]
            good = clear(a, b)
            if gap is not None:
                good &= gap(a, b, t) <= max_gap
            return good

        first = first_passing(valid, passes)
        has = first >= 0
        a_idx, b_idx = ends[has], mine[idx[has, first[has]]]
        found_pairs.append(np.stack([a_idx, b_idx], axis=1))
        found_len.append(np.linalg.norm(position[a_idx] - position[b_idx], axis=1))
    return _unique_links(found_pairs, found_len)


def bridge_components(
    position: np.ndarray,
    edges: np.ndarray,
    penalty: float,
    candidates: int = 8,
    clear: ClearFn = always_clear,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bridges (k, 2) that connect every component, their costs (k,) in metres (length, times
    `penalty` where the line is not clear) and whether each is clear (k,).

    Each Boruvka round, every component takes its cheapest candidate (ties: lowest place indices):
    the pairs of each of its places with that place's `candidates` nearest places (2D) of other
    components; a candidate costs its length (3D), times `penalty` if its line is not clear.
    """
    position = np.asarray(position, dtype=np.float64)
    P = len(position)
    all_edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    out_pairs, out_cost, out_clear = [], [], []
    tree = cKDTree(position[:, :2]) if P > 1 else None
    while P > 1:
        graph = sp.coo_matrix((np.ones(len(all_edges)), (all_edges[:, 0], all_edges[:, 1])), shape=(P, P))
        n_comp, comp = connected_components(graph, directed=False)
        if n_comp == 1:
            break
        a, b = other_component_neighbours(tree, position[:, :2], comp, candidates)
        length = np.linalg.norm(position[a] - position[b], axis=1)
        # The test runs inside cheapest_per_group, in this round; the defaults bind its arrays anyway.
        win, cost, ok = cheapest_per_group(
            comp[a], a, b, length, penalty, lambda i, a=a, b=b: clear(position[a[i], :2], position[b[i], :2])
        )
        pairs = np.sort(np.column_stack([a[win], b[win]]), axis=1).astype(np.int64)
        pairs, first = np.unique(pairs, axis=0, return_index=True)
        out_pairs.append(pairs)
        out_cost.append(cost[first])
        out_clear.append(ok[first])
        all_edges = np.vstack([all_edges, pairs])
    if not out_pairs:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0), np.zeros(0, dtype=bool)
    return np.vstack(out_pairs), np.concatenate(out_cost), np.concatenate(out_clear)


_SMALL_COMPONENT = 256
"""Components up to this size find their neighbours in one query of the tree of all places;
larger ones (few: at most P / 256) query a tree of the places outside them."""


def other_component_neighbours(
    tree: cKDTree, xy: np.ndarray, comp: np.ndarray, candidates: int
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate pairs (a, b) (m,) each: every place a with its min(candidates, places outside
    its component) nearest places b (2D) in other components, nearest first."""
    P = len(xy)
    size = np.bincount(comp)
    out_a, out_b = [], []
    small = size[comp] <= _SMALL_COMPONENT
    bucket = np.where(small, np.ceil(np.log2(np.maximum(size[comp], 1))).astype(np.int64), -1)
    for level in np.unique(bucket[bucket >= 0]):
        rows = np.flatnonzero(bucket == level)
        kq = int(min(P, candidates + (1 << int(level))))
        _, idx = tree.query(xy[rows], k=kq)
        idx = idx.reshape(len(rows), kq)
        other = comp[idx] != comp[rows][:, None]
        # Keep the first `candidates` others of each row (a row always has min(candidates, P - size) of them).
        keep = other & (np.cumsum(other, axis=1) <= candidates)
        r, c = np.nonzero(keep)
        out_a.append(rows[r])
        out_b.append(idx[r, c])
    for c in np.flatnonzero(size > _SMALL_COMPONENT):
        mine, rest = np.flatnonzero(comp == c), np.flatnonzero(comp != c)
        k = min(candidates, rest.size)
        _, idx = cKDTree(xy[rest]).query(xy[mine], k=k)
        out_a.append(np.repeat(mine, k))
        out_b.append(rest[idx.reshape(len(mine), k).ravel()])
    return np.concatenate(out_a).astype(np.int64), np.concatenate(out_b).astype(np.int64)


def cheapest_per_group(
    group: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    length: np.ndarray,
    penalty: float,
    clear: Callable[[np.ndarray], np.ndarray],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per group (0..G-1, every group present): the candidate of least (cost, a, b), where cost is
    `length`, or `length * penalty` (>= length) when `clear(indices) -> bool` fails.

    Candidates are tested shortest first, in doubling batches per group, and only while a
    candidate's length does not exceed the group's best cost so far (no later one can win).
    Returns (winner index (G,), its cost (G,), whether its line is clear (G,))."""
    order = np.lexsort((b, a, length, group))
    n_groups = int(group.max()) + 1
    start = np.searchsorted(group[order], np.arange(n_groups))
    end = np.searchsorted(group[order], np.arange(n_groups), side="right")
    best = np.full(n_groups, -1, dtype=np.int64)
    best_cost = np.full(n_groups, np.inf)
    best_ok = np.zeros(n_groups, dtype=bool)
    pos, batch = start.copy(), 1
    active = pos < end
    while active.any():
        g = np.flatnonzero(active)
        take = np.minimum(end[g] - pos[g], batch)
        owner = np.repeat(g, take)
        cand = order[np.repeat(pos[g], take) + np.arange(take.sum()) - np.repeat(np.cumsum(take) - take, take)]
        ok = clear(cand)
        cost = np.where(ok, length[cand], length[cand] * penalty)
        # Merge with the best so far: least (cost, a, b) per group.
        held = g[best[g] >= 0]
        all_owner = np.concatenate([owner, held])
        all_cand = np.concatenate([cand, best[held]])
        all_cost = np.concatenate([cost, best_cost[held]])
        all_ok = np.concatenate([ok, best_ok[held]])
        pick = np.lexsort((b[all_cand], a[all_cand], all_cost, all_owner))
        firsts = pick[np.r_[True, all_owner[pick][1:] != all_owner[pick][:-1]]]
        best[all_owner[firsts]] = all_cand[firsts]
        best_cost[all_owner[firsts]] = all_cost[firsts]
        best_ok[all_owner[firsts]] = all_ok[firsts]
        pos[g] += take
        batch *= 2
        nxt = np.minimum(pos, len(order) - 1)
        active = (pos < end) & (length[order[nxt]] <= best_cost)
    return best, best_cost, best_ok
