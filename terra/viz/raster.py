"""Top-down raster images of coloured points and of ground-truth terrain, for map backgrounds."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from matplotlib.axes import Axes

from terra.datasets.ground_truth import TerrainRaster
from terra.viz.style import map_palette, terrain_palette


@dataclass
class TopDownImage:
    """An RGBA image (H, W, 4) covering extent (xmin, xmax, ymin, ymax) metres, row 0 at ymin."""

    rgba: np.ndarray
    extent: tuple[float, float, float, float]

    def show(self, ax: Axes, alpha: float = 1.0) -> None:
        ax.imshow(self.rgba, origin="lower", extent=self.extent, interpolation="nearest", alpha=alpha, zorder=0)

    def crop(self, window: tuple[float, float, float, float]) -> TopDownImage:
        """The part of the image covering `window` (xmin, xmax, ymin, ymax metres), whole cells,
        so a zoomed panel does not resample the whole map."""
        h, w = self.rgba.shape[:2]
        x0, x1, y0, y1 = self.extent
        cx, cy = (x1 - x0) / max(w, 1), (y1 - y0) / max(h, 1)
        c0, c1 = (
            int(np.clip(np.floor((window[0] - x0) / cx), 0, w)),
            int(np.clip(np.ceil((window[1] - x0) / cx), 0, w)),
        )
        r0, r1 = (
            int(np.clip(np.floor((window[2] - y0) / cy), 0, h)),
            int(np.clip(np.ceil((window[3] - y0) / cy), 0, h)),
        )
        if c1 <= c0 or r1 <= r0:
            return TopDownImage(np.zeros((1, 1, 4)), (window[0], window[1], window[2], window[3]))
        return TopDownImage(self.rgba[r0:r1, c0:c1], (x0 + c0 * cx, x0 + c1 * cx, y0 + r0 * cy, y0 + r1 * cy))


def rasterize_points(
    points: np.ndarray, colours: np.ndarray, cell: float = 0.4, max_pixels: int = 1600
) -> TopDownImage:
    """Top-down image of points (N, 3, metres, map frame) with RGB colours (N, 3): each cell shows
    its highest point. `cell` (metres) grows when the image would exceed `max_pixels` on a side."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) == 0:
        return TopDownImage(np.zeros((1, 1, 4)), (0.0, 1.0, 0.0, 1.0))
    lo = points[:, :2].min(axis=0)
    span = points[:, :2].max(axis=0) - lo
    cell = max(cell, float(span.max()) / max_pixels)
    shape = (np.floor(span / cell).astype(np.int64) + 1)[::-1]  # rows (y), cols (x)
    col = np.floor((points[:, 0] - lo[0]) / cell).astype(np.int64)
    row = np.floor((points[:, 1] - lo[1]) / cell).astype(np.int64)
    key = row * shape[1] + col
    # Sort by (cell, z): the last entry of each cell is its highest point.
    order = np.lexsort((points[:, 2], key))
    last = order[np.r_[np.flatnonzero(np.diff(key[order])), len(order) - 1]]
    rgba = np.zeros((shape[0] * shape[1], 4))
    rgba[key[last], :3] = colours[last]
    rgba[key[last], 3] = 1.0
    extent = (float(lo[0]), float(lo[0] + shape[1] * cell), float(lo[1]), float(lo[1] + shape[0] * cell))
    return TopDownImage(rgba.reshape(shape[0], shape[1], 4), extent)


def point_classes(msm) -> np.ndarray:
    """(N,) what each map point shows in figures: its terrain index 0..T-1, T when it is not
    terrain (an object, a building, a tree: it has object observations), T + 1 when no camera
    labelled it at all (LiDAR only, e.g. beyond the cameras' range)."""
    terrain = msm.terrain_index()
    count = len(msm.terrain_classes)
    observed = np.diff(msm.counts.tocsr().indptr) > 0
    return np.where(terrain >= 0, terrain, np.where(observed, count, count + 1))


def terrain_points_image(
    points: np.ndarray, terrain_index: np.ndarray, terrain_classes: list[str], cell: float = 0.4
) -> TopDownImage:
    """Map points coloured by terrain index (-1 or T = not terrain, drawn dark grey; T + 1 = no
    camera label, light grey; see point_classes)."""
    palette = map_palette(terrain_classes)
    index = np.asarray(terrain_index)
    return rasterize_points(points, palette[np.where(index < 0, len(terrain_classes), index)], cell)


def terrain_raster_image(raster: TerrainRaster, terrain_classes: list[str]) -> TopDownImage:
    """The ground-truth terrain raster coloured like the map (cells of non-terrain classes grey,
    cells of class 0 transparent)."""
    palette = terrain_palette(terrain_classes)
    by_name = {name: i for i, name in enumerate(terrain_classes)}
    ids = np.array(sorted(raster.legend), dtype=np.int64)
    lut_size = int(max(ids.max(initial=0), raster.classes.max(initial=0))) + 1
    lut = np.full(lut_size, -1, dtype=np.int64)
    for class_id in ids:
        lut[class_id] = by_name.get(raster.legend[int(class_id)], -1)
    index = lut[np.clip(raster.classes, 0, lut_size - 1)]
    rgba = np.ones(raster.classes.shape + (4,))
    rgba[..., :3] = palette[index]
    rgba[raster.classes <= 0, 3] = 0.0
    h, w = raster.classes.shape
    x0, y0 = raster.origin
    extent = (float(x0), float(x0 + w * raster.resolution), float(y0), float(y0 + h * raster.resolution))
    return TopDownImage(rgba, extent)
