"""Where a set of grid cells sits in its list, found by binary search instead of an (H, W) index
array, so that work on a thin skeleton or one patch costs memory for its cells, not for the grid."""

from __future__ import annotations

import numpy as np


class CellIndex:
    """Positions of cells (K, 2) row/col, given in raster order (as np.argwhere returns them), in a
    grid of `shape`. `find` accepts cells one step outside the grid (rows -1..H, cols -1..W)."""

    def __init__(self, cells: np.ndarray, shape: tuple[int, int]) -> None:
        self.width = int(shape[1]) + 2
        self.keys = (np.asarray(cells[:, 0], dtype=np.int64) + 1) * self.width + (
            np.asarray(cells[:, 1], dtype=np.int64) + 1
        )

    def find(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(n,) position of each (row, col) in the list, -1 where it is not one of the cells."""
        keys = (np.asarray(rows, dtype=np.int64) + 1) * self.width + (np.asarray(cols, dtype=np.int64) + 1)
        if len(self.keys) == 0:
            return np.full(keys.shape, -1, dtype=np.int64)
        pos = np.minimum(np.searchsorted(self.keys, keys), len(self.keys) - 1)
        return np.where(self.keys[pos] == keys, pos, -1)
