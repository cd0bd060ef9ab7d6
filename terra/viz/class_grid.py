"""Terrain class grids: the map and the ground truth on one grid, drawn the same way.

A class grid is (H, W) int64 over an extent (xmin, xmax, ymin, ymax, metres, map frame) with
square cells, row 0 at ymin: -1 = nothing there (unobserved, or no ground truth), 0..T-1 = a
terrain class (index into the map's terrain classes), T = something that is not terrain
(buildings, trees, objects). The map's grid takes each cell's highest point, as a top-down view
does; the ground truth's takes the terrain raster at the cell centre, then every ground-truth
object's footprint on top, so buildings and trees show on both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terra.datasets.ground_truth import GroundTruth
from terra.viz.style import Extent, map_palette


@dataclass
class ClassGrid:
    """`index` (H, W) as described in the module docstring, over `extent` with square `cell` metres."""

    index: np.ndarray
    extent: Extent
    cell: float
    terrain_count: int

    @classmethod
    def empty(cls, extent: Extent, cell: float, terrain_count: int) -> ClassGrid:
        # Whole cells covering the extent; the tolerance keeps a grid's own (snapped) extent from
        # gaining a cell by rounding, so a grid made over another's extent has its shape.
        w = max(int(np.ceil((extent[1] - extent[0]) / cell - 1e-6)), 1)
        h = max(int(np.ceil((extent[3] - extent[2]) / cell - 1e-6)), 1)
        extent = (extent[0], extent[0] + w * cell, extent[2], extent[2] + h * cell)
        return cls(np.full((h, w), -1, dtype=np.int64), extent, float(cell), int(terrain_count))

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """x (W,) and y (H,) of the cell centres, metres."""
        h, w = self.index.shape
        return (self.extent[0] + (np.arange(w) + 0.5) * self.cell, self.extent[2] + (np.arange(h) + 0.5) * self.cell)

    def rgba(self, terrain_classes: list[str]) -> np.ndarray:
        """(H, W, 4) colours: the terrain palette, not terrain dark grey, no camera label light
        grey, nothing transparent."""
        palette = map_palette(terrain_classes)  # T terrain rows, not terrain, no camera label
        out = np.zeros(self.index.shape + (4,))
        seen = self.index >= 0
        out[seen, :3] = palette[np.minimum(self.index[seen], len(palette) - 1)]
        out[seen, 3] = 1.0
        return out


def map_class_grid(
    points: np.ndarray, terrain_index: np.ndarray, terrain_count: int, extent: Extent, cell: float
) -> ClassGrid:
    """The map's points (N, 3 metres) with their class (terra.viz.raster.point_classes: terrain
    index, T not terrain, T + 1 no camera label; -1 also not terrain) on a grid: each cell takes
    its highest point."""
    grid = ClassGrid.empty(extent, cell, terrain_count)
    points = np.asarray(points, dtype=np.float64)
    h, w = grid.index.shape
    col = np.floor((points[:, 0] - grid.extent[0]) / cell).astype(np.int64)
    row = np.floor((points[:, 1] - grid.extent[2]) / cell).astype(np.int64)
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    if not inside.any():
        return grid
    key = row[inside] * w + col[inside]
    z = points[inside, 2]
    labels = np.asarray(terrain_index)[inside]
    labels = np.where(labels >= 0, labels, terrain_count)
    order = np.lexsort((z, key))  # the last entry of each cell is its highest point
    last = order[np.r_[np.flatnonzero(np.diff(key[order])), len(order) - 1]]
    grid.index.reshape(-1)[key[last]] = labels[last]
    return grid


def gt_class_grid(gt: GroundTruth, terrain_classes: list[str], extent: Extent, cell: float) -> ClassGrid:
    """The ground truth on a grid: its terrain raster at each cell centre, then the footprint of
    every object (buildings, trees, objects) as not terrain."""
    import shapely

    from terra.tasks.boxes import BoxSet

    count = len(terrain_classes)
    grid = ClassGrid.empty(extent, cell, count)
    xs, ys = grid.centres()
    gx, gy = np.meshgrid(xs, ys)
    raster = gt.terrain
    if raster is not None:
        by_name = {name: i for i, name in enumerate(terrain_classes)}
        ids = raster.class_at(np.column_stack([gx.ravel(), gy.ravel()]))
        lut = {int(k): by_name.get(v, count) for k, v in raster.legend.items()}
        lut[0] = -1  # unlabelled: nothing
        # One row per raster id, and a last one for -1 (outside the raster): nothing.
        table = np.array([lut.get(int(i), -1) for i in range(int(ids.max(initial=0)) + 1)] + [-1])
        grid.index = table[ids].reshape(gx.shape)
    if gt.objects:
        corners = BoxSet.from_objects(gt.objects).footprint_corners()
        for quad in corners:
            lo, hi = quad.min(axis=0), quad.max(axis=0)
            c0, c1 = np.searchsorted(xs, [lo[0], hi[0]])
            r0, r1 = np.searchsorted(ys, [lo[1], hi[1]])
            if c1 <= c0 or r1 <= r0:
                continue
            inside = shapely.contains_xy(shapely.Polygon(quad), gx[r0:r1, c0:c1], gy[r0:r1, c0:c1])
            grid.index[r0:r1, c0:c1][inside] = count
    return grid


# Difference categories (per cell the map observed), in legend order.
SAME, OTHER_TERRAIN, TERRAIN_VS_OBJECT = 0, 1, 2
DIFFERENCE_LABELS = ("same class", "another terrain", "terrain on one side, not terrain on the other")
DIFFERENCE_COLOURS = ("#a3a3a3", "#000000", "#fdb462")


def difference(map_grid: ClassGrid, gt_grid: ClassGrid) -> tuple[np.ndarray, float | None]:
    """(H, W) category per cell (-1 where the ground truth has nothing or no camera labelled the
    map there) and the share of cells where both hold terrain whose terrain agrees (None when
    there is none)."""
    a, b, t = map_grid.index, gt_grid.index, map_grid.terrain_count
    both = (a >= 0) & (a <= t) & (b >= 0)  # cells the map labelled (not LiDAR-only ones) and the ground truth covers
    out = np.full(a.shape, -1, dtype=np.int64)
    out[both & (a == b)] = SAME
    out[both & (a != b) & (a < t) & (b < t)] = OTHER_TERRAIN
    out[both & (a != b) & ((a == t) | (b == t))] = TERRAIN_VS_OBJECT
    terrain = both & (a < t) & (b < t)
    share = float(np.count_nonzero(terrain & (a == b)) / np.count_nonzero(terrain)) if terrain.any() else None
    return out, share


def difference_rgba(categories: np.ndarray) -> np.ndarray:
    from matplotlib.colors import to_rgb

    colours = np.array([to_rgb(c) for c in DIFFERENCE_COLOURS])
    out = np.zeros(categories.shape + (4,))
    seen = categories >= 0
    out[seen, :3] = colours[categories[seen]]
    out[seen, 3] = 1.0
    return out
