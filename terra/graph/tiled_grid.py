"""The terrain grid built tile by tile: the same labels and blocked cells as `build_terrain_grid`,
and the same ground wherever any stage reads it, with working memory set by the tile size.

Each core's window is built by `build_terrain_grid` itself, on the points inside the window and
in the window's frame (cells of the one-piece frame, so cell (r, c) is the same cell), and its core
is copied out. Why that is the one-piece result:
- Labels and blocked cells depend on points within `terrain_grid_reach` cells (support window,
  densely-scanned test, fill radius). Filters treat outside an array as empty: at a closed side
  (the grid's own edge) that is what the one-piece grid does too; at an open side the margin
  keeps the core out of reach. Points keep their order, so every per-cell sum adds the same
  numbers in the same order; window filters sum in float64 and round to float32, and their tests
  carry a 1e-6 tolerance far above the rounding difference between windows.
- Ground: a cell without terrain points takes the mean height of the nearest cell with some
  (nearest with the lowest (column, row) on ties, the EDT's rule, which does not depend on where
  the array starts). A window's frame keeps the one-piece origin and an integer offset, so points
  fall in the same cells to the last bit. If that distance in the window is below the cell's gap to the unseen part
  (`Window.gap`), the nearest cells are the same. The check is required of every core cell that
  holds a point (their heights decide blocked cells and unlabelled ground) and of every cell
  within `read_radius` of a labelled cell (the places' heights); the window grows (doubling its
  margin) until it holds. Other cells' ground is read by no stage and may differ.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from terra.graph.gvd import EIGHT
from terra.graph.grid import GridFrame, TerrainGrid, build_terrain_grid, grid_frame, terrain_grid_reach
from terra.graph.tiling import Window, cores, window


def build_terrain_grid_tiled(
    points: np.ndarray,
    terrain: np.ndarray,
    cell_size: float = 0.4,
    obstacle_height: tuple[float, float] | None = (0.3, 2.0),
    obstacle_min_points: int = 2,
    support_radius: float = 1.6,
    min_support: float = 0.6,
    fill_radius: float = 0.0,
    tile: int = 512,
    margin: int = 64,
    read_radius: int = 2,
) -> TerrainGrid:
    """`build_terrain_grid(points (N, 3), terrain (N,), ...)` one core of `tile` x `tile` cells at a
    time (see the module docstring); margin: the first overlap tried, cells (at least the reach);
    read_radius: cells around labelled cells whose ground must be exact (the masks' closing)."""
    points = np.asarray(points)
    terrain = np.asarray(terrain)
    frame = grid_frame(points, terrain, cell_size)
    H, W = frame.shape
    grid = TerrainGrid(np.full((H, W), -1, np.int16), np.zeros((H, W), np.float32), np.zeros((H, W), bool),
                       np.asarray(frame.origin, dtype=np.float64), frame.cell_size)
    margin = max(margin, terrain_grid_reach(cell_size, support_radius, fill_radius))
    index = _PointIndex(points, frame)
    for core in cores((H, W), tile):
        m = margin
        while True:
            win = window((H, W), core, m)
            rows = index.inside(win)
            if not (terrain[rows] >= 0).any():
                if win.whole or not index.inside(window((H, W), core, 0)).size:
                    break  # no point in the core and no terrain point in reach: it stays -1, 0, False
                m *= 2
                continue
            # The cheap part of the ground check first (cells holding points), then the whole grid.
            if not win.whole and not _ground_proven(None, points[rows], terrain[rows], win, frame, read_radius):
                m *= 2
                continue
            part = build_terrain_grid(points[rows], terrain[rows], cell_size, obstacle_height, obstacle_min_points, support_radius,
                                      min_support, fill_radius=fill_radius, frame=frame.window(win.rows, win.cols))
            if win.whole or _ground_proven(part, points[rows], terrain[rows], win, frame, read_radius):
                grid.label[core], grid.ground[core], grid.blocked[core] = (a[win.core] for a in (part.label, part.ground, part.blocked))
                break
            m *= 2
    return grid


class _PointIndex:
    """Points sorted by grid row, to find those inside a window without scanning them all."""

    def __init__(self, points: np.ndarray, frame: GridFrame, chunk: int = 1 << 20) -> None:
        # 12 bytes a point (int32 cells, int32 order), computed in chunks: no float64 copy of the map.
        n = len(points)
        self.row, self.col = np.empty(n, dtype=np.int32), np.empty(n, dtype=np.int32)
        origin = np.asarray(frame.origin, dtype=np.float64)
        for start in range(0, n, chunk):
            xy = np.asarray(points[start : start + chunk, :2], dtype=np.float64)
            cell = np.floor((xy - origin) / frame.cell_size)  # as TerrainGrid.cell_of
            self.row[start : start + chunk] = np.clip(cell[:, 1], -1, frame.shape[0])
            self.col[start : start + chunk] = np.clip(cell[:, 0], -1, frame.shape[1])
        self.order = np.argsort(self.row, kind="stable").astype(np.int32)
        self.sorted_row = self.row[self.order]

    def inside(self, win: Window) -> np.ndarray:
        """Indices (increasing: the points' own order) of the points in the window's cells; the
        outermost windows take the points beyond the grid too, as the one-piece grid does."""
        lo = -1 if win.rows.start == 0 else win.rows.start  # rows are clipped to -1..H
        hi = np.iinfo(np.int32).max if win.closed[1] else win.rows.stop
        a, b = np.searchsorted(self.sorted_row, np.array([lo, hi], dtype=np.int32), side="left")
        rows = self.order[a:b]
        col = self.col[rows]
        keep = np.ones(len(rows), dtype=bool)
        if not win.closed[2]:
            keep &= col >= win.cols.start
        if not win.closed[3]:
            keep &= col < win.cols.stop
        return np.sort(rows[keep])


def _ground_proven(part: TerrainGrid | None, points: np.ndarray, terrain: np.ndarray, win: Window, frame: GridFrame,
                   read_radius: int) -> bool:
    """Whether the ground of every core cell that matters is the one-piece ground: its nearest cell
    with terrain points lies closer than the unseen part of the grid. The cells that matter: those
    holding points, and (with the window's grid `part`) those within `read_radius` of a labelled cell."""
    h, w = win.shape
    cells = TerrainGrid(np.zeros((0, 0), np.int16), np.zeros((0, 0), np.float32), np.zeros((0, 0), bool),
                        np.asarray(frame.origin, dtype=np.float64), frame.cell_size, frame.window(win.rows, win.cols).offset)
    rc = np.floor((points[:, :2] - cells.origin) / cells.cell_size).astype(np.int64)
    rows, cols = rc[:, 1] - cells.offset[0], rc[:, 0] - cells.offset[1]
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    has = np.zeros((h, w), dtype=bool)
    has[rows[inside & (terrain >= 0)], cols[inside & (terrain >= 0)]] = True
    needed = np.zeros((h, w), dtype=bool)
    needed[rows[inside], cols[inside]] = True
    if part is not None and read_radius > 0 and (part.label >= 0).any():
        needed |= ndimage.binary_dilation(part.label >= 0, EIGHT, iterations=read_radius)
    needed &= ~has
    core = needed[win.core]
    if not core.any():
        return True
    if not has.any():
        return False
    distance = ndimage.distance_transform_edt(~has)
    return bool((distance[win.core][core] < win.gap()[win.core][core]).all())
