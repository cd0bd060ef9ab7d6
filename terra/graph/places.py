"""Place nodes of one terrain: GVD -> pruned skeleton graph -> paths split by the paper's rule.

A GVD path between two nodes is split at its point of largest deviation from the chord while that
deviation exceeds `max_deviation`, otherwise at its arc-length midpoint while the chord is longer
than `max_distance` (the reference's max_deviation / max_distance rule). A chord that crosses an
obstacle cell is split at its point of largest deviation too, whatever the deviation: a place edge
is the straight segment a robot drives, and the GVD that curves around a bench or a building's
corner within 3.75 m of its chord gave edges through them (on the simulated small site, 15 edges
the wheelchair could take ran through picnic tables, benches, a bicycle rack and a building).
Every patch of the terrain that has no GVD node gets one place at its cell of largest clearance,
so no patch is dropped silently.

Two rules keep the places where the terrain is:
- Pockets: spur pruning removes the short GVD branches that run into corners, but also the branch
  into a pocket of the terrain (a service pad off a driveway, a plaza at the end of a walk). A
  pruned branch that reaches farther than `cover_radius` from the kept GVD is restored (farthest
  first, only its path back to the kept GVD), so such a pocket gets a place and the rest stays
  sparse.
- Pieces: where the GVD of one connected patch falls apart (a neck narrower than the minimum
  clearance), its pieces are joined along the shortest path through the patch, so places on one
  patch are always connected on that terrain.

Everything here is in grid cells; the caller converts to metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy import ndimage
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

from terra.graph import raster
from terra.graph.cell_index import CellIndex
from terra.graph.gvd import EIGHT, gvd, label_components
from terra.graph.skeleton import (
    SkeletonGraph,
    cell_adjacency,
    prune_spurs,
    simplify,
    skeleton_adjacency,
    skeleton_graph,
)


@dataclass
class CellPlaces:
    """cells: (n, 2) row/col of each place. edges: (e, 2) place pairs (i < j, unique).
    length: (e,) GVD path length between them, cells. clearance: (n,) cells."""

    cells: np.ndarray
    edges: np.ndarray
    length: np.ndarray
    clearance: np.ndarray


def split_path(
    path: np.ndarray, max_deviation: float, max_distance: float, obstacles: np.ndarray | None = None
) -> list[int]:
    """Indices (sorted, excluding both ends) where a polyline of cells (k, 2) (row, col) is split;
    `obstacles` (H, W) bool: cells no chord may cross (module docstring)."""
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
        if dev.max() > max_deviation or (obstacles is not None and chord_blocked(obstacles, a, b)):
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


def chord_blocked(obstacles: np.ndarray, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether the straight segment between cell centres a and b (2,) (row, col) passes an
    `obstacles` (H, W) cell: sampled every quarter cell, each sample in the cell whose centre is
    nearest (outside the raster: no obstacle)."""
    n = max(int(np.ceil(4 * np.abs(b - a).max())), 1)
    cells = np.rint(a + (b - a) * (np.arange(n + 1) / n)[:, None]).astype(np.int64)
    inside = (cells >= 0).all(axis=1) & (cells[:, 0] < obstacles.shape[0]) & (cells[:, 1] < obstacles.shape[1])
    return bool(obstacles[cells[inside, 0], cells[inside, 1]].any())


