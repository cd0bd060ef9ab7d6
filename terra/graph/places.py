"""Place nodes of one terrain: GVD -> pruned skeleton graph -> paths split by the paper's rule.

A GVD path between two nodes is split at its point of largest deviation from the chord while that
deviation exceeds `max_deviation`, otherwise at its arc-length midpoint while the chord is longer
than `max_distance` (the reference's max_deviation / max_distance rule). Every patch of the
terrain that has no GVD node gets one place at its cell of largest clearance, so no patch is
dropped silently.

Everything here is in grid cells; the caller converts to metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from terra.graph.gvd import EIGHT, gvd
from terra.graph.skeleton import SkeletonGraph, prune_spurs, simplify, skeleton_graph


@dataclass
class CellPlaces:
    """cells: (n, 2) row/col of each place. edges: (e, 2) place pairs (i < j, unique).
    length: (e,) GVD path length between them, cells. clearance: (n,) cells."""

    cells: np.ndarray
    edges: np.ndarray
    length: np.ndarray
    clearance: np.ndarray


def split_path(path: np.ndarray, max_deviation: float, max_distance: float) -> list[int]:
    """Indices (sorted, excluding both ends) where a polyline of cells is split."""
    pts = np.asarray(path, dtype=np.float64)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    splits: list[int] = []
    stack = [(0, len(pts) - 1)]
    while stack:
        i0, i1 = stack.pop()
        if i1 - i0 < 2:
            continue
        a, b = pts[i0], pts[i1]
        inner = pts[i0 + 1 : i1]
        chord = b - a
        chord_len = float(np.hypot(*chord))
        if chord_len < 1e-9:
            dev = np.linalg.norm(inner - a, axis=1)
        else:
            dev = np.abs(chord[0] * (inner[:, 1] - a[1]) - chord[1] * (inner[:, 0] - a[0])) / chord_len
        if dev.max() > max_deviation:
            m = i0 + 1 + int(np.argmax(dev))
        elif chord_len > max_distance:
            mid = 0.5 * (arc[i0] + arc[i1])
            m = i0 + 1 + int(np.argmin(np.abs(arc[i0 + 1 : i1] - mid)))
        else:
            continue
        splits.append(m)
        stack.append((m, i1))
        stack.append((i0, m))
    return sorted(splits)


def split_graph(g: SkeletonGraph, max_deviation: float, max_distance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cells (n, 2), edges (e, 2), lengths (e,)) after splitting every path; the first nodes are
    g's own. Loops shorter than the split thresholds vanish; parallel edges keep the shortest."""
    cells = [g.node_cell]
    n = len(g.node_cell)
    edges, lengths = [], []
    for e, (u, v) in enumerate(g.edges):
        path = g.path(e)
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path.astype(np.float64), axis=0), axis=1))])
        cuts = split_path(path, max_deviation, max_distance)
        ids = [int(u)] + list(range(n, n + len(cuts))) + [int(v)]
        if cuts:
            cells.append(path[cuts])
            n += len(cuts)
        at = [0] + cuts + [len(path) - 1]
        for k in range(len(ids) - 1):
            edges.append((ids[k], ids[k + 1]))
            lengths.append(arc[at[k + 1]] - arc[at[k]])
    cells_arr = np.vstack(cells).astype(np.int64)
    return cells_arr, *unique_edges(np.asarray(edges, dtype=np.int64).reshape(-1, 2), np.asarray(lengths, dtype=np.float64))


def unique_edge_rows(edges: np.ndarray, weight: np.ndarray, tiebreak: np.ndarray | None = None) -> np.ndarray:
    """Rows to keep so that each unordered pair appears once (the lightest, then the lowest
    `tiebreak`), without self-loops, ordered by (min, max) endpoint."""
    pairs = np.sort(np.asarray(edges, dtype=np.int64).reshape(-1, 2), axis=1)
    tiebreak = np.zeros(len(pairs)) if tiebreak is None else tiebreak
    order = np.lexsort((tiebreak, weight, pairs[:, 1], pairs[:, 0]))
    order = order[pairs[order, 0] != pairs[order, 1]]
    first = np.ones(len(order), dtype=bool)
    first[1:] = np.any(pairs[order[1:]] != pairs[order[:-1]], axis=1)
    return order[first]


def unique_edges(edges: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edges as sorted pairs (i < j) without self-loops or duplicates (the lightest one kept),
    ordered by (i, j)."""
    rows = unique_edge_rows(edges, weight)
    return np.sort(np.asarray(edges, dtype=np.int64).reshape(-1, 2), axis=1)[rows], np.asarray(weight, dtype=np.float64)[rows]


def extract_places(
    free: np.ndarray,
    min_clearance: float,
    min_gap: float,
    prune_ratio: float,
    prune_length: float,
    junction_merge: float,
    max_deviation: float,
    max_distance: float,
) -> CellPlaces:
    """Places and GVD edges of one terrain's free mask (H, W); every length here is in cells."""
    skeleton, distance = gvd(free, min_clearance, min_gap)
    skeleton = prune_spurs(skeleton, distance, prune_ratio, prune_length)
    graph = simplify(skeleton_graph(skeleton, distance), distance, junction_merge)
    cells, edges, length = split_graph(graph, max_deviation, max_distance)
    cells = np.vstack([cells, _lonely_patch_cells(free, distance, cells)])
    return CellPlaces(cells, edges, length, distance[cells[:, 0], cells[:, 1]].astype(np.float64))


def _lonely_patch_cells(free: np.ndarray, distance: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """One cell (largest clearance) for every free patch that holds no place yet."""
    labels, n = ndimage.label(free, structure=EIGHT)
    if n == 0:
        return np.zeros((0, 2), dtype=np.int64)
    covered = np.zeros(n + 1, dtype=bool)
    covered[labels[cells[:, 0], cells[:, 1]]] = True
    missing = np.flatnonzero(~covered[1:]) + 1
    if missing.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    # Only the cells of the missing patches are sorted (ndimage.maximum_position sorts them all):
    # per patch, the largest clearance, ties to the first cell in raster order.
    is_missing = np.zeros(n + 1, dtype=bool)
    is_missing[missing] = True
    flat = np.flatnonzero(is_missing[labels.ravel()])
    patch = labels.ravel()[flat]
    order = np.lexsort((flat, -distance.ravel()[flat], patch))
    first = np.ones(len(order), dtype=bool)
    first[1:] = patch[order][1:] != patch[order][:-1]
    return np.column_stack(np.unravel_index(flat[order][first], labels.shape)).astype(np.int64)
