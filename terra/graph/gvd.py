"""Generalized Voronoi diagram of one terrain's free cells, with brushfire semantics, vectorized.

The brushfire of Lau et al. (2013), as Hydra adapts it for places, grows a distance field out of the
obstacles and records for every free cell its nearest obstacle cell ("parent"). A free cell lies on
the GVD where it and a 4-neighbour have parents that belong to different obstacle components, or to
one component but far apart: the two parents are not 8-adjacent and the free space between them is
not just a step of one digitised wall (their midpoint has clearance >= `min_gap`).
Here the whole brushfire is one exact Euclidean distance transform with nearest-obstacle indices
(scipy.ndimage.distance_transform_edt), the components come from ndimage.label, and the test runs
on whole shifted arrays; the two-cell-thick result is thinned to one cell by Guo-Hall thinning
(terra.graph.thinning; unlike Zhang-Suen skeletonization it keeps two-cell-thick diagonal bands).

Grid convention: a boolean (H, W) array, True = free (a cell of this terrain). Everything outside
the array counts as obstacle. Distances are in cells.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terra.graph import raster
from terra.graph.thinning import thin

EIGHT = np.ones((3, 3), dtype=bool)


@dataclass
class Brushfire:
    """distance: (H, W) float32 cells to the nearest obstacle (0 on obstacles). parent: (2, H, W)
    int32 row/col of that obstacle cell (-1 where there is no obstacle at all). component: (H, W)
    int32 label of the parent's 8-connected obstacle component (0 = the outside of the grid)."""

    distance: np.ndarray
    parent: np.ndarray
    component: np.ndarray


def brushfire(
    free: np.ndarray, closed: tuple[bool, bool, bool, bool] = (True, True, True, True), labels: np.ndarray | None = None
) -> Brushfire:
    """Distance field, nearest obstacle and its component for every cell of a free-space mask.

    Each cell's parent is the nearest obstacle cell, ties to the lowest (column, row): that is
    scipy's exact EDT (tests/graph/test_graph_tiling.py checks it against brute force), and it does not
    depend on where the array starts, which the tiled GVD relies on.

    For a window of a larger mask (terra.graph.tiled_gvd): `closed` says which sides (first row,
    last row, first column, last column) are the edge of the whole mask, beyond which lies the
    obstacle frame; beyond the other sides nothing is known and no obstacle is assumed.
    `labels` (H + 2, W + 2): the obstacle components of the whole mask over this window and the
    one-cell ring around it (the frame included), instead of components of the window alone.
    """
    free = np.asarray(free, dtype=bool)
    # A one-cell obstacle frame makes the outside an obstacle; it is labelled with the components
    # it touches, so a wall that reaches the border joins the outside component.
    padded = np.pad(free, 1, constant_values=False)
    top, bottom, left, right = (not side for side in closed)
    padded[0, :], padded[-1, :] = top, bottom
    padded[:, 0] = left
    padded[:, -1] = right
    if not all(closed):
        # A corner cell beyond a closed side is outside the whole mask: frame; beyond two open sides, unknown.
        padded[0, 0], padded[0, -1], padded[-1, 0], padded[-1, -1] = (
            top and left,
            top and right,
            bottom and left,
            bottom and right,
        )
    distance, parent = raster.distance_and_nearest_zero(padded)
    if labels is None:
        labels, _ = raster.label(~padded, structure=EIGHT)
    component = labels[parent[0], parent[1]]
    inner = (slice(1, -1), slice(1, -1))
    return Brushfire(
        distance=distance[inner].astype(np.float32),
        parent=(parent[:, 1:-1, 1:-1] - 1).astype(np.int32),
        component=component[inner].astype(np.int32),
    )


