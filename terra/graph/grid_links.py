"""Grid links: same-terrain pieces of the places graph joined by a path on the terrain grid.

A terrain's places can fall into pieces (connected components of the graph restricted to that
terrain's edges) although their cells are connected in the grid, or nearly so: a lane between
two rows of parked cars that the opening of the terrain mask cut, a loop of places whose straight
links to the rest of the lot all cross a car. Strip links (linking.py) only try straight lines
from dead ends; here a piece is joined to a nearby piece of its terrain by the cheapest 8-connected
grid path between their places that

- crosses no blocked cell and no cell labelled with another terrain (a diagonal step also needs
  both cells beside it free, so a path never squeezes between two blocked corners);
- runs on cells labelled with the terrain, or on unlabelled free cells (ground no camera labelled
  or no sensor saw) for at most `max_gap` metres in all;
- is at most `max_length` metres long.

A path costs its length plus `OFF_TERRAIN_WEIGHT` times its length on unlabelled cells (so it
keeps to the terrain where it can); the link it yields costs the path's length (3D: with the
height difference of its two places), not the straight line's.

Candidates: pairs of places of one terrain in different pieces, at most `reach` metres apart (2D),
taken nearest first, one per pair of pieces; a pair is searched only while its pieces are not yet
joined (union-find), so n pieces cost at most n - 1 successful searches. Each search runs in the
window of cells that can hold a path of at most `max_length` metres between the pair (the box of
the ellipse around it), from every place of one piece in the window to every place of the other:
its cost does not grow with the map, and it reads only the whole grid's arrays, so a tiled build
gives the same links as a one-piece build.

Positions are (P, 3) metres in the map frame; the grid follows grid.py's convention.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.cluster.hierarchy import DisjointSet
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

OFF_TERRAIN_WEIGHT = 10.0
"""A metre on unlabelled cells costs 1 + this: a path keeps to its terrain unless the detour on it
is more than this many times longer."""

_STEPS = ((0, 1), (1, 0), (1, 1), (1, -1))
"""Half of the 8 neighbour offsets (row, col); each edge of the cell graph is built once."""


@dataclass(frozen=True)
class GridPathRules:
    """Where a grid link may run: label (H, W) terrain index per cell (-1 = none), blocked (H, W),
    origin (2,) metres (lower-left corner of cell (0, 0)), cell_size metres; max_gap and
    max_length metres (see the module docstring)."""

    label: np.ndarray
    blocked: np.ndarray
    origin: np.ndarray
    cell_size: float
    max_gap: float
    max_length: float


def terrain_pieces(terrain: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(P,) piece label of every place: connected components of the graph restricted to edges
    (E, 2) between two places of one terrain."""
    terrain = np.asarray(terrain)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    same = edges[terrain[edges[:, 0]] == terrain[edges[:, 1]]]
    P = len(terrain)
    graph = sp.coo_matrix((np.ones(len(same)), (same[:, 0], same[:, 1])), shape=(P, P))
    return connected_components(graph, directed=False)[1]


def candidate_pairs(
    position: np.ndarray, terrain: np.ndarray, piece: np.ndarray, reach: float, candidates: int
) -> np.ndarray:
    """(m, 2) place pairs (i < j) of one terrain in different pieces, at most `reach` metres apart
    (2D; each place with its `candidates` nearest of its terrain), one per pair of pieces (the
    nearest; ties: lowest indices), ordered by distance then indices."""
    out = []
    for t in np.unique(terrain):
        mine = np.flatnonzero(terrain == t)
        if len(np.unique(piece[mine])) < 2:
            continue
        k = min(candidates + 1, mine.size)
        dist, idx = cKDTree(position[mine, :2]).query(position[mine, :2], k=k, distance_upper_bound=reach)
        dist, idx = dist.reshape(len(mine), k), idx.reshape(len(mine), k)
        rows, cols = np.nonzero(np.isfinite(dist))
        a, b = mine[rows], mine[idx[rows, cols]]
        keep = piece[a] != piece[b]
        out.append(np.sort(np.column_stack([a[keep], b[keep]]), axis=1))
    if not out:
        return np.zeros((0, 2), dtype=np.int64)
    pairs = np.unique(np.vstack(out), axis=0)
    length = np.linalg.norm(position[pairs[:, 0], :2] - position[pairs[:, 1], :2], axis=1)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0], length))]
    # One pair per pair of pieces: the first (nearest) in that order.
    keys = np.sort(piece[pairs], axis=1)
    _, first = np.unique(keys, axis=0, return_index=True)
    return pairs[np.sort(first)].astype(np.int64)


def link_pieces_on_grid(
    position: np.ndarray,
    terrain: np.ndarray,
    edges: np.ndarray,
    rules: GridPathRules,
    reach: float,
    candidates: int = 8,
) -> tuple[np.ndarray, np.ndarray]:
    """Grid links (k, 2) (i < j, unique) between pieces of each terrain's places graph and their
    costs (k,) in metres: the grid path's length with the height difference of its places."""
    position = np.asarray(position, dtype=np.float64)
    terrain = np.asarray(terrain, dtype=np.int64)
    piece = terrain_pieces(terrain, edges)
    joined = DisjointSet(range(piece.max() + 1 if len(piece) else 0))
    found, cost = [], []
    for a, b in candidate_pairs(position, terrain, piece, reach, candidates):
        if joined.connected(int(piece[a]), int(piece[b])):
            continue
        path = _grid_path(position, terrain, piece, a, b, rules)
        if path is None:
            continue
        i, j, length = path
        joined.merge(int(piece[a]), int(piece[b]))
        found.append((min(i, j), max(i, j)))
        cost.append(float(np.hypot(length, position[i, 2] - position[j, 2])))
    if not found:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    return np.asarray(found, dtype=np.int64), np.asarray(cost)


