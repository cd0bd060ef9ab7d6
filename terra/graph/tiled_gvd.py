"""The GVD of one terrain computed tile by tile: the same cells and distances as `gvd(free)`.

`tiled_gvd` runs the steps of terra.graph.gvd (brushfire, Voronoi test, thinning, filling empty
loops, thinning) in the window of each core (terra.graph.tiling), keeps the core, and grows the
window (doubling its margin) until every core cell is proven to be as in one piece. The proof, step
by step, with d(x) the distance of cell x to its nearest obstacle and g(x) its gap (how far the
unseen part of the grid is, `Window.gap`):

1. Brushfire. The obstacle mask is exact everywhere in the window (it is read from the whole
   mask); obstacle components come from the whole mask (`obstacle_components`). Beyond an open side
   the window assumes no obstacle, so its distance d'(x) >= d(x); if d'(x) < g(x), every obstacle
   within d'(x) lies in the window, hence d'(x) = d(x) and the nearest obstacles are the same set,
   and the parent (the nearest obstacle with the lowest (column, row)) is the same.
2. Voronoi test at x uses x, its 4-neighbours y (d(y) <= d(x) + 1) and the clearance at the
   midpoint m of their parents (|m - x| <= d(x) + 2, d'(m) <= d(x) + 2.5). All are exact when
   2 d'(x) + 6 < g(x); obstacle cells are never marked. Call the cells where this holds E0.
3. Thinning (Guo-Hall) reads 3 x 3 neighbourhoods, 2 sub-iterations per iteration: after i
   iterations the window and the whole grid agree on the cells farther than 2i (chessboard) from
   any cell outside E0. If every window stops within N iterations and every core is farther than
   2N from the outside of its E0, the whole grid also stops within N (on every core it repeats the
   window's last, unchanged, iteration) and agrees with the windows on the cores. N (`rounds`) is
   checked per window; a window that needs more restarts the terrain with more.
4. Filling empty loops: a hole of the thin skeleton is filled when it holds no obstacle and does
   not touch the grid's edge. Let E1 be E0 shrunk by 2N. For a cell x off the skeleton in E1, the
   4-connected part P of E1's off-skeleton cells around x lies in the true hole and in the
   window's hole: if P holds an obstacle, neither is filled; if P touches nothing outside E1, it
   is the whole hole in both. Otherwise x is unsure.
5. Thinning again: as in 3, from E1 without the unsure cells.

So a core is proven when all its cells lie farther than 2N from the outside of E1 and from every
unsure cell. Distances in the core then also satisfy d' < g (step 1). A window that covers the
whole grid is always proven. The one-piece `gvd` works on the bounding box of the free cells; that
is the same as the whole grid with the obstacle frame around it (outside the box everything is
obstacle, connected to the frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from terra.graph import raster
from terra.graph.gvd import brushfire, empty_loops, free_box, label_components, voronoi_cells
from terra.graph.thinning import thin_counted
from terra.graph.tiling import Window, cores, window


@dataclass
class TiledGvdStats:
    """What the tiling cost: windows computed (growths included), the largest margin used
    (cells), and the thinning rounds N the proof needed."""

    windows: int = 0
    max_margin: int = 0
    rounds: int = 0


class _NeedMoreRounds(Exception):
    def __init__(self, rounds: int) -> None:
        super().__init__(rounds)
        self.rounds = rounds


def obstacle_components(free: np.ndarray) -> np.ndarray:
    """(H + 2, W + 2) uint16 (int32 when there are 65,535 components or more): 8-connected
    components of the obstacle cells of `free` (H, W) with the one-cell obstacle frame around it
    (as gvd.brushfire labels them), frame included. The same labels in either type; the narrower
    one halves the array that stays in memory while the terrain's windows are computed."""
    return label_components(np.pad(~np.asarray(free, dtype=bool), 1, constant_values=True))[0]


