"""Guo-Hall parallel thinning (two sub-iterations, 1989), run on the set cells only.

A GVD candidate band covers a small share of a large grid, so each pass gathers the 8-neighbour
codes of the remaining cells (O(cells), not O(grid)) and deletes, all at once, the cells that the
sub-iteration's lookup table marks. The result equals a full-grid implementation of the same
algorithm (scikit-image's `thin`), which the tests check.
"""

from __future__ import annotations

from functools import cache

import numpy as np

# Neighbour i (bit i of the code), counter-clockwise from east; "north" is row - 1.
_NEIGHBOURS = np.array([(0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0), (1, 1)])


@cache
def _tables() -> tuple[np.ndarray, np.ndarray]:
    """Deletion tables (256,) of the two sub-iterations from Guo and Hall's conditions G1-G3."""
    codes = np.arange(256)
    x = [(codes >> i) & 1 for i in range(8)] + [codes & 1]  # x[8] wraps to x[0]
    # G1: exactly one 8-connected run of set neighbours around the cell.
    crossing = sum(((1 - x[2 * i]) & (x[2 * i + 1] | x[(2 * i + 2) % 8])) for i in range(4))
    n1 = sum(x[2 * k] | x[2 * k + 1] for k in range(4))
    n2 = sum(x[2 * k + 1] | x[(2 * k + 2) % 8] for k in range(4))
    g2 = (np.minimum(n1, n2) >= 2) & (np.minimum(n1, n2) <= 3)
    g1 = crossing == 1
    # G3 (first pass) and G3' (second): which side of the cell may erode in this pass.
    g3 = ((x[1] | x[2] | (1 - x[7])) & x[0]) == 0
    g3p = ((x[5] | x[6] | (1 - x[3])) & x[4]) == 0
    return (g1 & g2 & g3), (g1 & g2 & g3p)


def thin(mask: np.ndarray) -> np.ndarray:
    """One-cell-thin skeleton of a boolean (H, W) mask (Guo-Hall), topology preserved."""
    return thin_counted(mask)[0]


def thin_counted(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """`thin` and the number of full iterations (both sub-iterations) it ran, the last one being
    the pass that changed nothing. A cell's result depends on the mask within 2 cells per
    iteration (each sub-iteration reads the 3 x 3 neighbourhood): terra.graph.tiled_gvd uses this
    count to bound how far a window's border can reach into its core."""
    mask = np.asarray(mask, dtype=bool)
    H, W = mask.shape
    grid = np.zeros((H + 2, W + 2), dtype=bool)  # a false frame keeps neighbour lookups inside
    grid[1:-1, 1:-1] = mask
    cells = np.argwhere(grid)
    weights = (1 << np.arange(8)).astype(np.int64)
    tables = _tables()
    changed = True
    iterations = 0
    while changed and len(cells):
        changed = False
        iterations += 1
        for table in tables:
            bits = grid[cells[:, 0, None] + _NEIGHBOURS[:, 0], cells[:, 1, None] + _NEIGHBOURS[:, 1]]
            delete = table[bits.astype(np.int64) @ weights]
            if delete.any():
                grid[cells[delete, 0], cells[delete, 1]] = False
                cells = cells[~delete]
                changed = True
    return grid[1:-1, 1:-1].copy(), iterations
