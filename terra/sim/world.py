"""A generated world: ground, terrain classes, solid shapes, ground-truth objects, regions, route."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

from terra.datasets.ground_truth import GroundTruth, NamedRegion, ObjectBox, TerrainRaster
from terra.sim.classes import SIM_CLASSES, class_id
from terra.sim.heightfield import Heightfield
from terra.sim.primitives import BOX, Primitives

OUTSIDE_TERRAIN = class_id("grass")
"""Terrain class of the ground beyond the raster: the campus is surrounded by fields."""


@dataclass
class TerrainGrid:
    """Terrain class per cell (H, W) uint8; cell (r, c) covers x in [x0 + c res, x0 + (c+1) res),
    y in [y0 + r res, ...): the layout of `terra.datasets.ground_truth.TerrainRaster`."""

    classes: np.ndarray
    origin: np.ndarray
    resolution: float

    def class_at(self, xy: np.ndarray) -> np.ndarray:
        """(N,) class ids at map-frame points (N, 2); OUTSIDE_TERRAIN beyond the grid."""
        rc = np.floor((xy[:, :2] - self.origin) / self.resolution).astype(np.int64)
        rows, cols = rc[:, 1], rc[:, 0]
        h, w = self.classes.shape
        inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        out = np.full(xy.shape[0], OUTSIDE_TERRAIN, dtype=np.int32)
        out[inside] = self.classes[rows[inside], cols[inside]]
        return out

    def cell_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Cell-centre x (W,) and y (H,) coordinates, metres."""
        h, w = self.classes.shape
        return (
            self.origin[0] + (np.arange(w) + 0.5) * self.resolution,
            self.origin[1] + (np.arange(h) + 0.5) * self.resolution,
        )


@dataclass
class World:
    """Everything the sensors see and the ground truth describes (map frame, metres).

    extent: (x0, y0, x1, y1) of the generated area. route: (K, 2) polyline the robot follows.
    Buildings and trees are ground-truth objects too (with their own instance ids); terrain has
    instance id 0.
    """

    name: str
    seed: int
    extent: tuple[float, float, float, float]
    ground: Heightfield
    terrain: TerrainGrid
    prims: Primitives
    objects: list[ObjectBox]
    regions: list[NamedRegion]
    route: np.ndarray
    _tree: cKDTree | None = field(default=None, repr=False)
    _raster_height: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        # Per-shape constants the renderer needs every frame.
        self.bounding_radius = self.prims.bounding_radius
        self.cos_yaw = np.cos(self.prims.yaw)
        self.sin_yaw = np.sin(self.prims.yaw)

    def prims_near(self, position: np.ndarray, radius: float) -> np.ndarray:
        """Indices (sorted) of shapes whose bounding sphere comes within `radius` metres of `position`."""
        if len(self.prims) == 0:
            return np.zeros(0, np.int64)
        tree = self._tree
        if tree is None:
            tree = self._tree = cKDTree(self.prims.center)
        idx = np.asarray(tree.query_ball_point(position, radius + float(self.bounding_radius.max())), dtype=np.int64)
        idx.sort()
        d = np.linalg.norm(self.prims.center[idx] - position, axis=1)
        return idx[d - self.bounding_radius[idx] <= radius]

    def stairs_tops(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Height (metres, map frame) of the highest stairs tread over each point (x, y arrays of one
        shape); NaN where no stairs are."""
        top = np.full(x.shape, np.nan)
        stairs = np.flatnonzero((self.prims.class_id == class_id("stairs")) & (self.prims.kind == BOX))
        for p in stairs:
            c, s = self.cos_yaw[p], self.sin_yaw[p]
            rx, ry = x - self.prims.center[p, 0], y - self.prims.center[p, 1]
            hx, hy, hz = self.prims.half[p]
            inside = (np.abs(c * rx + s * ry) <= hx) & (np.abs(-s * rx + c * ry) <= hy)
            top[inside] = np.fmax(top[inside], self.prims.center[p, 2] + hz)
        return top

    def ground_truth(self) -> GroundTruth:
        """Objects, terrain raster with ground heights at cell centres, named regions. With step
        offsets (the `geometry` option) the heights include them and the stairs' treads."""
        if self._raster_height is None:  # 41 M cells on the huge preset: computed once, not per caller
            xs, ys = self.terrain.cell_centres()
            gx, gy = np.meshgrid(xs, ys)
            height = self.ground.height(np.stack([gx.ravel(), gy.ravel()], axis=1)).reshape(gx.shape)
            if self.ground.steps is not None:  # the stairs' treads are ground a robot meets
                height = np.fmax(height, self.stairs_tops(gx, gy))
            self._raster_height = height.astype(np.float32)
        legend = {c.id: c.name for c in SIM_CLASSES if c.terrain or c.id == 0}
        raster = TerrainRaster(
            self.terrain.classes.astype(np.int32),
            self._raster_height.copy(),
            self.terrain.origin.copy(),
            self.terrain.resolution,
            legend,
        )
        return GroundTruth(list(self.objects), raster, list(self.regions))