def tiled_gvd(
    free: np.ndarray,
    min_clearance: float = 1.0,
    min_gap: float = 1.5,
    tile: int = 512,
    margin: int = 128,
    rounds: int = 4,
    stats: TiledGvdStats | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """`gvd(free, min_clearance, min_gap)` computed core by core: ((H, W) bool skeleton,
    (H, W) float32 distance in cells), equal to the one-piece result (see the module docstring).
    tile, margin: cells; rounds: the thinning iterations N assumed at first."""
    free = np.asarray(free, dtype=bool)
    stats = stats if stats is not None else TiledGvdStats()
    while True:
        try:
            return _tiled_gvd(free, min_clearance, min_gap, tile, margin, rounds, stats)
        except _NeedMoreRounds as more:
            rounds = max(2 * rounds, more.rounds)


def _tiled_gvd(
    free: np.ndarray, min_clearance: float, min_gap: float, tile: int, margin: int, rounds: int, stats: TiledGvdStats
) -> tuple[np.ndarray, np.ndarray]:
    skeleton = np.zeros(free.shape, dtype=bool)
    distance = np.zeros(free.shape, dtype=np.float32)
    box = free_box(free)  # as gvd() does: only the bounding box of the free cells, plus one cell, framed
    if box is None:
        return skeleton, distance
    sub = free[box]
    labels = obstacle_components(sub)
    stats.rounds = rounds
    for core in cores(sub.shape, tile):
        if not sub[core].any():  # skeleton cells are free cells; obstacles have distance 0
            continue
        m = margin
        while True:
            win = window(sub.shape, core, m)
            stats.windows += 1
            stats.max_margin = max(stats.max_margin, m)
            result = window_gvd(sub, labels, win, min_clearance, min_gap, rounds)
            if result is not None:
                break
            m *= 2
        skeleton[box][core], distance[box][core] = result
    return skeleton, distance


def window_gvd(
    free: np.ndarray, labels: np.ndarray, win: Window, min_clearance: float, min_gap: float, rounds: int
) -> tuple[np.ndarray, np.ndarray] | None:
    """The GVD skeleton and distance of `win`'s core, computed in the window, or None when the
    window is too small to prove them (see the module docstring). Raises _NeedMoreRounds when a
    thinning needs more than `rounds` iterations."""
    fw = free[win.rows, win.cols]
    if fw.all() and not any(win.closed):
        return None  # no obstacle in sight: every distance is unknown
    lw = labels[win.rows.start : win.rows.stop + 2, win.cols.start : win.cols.stop + 2]
    fire = brushfire(fw, win.closed, lw)
    marked = voronoi_cells(fw, fire, min_clearance, min_gap)
    gap = win.gap()
    core = win.core
    # Step 2: where the marks are exact; cells too near the unseen part fail early, cheaply.
    sure0 = ~fw | (2.0 * fire.distance + 6.0 < gap)
    if not win.whole and not _proven(win.clearance(~sure0)[core], 4 * rounds):
        return None
    thin1, n1 = thin_counted(marked)
    fill = empty_loops(thin1, fw)
    thin2, n2 = thin_counted(thin1 | fill) if fill.any() else (thin1, 0)
    if max(n1, n2) > rounds:
        raise _NeedMoreRounds(max(n1, n2))
    if not win.whole:
        sure1 = win.clearance(~sure0) > 2 * rounds  # step 3
        unsure = ~sure1 | _unsure_holes(thin1, fw, sure1)  # step 4
        if not _proven(win.clearance(unsure)[core], 2 * rounds):  # step 5
            return None
    return thin2[core], fire.distance[core]


def _proven(clearance: np.ndarray, reach: int) -> bool:
    return bool((clearance > reach).all())


def _unsure_holes(skeleton: np.ndarray, free: np.ndarray, sure: np.ndarray) -> np.ndarray:
    """Cells of the 4-connected parts of the sure off-skeleton cells that hold no obstacle and
    touch an unsure cell (4-adjacent): whether their hole gets filled is not known here."""
    parts, n = raster.label(~skeleton & sure)
    if n == 0:
        return np.zeros(skeleton.shape, dtype=bool)
    has_obstacle = np.bincount(parts.ravel(), weights=~free.ravel(), minlength=n + 1) > 0
    edge = ndimage.binary_dilation(~sure, border_value=0)  # 4-neighbours of unsure cells
    touches = np.bincount(parts.ravel(), weights=edge.ravel(), minlength=n + 1) > 0
    bad = ~has_obstacle & touches
    bad[0] = False
    return bad[parts]
