"""The terrain grid built tile by tile: the same labels and blocked cells as `build_terrain_grid`,
and the same ground wherever any stage reads it, with working memory set by the tile size.

Each core's window is built by `build_terrain_grid` itself, on the points inside the window and
in the window's frame (cells of the one-piece frame, so cell (r, c) is the same cell), and its core
is copied out. Why that is the one-piece result:
- Labels and blocked cells depend on points within `terrain_grid_reach` cells (support window,
  densely-scanned test, the hysteresis chain of at most `hysteresis_steps` cells and the weak
  window at its end, fill radius), given the terrain-based ground of the cells there (below).
  Filters and dilations treat outside an array as empty: at a closed side (the grid's own edge)
  that is what the one-piece grid does too; at an open side the margin keeps the core out of
  reach. Points keep their order, so every per-cell sum adds the same numbers in the same order;
  window filters sum in float64 and round to float32, and their tests carry a 1e-6 tolerance far
  above the rounding difference between windows. An unbounded hysteresis (`weak_reach` None)
  has no reach: a label can depend on cells across the whole map, so that grid is built in one
  piece (`TiledGridStats.one_piece` says why).
- Terrain-based ground: a cell without terrain points first takes the mean height of the nearest
  cell with some (nearest with the lowest (column, row) on ties, the EDT's rule, which does not
  depend on where the array starts). A window's frame keeps the one-piece origin and an integer
  offset, so points fall in the same cells to the last bit. If that distance in the window is
  below the cell's gap to the unseen part (`Window.gap`), the nearest cells are the same. The
  heights of a cell's other points above it decide whether the cell is blocked and whether it
  holds unlabelled ground, and so the labels within reach: the check is required of every cell
  holding only other points within the reach of the core.
- Final ground: cells holding unlabelled ground (and no terrain point) take those points' mean
  height, then every cell without either takes the nearest cell with either. A cell's own
  terrain distance E (to its nearest cell with terrain points) bounds that search; if E is below
  its gap, and no cell within E holds other points whose terrain-based ground is unproven (which
  could turn unlabelled ground on or off), every candidate within E is known exactly and the
  nearest one is the one-piece one. The check is required of every core cell within
  `read_radius` of a labelled cell (the places' heights); no other stage reads the final ground.
The window grows (doubling its margin) until both checks hold.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from terra.graph import raster
from terra.graph.grid import (
    OBSTACLE_BAND,
    OBSTACLE_MIN_POINTS,
    GridFrame,
    TerrainGrid,
    build_terrain_grid,
    empty_grid,
    grid_frame,
    hysteresis_steps,
    terrain_grid_reach,
)
from terra.graph.tiling import Window, cores, window


@dataclass
class TiledGridStats:
    """What a tiled terrain grid build did: windows built, the widest margin (cells) a core needed,
    and, when the grid had to be built in one piece, why (None when it was tiled)."""

    windows: int = 0
    max_margin: int = 0
    one_piece: str | None = None


def build_terrain_grid_tiled(
    points: np.ndarray,
    terrain: np.ndarray,
    cell_size: float = 0.4,
    obstacle_height: tuple[float, float] | None = OBSTACLE_BAND,
    obstacle_min_points: int = OBSTACLE_MIN_POINTS,
    support_radius: float = 1.6,
    min_support: float = 0.6,
    fill_radius: float = 0.0,
    weak_support: float | None = None,
    weak_reach: float | None = None,
    support_cell: float | None = None,
    tile: int = 512,
    margin: int = 64,
    read_radius: int = 2,
    stats: TiledGridStats | None = None,
    frame: GridFrame | None = None,
) -> TerrainGrid:
    """`build_terrain_grid(points (N, 3), terrain (N,), ...)` one core of `tile` x `tile` cells at a
    time (see the module docstring); margin: the first overlap tried, cells (at least the reach);
    read_radius: cells around labelled cells whose ground must be exact (the masks' closing);
    frame: `grid_frame` of the points, when the caller has it already.
    With an unbounded hysteresis (weak_reach None) the grid is built in one piece (stats says so)."""
    points = np.asarray(points)
    terrain = np.asarray(terrain)
    stats = stats if stats is not None else TiledGridStats()
    args = (cell_size, obstacle_height, obstacle_min_points, support_radius, min_support)
    weak = {
        "fill_radius": fill_radius,
        "weak_support": weak_support,
        "weak_reach": weak_reach,
        "support_cell": support_cell,
    }
    frame = frame or grid_frame(points, terrain, cell_size)
    chain = hysteresis_steps(cell_size, support_radius, min_support, weak_support, weak_reach)
    if chain is None:
        stats.one_piece = "build.grid.weak_reach is null: the hysteresis can carry a class across the whole map"
        return build_terrain_grid(points, terrain, *args, **weak, frame=frame)
    index = _PointIndex(points, frame)  # before the grid: its sorting temporaries come and go first
    grid = empty_grid(frame)

    def build(rows: np.ndarray, part: GridFrame) -> TerrainGrid:
        return build_terrain_grid(points[rows], terrain[rows], *args, **weak, frame=part)

    reach = terrain_grid_reach(cell_size, support_radius, fill_radius, chain, support_cell)
    builder = _CoreBuilder(points, terrain, index, frame, reach, read_radius, build, stats)
    for core in cores(frame.shape, tile):
        builder.fill(grid, core, max(margin, reach))
    return grid


@dataclass
class _CoreBuilder:
    """Builds the tiled grid one core at a time (module docstring): the points (N, 3) and their
    classes (N,) with their row index, the one-piece frame, the reach of the labels and the
    read radius of the ground check (cells), and `build(rows, frame)`, the one-piece build of
    the points `rows` in a window's frame."""

    points: np.ndarray
    terrain: np.ndarray
    index: _PointIndex
    frame: GridFrame
    reach: int
    read_radius: int
    build: Callable[[np.ndarray, GridFrame], TerrainGrid]
    stats: TiledGridStats

    def fill(self, grid: TerrainGrid, core: tuple[slice, slice], margin: int) -> None:
        """In place: the labels, ground and blocked flags of `core` in `grid`, from a window whose
        margin doubles, from `margin` cells, until its core is proven the one-piece result."""
        shape = self.frame.shape
        m = margin
        while True:
            win = window(shape, core, m)
            rows = self.index.inside(win)
            if not (self.terrain[rows] >= 0).any():
                if win.whole or not self.index.inside(window(shape, core, 0)).size:
                    return  # no point in the core and no terrain point in reach: it stays -1, 0, False
                m *= 2
                continue
            # The cheap part of the ground check first (cells holding points), then the whole grid.
            if not (win.whole or self._ground_proven(None, rows, win)):
                m *= 2
                continue
            part = self.build(rows, self.frame.window(win.rows, win.cols))
            self.stats.windows += 1
            if win.whole or self._ground_proven(part, rows, win):
                for name in ("label", "ground", "blocked"):
                    getattr(grid, name)[core] = getattr(part, name)[win.core]
                self.stats.max_margin = max(self.stats.max_margin, m)
                return
            m *= 2

    def _ground_proven(self, part: TerrainGrid | None, rows: np.ndarray, win: Window) -> bool:
        # The points are taken per call, as the build takes its own: no copy outlives its check.
        return _ground_proven(
            part, self.points[rows], self.terrain[rows], win, self.frame, self.read_radius, self.reach
        )


class _PointIndex:
    """Points sorted by grid row, to find those inside a window without scanning them all."""

    def __init__(self, points: np.ndarray, frame: GridFrame, chunk: int = 1 << 20) -> None:
        # 8 bytes a point where the grid has fewer than 32,767 rows and columns (int16 cells, int32
        # order), computed in chunks: no float64 copy of the map.
        n = len(points)
        cell = np.int16 if max(frame.shape) + 1 < np.iinfo(np.int16).max else np.int32
        row, col = np.empty(n, dtype=cell), np.empty(n, dtype=cell)
        origin = np.asarray(frame.origin, dtype=np.float64)
        for start in range(0, n, chunk):
            xy = np.asarray(points[start : start + chunk, :2], dtype=np.float64)
            rc = np.floor((xy - origin) / frame.cell_size)  # as TerrainGrid.cell_of
            row[start : start + chunk] = np.clip(rc[:, 1], -1, frame.shape[0])
            col[start : start + chunk] = np.clip(rc[:, 0], -1, frame.shape[1])
        self.order = np.argsort(row, kind="stable").astype(np.int32)
        self.sorted_row = row[self.order]
        del row
        self.sorted_col = col[self.order]
        self.rows = frame.shape[0]

    def inside(self, win: Window) -> np.ndarray:
        """Indices (increasing: the points' own order) of the points in the window's cells; the
        outermost windows take the points beyond the grid too, as the one-piece grid does."""
        lo = -1 if win.rows.start == 0 else win.rows.start  # rows are clipped to -1..H
        hi = self.rows + 1 if win.closed[1] else win.rows.stop
        a, b = np.searchsorted(self.sorted_row, np.array([lo, hi], dtype=self.sorted_row.dtype), side="left")
        rows = self.order[a:b]
        col = self.sorted_col[a:b]
        keep = np.ones(len(rows), dtype=bool)
        if not win.closed[2]:
            keep &= col >= win.cols.start
        if not win.closed[3]:
            keep &= col < win.cols.stop
        return np.sort(rows[keep])


def _ground_proven(
    part: TerrainGrid | None,
    points: np.ndarray,
    terrain: np.ndarray,
    win: Window,
    frame: GridFrame,
    read_radius: int,
    reach: int,
) -> bool:
    """Whether the ground every stage reads in the core is the one-piece ground (module docstring):
    the terrain-based ground of the cells within `reach` of the core that hold only other points,
    and (with the window's grid `part`) the final ground of the core cells within `read_radius`
    of a labelled cell."""
    h, w = win.shape
    cells = TerrainGrid(
        np.zeros((0, 0), np.int16),
        np.zeros((0, 0), np.float32),
        np.zeros((0, 0), bool),
        np.asarray(frame.origin, dtype=np.float64),
        frame.cell_size,
        frame.window(win.rows, win.cols).offset,
    )
    rc = np.floor((points[:, :2] - cells.origin) / cells.cell_size).astype(np.int64)
    rows, cols = rc[:, 1] - cells.offset[0], rc[:, 0] - cells.offset[1]
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    has = np.zeros((h, w), dtype=bool)
    has[rows[inside & (terrain >= 0)], cols[inside & (terrain >= 0)]] = True
    other = np.zeros((h, w), dtype=bool)
    other[rows[inside & (terrain < 0)], cols[inside & (terrain < 0)]] = True
    other &= ~has  # a cell with terrain points has its own ground
    gap = win.gap()
    distance = raster.distance_to_zero(~has) if has.any() else np.full((h, w), np.inf)
    unsure = other & ~(distance < gap)  # terrain-based ground may differ: unlabelled ground and blocked flags too
    near = (
        slice(max(win.core[0].start - reach, 0), win.core[0].stop + reach),
        slice(max(win.core[1].start - reach, 0), win.core[1].stop + reach),
    )
    if unsure[near].any():
        return False
    if part is None or read_radius <= 0 or not (part.label >= 0).any():
        return True
    needed = raster.grown(part.label >= 0, read_radius) & ~has
    core = needed[win.core]
    if not core.any():
        return True
    bound = np.minimum(gap, raster.distance_to_zero(~unsure)) if unsure.any() else gap
    return bool((distance[win.core][core] < bound[win.core][core]).all())
