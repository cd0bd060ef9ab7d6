"""Tiles of a grid: square cores that partition it, and windows (a core plus an overlap) to compute
them in, with what a window can and cannot know about the rest of the grid.

A grid of H x W cells is cut into cores of `tile` x `tile` cells (the last row and column of cores
may be smaller). A core is computed in its window: the core grown by `margin` cells on every side,
clipped to the grid. A window side on the grid's own edge is *closed*: beyond it lies exactly what
lies beyond the grid in one piece. The other sides are *open*: the grid goes on there, unseen.

Everything a window computes is a function of the window's cells, so a result at a cell is the
same as in one piece wherever the cells it depends on are all inside the window; the stages say
how far that is (their *reach*) and check it per cell with `gap` (how far the unseen part is) and
`clearance` (how far the nearest cell with an unsure value is). Distances here are in cells.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terra.graph import raster


@dataclass(frozen=True)
class Window:
    """Cells [rows, cols] of the grid around one core. closed: whether each side (first row, last
    row, first column, last column) is the grid's edge. core: the core's slices inside the window."""

    rows: slice
    cols: slice
    closed: tuple[bool, bool, bool, bool]
    core: tuple[slice, slice]

    @property
    def shape(self) -> tuple[int, int]:
        return self.rows.stop - self.rows.start, self.cols.stop - self.cols.start

    @property
    def whole(self) -> bool:
        """The window is the whole grid: nothing is unseen."""
        return all(self.closed)

    def gap(self) -> np.ndarray:
        """(h, w) float32: for each cell, a lower bound on its distance to any grid cell outside the
        window (inf when every side is closed). It is exact in rows and columns: the unseen cells
        beyond an open first row are at least (row + 1) away, Euclidean or chessboard alike."""
        h, w = self.shape
        inf = np.float32(np.inf)
        rows = np.full(h, inf, dtype=np.float32)
        cols = np.full(w, inf, dtype=np.float32)
        if not self.closed[0]:
            rows = np.minimum(rows, np.arange(1, h + 1, dtype=np.float32))
        if not self.closed[1]:
            rows = np.minimum(rows, np.arange(h, 0, -1, dtype=np.float32))
        if not self.closed[2]:
            cols = np.minimum(cols, np.arange(1, w + 1, dtype=np.float32))
        if not self.closed[3]:
            cols = np.minimum(cols, np.arange(w, 0, -1, dtype=np.float32))
        return np.minimum(rows[:, None], cols[None, :])

    def clearance(self, unsure: np.ndarray) -> np.ndarray:
        """(h, w) float32: chessboard distance from each cell to the nearest `unsure` cell of the
        window or unseen cell beyond an open side (inf if there is none). A cell with clearance > r
        has every cell within r (chessboard) inside the window and sure."""
        gap = self.gap()
        if not unsure.any():
            return gap
        to_unsure = raster.chessboard_to_zero(~unsure).astype(np.float32)
        return np.minimum(gap, to_unsure)


def cores(shape: tuple[int, int], tile: int) -> list[tuple[slice, slice]]:
    """Row-major cores of `tile` x `tile` cells (smaller at the far edges) covering a grid."""
    if tile < 1:
        raise ValueError("tile must be at least one cell")
    H, W = shape
    return [
        (slice(r, min(r + tile, H)), slice(c, min(c + tile, W))) for r in range(0, H, tile) for c in range(0, W, tile)
    ]


def window(shape: tuple[int, int], core: tuple[slice, slice], margin: int) -> Window:
    """The window of a core: grown by `margin` cells on every side, clipped to the grid."""
    H, W = shape
    rows = slice(max(core[0].start - margin, 0), min(core[0].stop + margin, H))
    cols = slice(max(core[1].start - margin, 0), min(core[1].stop + margin, W))
    closed = (rows.start == 0, rows.stop == H, cols.start == 0, cols.stop == W)
    inner = (
        slice(core[0].start - rows.start, core[0].stop - rows.start),
        slice(core[1].start - cols.start, core[1].stop - cols.start),
    )
    return Window(rows, cols, closed, inner)


def tile_cells(tile_size: float | None, cell_size: float) -> int | None:
    """Cells per tile side for a tile size in metres (None: one piece)."""
    return None if tile_size is None else max(int(round(tile_size / cell_size)), 1)