def voronoi_cells(free: np.ndarray, fire: Brushfire, min_clearance: float = 1.0, min_gap: float = 1.5) -> np.ndarray:
    """(H, W) bool: free cells with clearance >= `min_clearance` (cells) where a 4-neighbour's
    parent lies in another obstacle component, or in the same component but far apart: the two
    parents are not 8-adjacent and free space of clearance >= `min_gap` cells lies between them
    (at their midpoint). The midpoint test tells two walls of a corridor, or the two sides of a
    corner, from neighbouring steps of one digitised wall, whose midpoint lies on the wall."""
    free = np.asarray(free, dtype=bool)
    H, W = free.shape
    padded_distance = np.pad(fire.distance, 1)
    marked = np.zeros(free.shape, dtype=bool)
    for axis in (0, 1):
        n = free.shape[axis]
        a = [slice(None), slice(None)]
        b = [slice(None), slice(None)]
        a[axis], b[axis] = slice(0, n - 1), slice(1, n)
        a, b = tuple(a), tuple(b)
        ra, ca = fire.parent[0][a], fire.parent[1][a]
        rb, cb = fire.parent[0][b], fire.parent[1][b]
        chord2 = (ra - rb).astype(np.float32) ** 2 + (ca - cb).astype(np.float32) ** 2
        # Clearance at the parents' midpoint: the largest over the (up to four) cells that hold
        # it, so the test is mirror-symmetric (rounding one way made one side of a symmetric
        # corridor end pass and the other fail, bending the dead end off the centre line).
        # Parents may lie in the one-cell frame outside the grid (-1 or H / W): pad by one.
        mid = np.zeros(ra.shape, dtype=np.float32)
        for rr in ((ra + rb) // 2, (ra + rb + 1) // 2):
            for cc in ((ca + cb) // 2, (ca + cb + 1) // 2):
                np.maximum(mid, padded_distance[np.clip(rr + 1, 0, H + 1), np.clip(cc + 1, 0, W + 1)], out=mid)
        far = (chord2 > 2.0) & (mid >= min_gap)
        hit = free[a] & free[b] & ((fire.component[a] != fire.component[b]) | far)
        # Mark the cell of the pair nearer the true boundary between the parents (the one with
        # the larger clearance; both on ties), so odd-width corridors give their centre line.
        marked[a] |= hit & (fire.distance[a] >= fire.distance[b])
        marked[b] |= hit & (fire.distance[b] >= fire.distance[a])
    return marked & free & (fire.distance >= min_clearance)


def fill_empty_loops(skeleton: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Thin again after filling every hole of the skeleton that holds no obstacle cell.

    A GVD loop always encloses an obstacle; loops around free cells only are thinning artefacts
    where several GVD branches meet (e.g. in the middle of a room).
    """
    empty = empty_loops(skeleton, free)
    return thin(skeleton | empty) if empty.any() else skeleton


def empty_loops(skeleton: np.ndarray, free: np.ndarray) -> np.ndarray:
    """(H, W) bool: the cells of every hole of the skeleton (a 4-connected component of the cells
    off it) that holds no obstacle cell and does not touch the array's border."""
    holes, n = raster.label(~skeleton)  # 4-connected complement
    if n <= 1:
        return np.zeros(np.shape(skeleton), dtype=bool)
    has_obstacle = np.bincount(holes.ravel(), weights=~free.ravel(), minlength=n + 1) > 0
    touches_border = np.zeros(n + 1, dtype=bool)
    touches_border[np.concatenate([holes[0], holes[-1], holes[:, 0], holes[:, -1]])] = True
    empty = ~has_obstacle & ~touches_border
    empty[0] = False
    return empty[holes]


def label_components(mask: np.ndarray, structure: np.ndarray = EIGHT) -> tuple[np.ndarray, int]:
    """`ndimage.label(mask, structure)` in uint16 when the components fit (fewer than 65,536), else
    int32: the same labels, in half the memory on a full grid."""
    try:
        return raster.label(mask, structure=structure, output=np.uint16)
    except RuntimeError:  # scipy: "insufficient bit-depth in requested output type"
        return raster.label(mask, structure=structure, output=np.int32)


def component_sizes(labels: np.ndarray, n: int, rows: int = 256) -> np.ndarray:
    """(n + 1,) int64 cells per label of an (H, W) label array (0 = background), counted a few rows
    at a time: np.bincount would first copy the whole array to int64."""
    sizes = np.zeros(n + 1, dtype=np.int64)
    for start in range(0, labels.shape[0], rows):
        sizes += np.bincount(labels[start : start + rows].ravel(), minlength=n + 1)
    return sizes


def free_box(free: np.ndarray) -> tuple[slice, slice] | None:
    """The bounding box of the free cells of `free` (H, W) plus one cell on each side (clipped to
    the grid), as (row, column) slices; None when no cell is free."""
    rows, cols = np.flatnonzero(free.any(axis=1)), np.flatnonzero(free.any(axis=0))
    if rows.size == 0:
        return None
    return slice(max(rows[0] - 1, 0), rows[-1] + 2), slice(max(cols[0] - 1, 0), cols[-1] + 2)


def gvd(free: np.ndarray, min_clearance: float = 1.0, min_gap: float = 1.5) -> tuple[np.ndarray, np.ndarray]:
    """One-cell-thin GVD of a free mask and the distance field: ((H, W) bool, (H, W) float32 cells).

    Work is restricted to the bounding box of the free cells (plus a margin), so a terrain that
    covers a small part of a large grid costs little.
    """
    free = np.asarray(free, dtype=bool)
    skeleton = np.zeros(free.shape, dtype=bool)
    distance = np.zeros(free.shape, dtype=np.float32)
    box = free_box(free)
    if box is None:
        return skeleton, distance
    sub = free[box]
    fire = brushfire(sub)
    marked = voronoi_cells(sub, fire, min_clearance, min_gap)
    skeleton[box] = fill_empty_loops(thin(marked), sub)
    distance[box] = fire.distance
    return skeleton, distance