def _grid_path(
    position: np.ndarray, terrain: np.ndarray, piece: np.ndarray, a: int, b: int, rules: GridPathRules
) -> tuple[int, int, float] | None:
    """The cheapest allowed grid path from a place of a's piece to one of b's piece, in the window
    around a and b: (its first place, its last place, its length in metres), or None."""
    s = rules.cell_size
    H, W = rules.label.shape
    pa, pb = position[a, :2], position[b, :2]
    grow = max(rules.max_length - float(np.linalg.norm(pb - pa)), 0.0) / 2
    lo = np.floor((np.minimum(pa, pb) - grow - rules.origin) / s).astype(np.int64) - 1  # (col, row)
    hi = np.floor((np.maximum(pa, pb) + grow - rules.origin) / s).astype(np.int64) + 2
    c0, r0 = max(int(lo[0]), 0), max(int(lo[1]), 0)
    c1, r1 = min(int(hi[0]), W), min(int(hi[1]), H)
    label = rules.label[r0:r1, c0:c1]
    t = terrain[a]
    on = label == t
    free = on | ((label < 0) & ~rules.blocked[r0:r1, c0:c1])
    ends = _places_in_window(position, terrain, piece, (piece[a], piece[b]), t, rules.origin, s, (r0, c0), free.shape)
    if ends is None:
        return None
    (src_place, src_cell), (dst_place, dst_cell) = ends
    free[np.unravel_index(np.concatenate([src_cell, dst_cell]), free.shape)] = True  # places sit on their mask
    graph, step_len, step_off = _cell_graph(free, ~on, s)
    limit = rules.max_length + OFF_TERRAIN_WEIGHT * rules.max_gap
    dist, pred, _ = dijkstra(graph, indices=np.unique(src_cell), min_only=True, return_predecessors=True, limit=limit)
    reached = np.isfinite(dist[dst_cell])
    if not reached.any():
        return None
    # Cheapest target; ties: lowest place index (targets are sorted by place index).
    best = np.flatnonzero(reached)[np.argmin(dist[dst_cell[reached]])]
    length, off, cell = 0.0, 0.0, int(dst_cell[best])
    while pred[cell] >= 0:
        prev = int(pred[cell])
        length += step_len[prev, cell]
        off += step_off[prev, cell]
        cell = prev
    if off > rules.max_gap + 1e-9 or length > rules.max_length + 1e-9:
        return None
    first = src_place[np.flatnonzero(src_cell == cell)[0]]
    return int(first), int(dst_place[best]), float(length)


def _places_in_window(
    position: np.ndarray,
    terrain: np.ndarray,
    piece: np.ndarray,
    pieces: tuple[int, int],
    t: int,
    origin: np.ndarray,
    s: float,
    corner: tuple[int, int],
    shape: tuple[int, int],
):
    """((places, flat cells) of the first piece, (places, flat cells) of the second) inside the
    window (cells from `corner` (row, col), `shape`), places by increasing index; None when a
    piece has none there."""
    out = []
    for k in pieces:
        mine = np.flatnonzero((terrain == t) & (piece == k))
        rc = np.floor((position[mine, :2] - origin) / s).astype(np.int64)
        rows, cols = rc[:, 1] - corner[0], rc[:, 0] - corner[1]
        inside = (rows >= 0) & (rows < shape[0]) & (cols >= 0) & (cols < shape[1])
        if not inside.any():
            return None
        out.append((mine[inside], rows[inside] * shape[1] + cols[inside]))
    return tuple(out)


def _cell_graph(free: np.ndarray, off: np.ndarray, s: float) -> tuple[sp.csr_matrix, sp.csr_matrix, sp.csr_matrix]:
    """Symmetric 8-connected graphs over the free cells (h, w) (flat indices): the cost of each step
    (its length plus OFF_TERRAIN_WEIGHT times its length on `off` cells, half a step per end cell),
    its length and its length on `off` cells (metres)."""
    h, w = free.shape
    rows, cols, lengths, offs = [], [], [], []
    index = np.arange(h * w).reshape(h, w)
    for dr, dc in _STEPS:
        r_lo, r_hi = 0, h - dr
        c_lo, c_hi = max(0, -dc), w - max(0, dc)
        if r_hi <= r_lo or c_hi <= c_lo:
            continue
        src = (slice(r_lo, r_hi), slice(c_lo, c_hi))
        dst = (slice(r_lo + dr, r_hi + dr), slice(c_lo + dc, c_hi + dc))
        ok = free[src] & free[dst]
        if dr and dc:  # a diagonal step needs both cells beside it free
            ok &= free[r_lo + dr : r_hi + dr, c_lo:c_hi] & free[r_lo:r_hi, c_lo + dc : c_hi + dc]
        step = s * np.hypot(dr, dc)
        rows.append(index[src][ok])
        cols.append(index[dst][ok])
        lengths.append(np.full(int(ok.sum()), step))
        offs.append(step * 0.5 * (off[src][ok].astype(np.float64) + off[dst][ok]))
    r, c = np.concatenate(rows), np.concatenate(cols)
    length, off_len = np.concatenate(lengths), np.concatenate(offs)

    def symmetric(values: np.ndarray) -> sp.csr_matrix:
        return sp.csr_matrix(
            (np.concatenate([values, values]), (np.concatenate([r, c]), np.concatenate([c, r]))), shape=(h * w, h * w)
        )

    return symmetric(length + OFF_TERRAIN_WEIGHT * off_len), symmetric(length), symmetric(off_len)