def split_graph(
    g: SkeletonGraph, max_deviation: float, max_distance: float, obstacles: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cells (n, 2), edges (e, 2), lengths (e,)) after splitting every path (`split_path`, no
    chord across an `obstacles` (H, W) cell); the first nodes are g's own. Loops shorter than the
    split thresholds vanish; parallel edges keep the shortest."""
    cells = [g.node_cell]
    n = len(g.node_cell)
    edges, lengths = [], []
    for e, (u, v) in enumerate(g.edges):
        path = g.path(e)
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path.astype(np.float64), axis=0), axis=1))])
        cuts = split_path(path, max_deviation, max_distance, obstacles)
        ids = [int(u)] + list(range(n, n + len(cuts))) + [int(v)]
        if cuts:
            cells.append(path[cuts])
            n += len(cuts)
        at = [0] + cuts + [len(path) - 1]
        for k in range(len(ids) - 1):
            edges.append((ids[k], ids[k + 1]))
            lengths.append(arc[at[k + 1]] - arc[at[k]])
    cells_arr = np.vstack(cells).astype(np.int64)
    return cells_arr, *unique_edges(
        np.asarray(edges, dtype=np.int64).reshape(-1, 2), np.asarray(lengths, dtype=np.float64)
    )


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
    return np.sort(np.asarray(edges, dtype=np.int64).reshape(-1, 2), axis=1)[rows], np.asarray(
        weight, dtype=np.float64
    )[rows]


def extract_places(
    free: np.ndarray,
    min_clearance: float,
    min_gap: float,
    prune_ratio: float,
    prune_length: float,
    junction_merge: float,
    max_deviation: float,
    max_distance: float,
    cover_radius: float = np.inf,
    gvd_result: tuple[np.ndarray, np.ndarray] | None = None,
    obstacles: np.ndarray | None = None,
) -> CellPlaces:
    """Places and GVD edges of one terrain's free mask (H, W); every length here is in cells.
    gvd_result: `gvd(free, min_clearance, min_gap)` when already computed (by the tiled GVD);
    obstacles: (H, W) bool cells no edge's straight segment may cross (`split_path`)."""
    full, distance = gvd_result if gvd_result is not None else gvd(free, min_clearance, min_gap)
    skeleton = prune_spurs(full, distance, prune_ratio, prune_length)
    skeleton = restore_far_branches(full, skeleton, cover_radius)
    graph = simplify(skeleton_graph(skeleton, distance), distance, junction_merge)
    cells, edges, length = split_graph(graph, max_deviation, max_distance, obstacles)
    patches = label_components(free)  # 8-connected patches, labelled once for both steps
    cells = np.vstack([cells, _lonely_patch_cells(free, distance, cells, patches)])
    joins, join_length = join_patch_pieces(free, cells, edges, patches)
    del patches
    edges, length = unique_edges(np.vstack([edges, joins]), np.concatenate([length, join_length]))
    return CellPlaces(cells, edges, length, distance[cells[:, 0], cells[:, 1]].astype(np.float64))


def restore_far_branches(full: np.ndarray, kept: np.ndarray, radius: float) -> np.ndarray:
    """`kept` plus the pruned branches of `full` that reach farther than `radius` cells from it.

    Greedy, farthest first: the pruned cell farthest from the kept skeleton is joined back by its
    shortest path along `full`, distances are updated, and so on until every pruned cell lies
    within `radius` of the kept skeleton (or cannot reach it). Both are (H, W) bool, thin.
    """
    kept = np.array(kept, dtype=bool)
    if not np.isfinite(radius) or not kept.any():
        return kept
    cells, adjacency = skeleton_adjacency(full)
    on_kept = kept[cells[:, 0], cells[:, 1]]
    pruned = np.flatnonzero(~on_kept)
    if pruned.size == 0:
        return kept
    far = cKDTree(cells[on_kept]).query(cells[pruned])[0]
    while True:
        candidates = np.flatnonzero(far > radius)
        if candidates.size == 0:
            return kept
        tip = int(pruned[candidates[np.argmax(far[candidates])]])
        dist, pred = dijkstra(adjacency, directed=False, indices=tip, return_predecessors=True)
        reach = np.flatnonzero(on_kept & np.isfinite(dist))
        if reach.size == 0:  # a branch cut off from the kept skeleton: leave it
            far[candidates[np.argmax(far[candidates])]] = 0.0
            continue
        node, path = int(reach[np.argmin(dist[reach])]), []
        while node != tip:
            node = int(pred[node])
            path.append(node)
        path = np.asarray(path, dtype=np.int64)
        kept[cells[path, 0], cells[path, 1]] = True
        on_kept[path] = True
        far = np.minimum(far, cKDTree(cells[path]).query(cells[pruned])[0])


def join_patch_pieces(
    free: np.ndarray, cells: np.ndarray, edges: np.ndarray, patches: tuple[np.ndarray, int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Edges (k, 2) and their lengths (k,) in cells that join places of one 8-connected patch of
    `free` that the GVD edges leave in separate pieces, each along the shortest path through the
    patch (a minimum spanning tree over the pieces, from a geodesic Voronoi partition of the patch
    by its places). patches: `ndimage.label(free, EIGHT)` when already computed."""
    none = np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    n = len(cells)
    if n < 2:
        return none
    patch, _ = patches if patches is not None else raster.label(free, structure=EIGHT)
    place_patch = patch[cells[:, 0], cells[:, 1]]
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, piece = connected_components(graph, directed=False)
    split = [p for p in np.unique(place_patch) if p > 0 and len(np.unique(piece[place_patch == p])) > 1]
    pairs, lengths = [], []
    boxes = ndimage.find_objects(patch)
    for p in split:
        box = boxes[p - 1]  # the patch's bounding box: no full-grid mask per patch
        corner = np.array([box[0].start, box[1].start])
        a, b, length = _geodesic_joins(patch[box] == p, cells - corner, np.flatnonzero(place_patch == p), piece)
        pairs.append(np.column_stack([a, b]))
        lengths.append(length)
    if not pairs:
        return none
    return np.vstack(pairs).astype(np.int64), np.concatenate(lengths)


def _geodesic_joins(
    region: np.ndarray, cells: np.ndarray, places: np.ndarray, piece: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum spanning joins (place a, place b, length in cells) between the pieces of `places`
    inside one connected `region` (H, W) bool: every cell takes its geodesically nearest place;
    neighbouring cells owned by places of different pieces offer a join of d_a + step + d_b."""
    rows, cols = np.flatnonzero(region.any(axis=1)), np.flatnonzero(region.any(axis=0))  # its bounds, not its cells
    lo, hi = np.array([rows[0], cols[0]]), np.array([rows[-1], cols[-1]]) + 1
    sub = region[lo[0] : hi[0], lo[1] : hi[1]]
    region_cells, adjacency = cell_adjacency(sub)
    sources = CellIndex(region_cells, sub.shape).find(cells[places, 0] - lo[0], cells[places, 1] - lo[1])
    dist, _, origin = dijkstra(adjacency, directed=False, indices=sources, min_only=True, return_predecessors=True)
    owner = np.full(len(region_cells), -1, dtype=np.int64)
    owner[sources] = places
    owner = owner[origin]
    coo = sp.triu(adjacency).tocoo()
    del adjacency
    u, v, step = coo.row, coo.col, coo.data
    cross = np.flatnonzero(piece[owner[u]] != piece[owner[v]])  # only the pairs across pieces are kept
    u, v, step = u[cross], v[cross], step[cross]
    del coo
    a, b, cost = owner[u], owner[v], dist[u] + step + dist[v]
    # Kruskal over pieces: cheapest candidate first, ties by place indices.
    order = np.lexsort((b, a, cost))
    parent = {int(c): int(c) for c in np.unique(piece[places])}

    def root(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    out_a, out_b, out_len = [], [], []
    for i in order.tolist():
        ra, rb = root(int(piece[a[i]])), root(int(piece[b[i]]))
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
            out_a.append(int(a[i]))
            out_b.append(int(b[i]))
            out_len.append(float(cost[i]))
    return np.asarray(out_a, np.int64), np.asarray(out_b, np.int64), np.asarray(out_len)


def _lonely_patch_cells(
    free: np.ndarray, distance: np.ndarray, cells: np.ndarray, patches: tuple[np.ndarray, int] | None = None
) -> np.ndarray:
    """One cell (largest clearance) for every free patch that holds no place yet (patches:
    `ndimage.label(free, EIGHT)` when already computed)."""
    labels, n = patches if patches is not None else raster.label(free, structure=EIGHT)
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
