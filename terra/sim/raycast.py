"""Ray casting against a World: first hit of every sensor ray, with its label and surface normal.

Rays are grouped in small angular tiles (a cone each); per frame a shape is tested only against the
rays of tiles whose cone meets the cone of its bounding sphere. The ground is intersected last, up
to the nearest shape hit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terra.sim.classes import CLASS_COLORS
from terra.sim.heightfield import Heightfield
from terra.sim.kernels import cast_kernel, cull_kernel
from terra.sim.world import World


@dataclass
class RayTiles:
    """Sensor rays (N, 3) unit, sensor frame, grouped in tiles: rays (G, M) indices (edge tiles
    repeat a ray), axis (G, 3) unit cone axis, half_angle (G,) radians holding every ray of the tile."""

    directions: np.ndarray
    rays: np.ndarray
    axis: np.ndarray
    half_angle: np.ndarray

    def __post_init__(self) -> None:
        self.cos_half = np.cos(self.half_angle)  # per-frame culling constants
        self.sin_half = np.sin(self.half_angle)

    @classmethod
    def from_grid(cls, directions: np.ndarray, rows: int, cols: int, tile_rows: int, tile_cols: int) -> RayTiles:
        """Tiles of tile_rows x tile_cols over rays stored row-major on a rows x cols grid."""
        r0 = np.arange(0, rows, tile_rows)
        c0 = np.arange(0, cols, tile_cols)
        dr, dc = np.meshgrid(np.arange(tile_rows), np.arange(tile_cols), indexing="ij")
        rr = np.minimum(r0[:, None, None, None] + dr[None, None], rows - 1)
        cc = np.minimum(c0[None, :, None, None] + dc[None, None], cols - 1)
        rays = (rr * cols + cc).reshape(len(r0) * len(c0), tile_rows * tile_cols)
        d = directions[rays]  # (G, M, 3)
        axis = d.sum(axis=1)
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        cos = np.clip(np.einsum("gmk,gk->gm", d, axis), -1.0, 1.0)
        half = np.arccos(cos.min(axis=1)) + 1e-6
        return cls(directions, rays.astype(np.int64), axis, half)


@dataclass
class Hits:
    """First hit per ray: t (N,) metres (inf = nothing within range), class_id / instance_id (N,)
    int32 (0 for no hit), normal (N, 3) map frame, color (N, 3) uint8 base colour, and the
    world-frame ray directions (N, 3)."""

    t: np.ndarray
    class_id: np.ndarray
    instance_id: np.ndarray
    normal: np.ndarray
    color: np.ndarray
    directions: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return np.isfinite(self.t)


def cast(world: World, T_map_sensor: np.ndarray, tiles: RayTiles, max_range: float) -> Hits:
    """Cast every ray of `tiles` from the sensor at pose T_map_sensor (4x4) up to `max_range` metres."""
    R = T_map_sensor[:3, :3]
    origin = np.ascontiguousarray(T_map_sensor[:3, 3], dtype=np.float64)
    dirs = np.ascontiguousarray(tiles.directions @ R.T)
    tile_ptr, tile_prims = _tile_candidates(world, origin, R, tiles, max_range)
    t, prim, normal = _first_hits(world, origin, dirs, tiles, tile_ptr, tile_prims, max_range)
    class_id, instance_id, color = _hit_labels(world, origin, dirs, t, prim)
    return Hits(t, class_id, instance_id, normal, color, dirs)


def _tile_candidates(
    world: World, origin: np.ndarray, R: np.ndarray, tiles: RayTiles, max_range: float
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate shapes per tile (CSR: tile_ptr (G + 1,), tile_prims): the cone of the tile (turned
    into the map frame by the sensor's rotation R) meets the cone of the shape's bounding sphere.
    The test keeps a 1e-6 rad margin (RayTiles.half_angle), so rounding in it never changes a hit."""
    near = world.prims_near(origin, max_range)
    if not near.size:
        return np.zeros(tiles.rays.shape[0] + 1, np.int64), np.zeros(0, np.int64)
    rel = world.prims.center[near] - origin
    dist = np.linalg.norm(rel, axis=1)
    radius = world.bounding_radius[near]
    ang = np.where(dist <= radius, np.pi, np.arcsin(np.clip(radius / np.maximum(dist, 1e-9), 0.0, 1.0)))
    u = rel / np.maximum(dist, 1e-9)[:, None]
    tile_ptr, local = cull_kernel(
        np.ascontiguousarray(tiles.axis @ R.T),
        tiles.cos_half,
        tiles.sin_half,
        tiles.half_angle,
        np.ascontiguousarray(u),
        np.cos(ang),
        np.sin(ang),
        ang,
    )
    return tile_ptr, near[local]


def _first_hits(
    world: World,
    origin: np.ndarray,
    dirs: np.ndarray,
    tiles: RayTiles,
    tile_ptr: np.ndarray,
    tile_prims: np.ndarray,
    max_range: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first hit of each ray `dirs` (N, 3), map frame: t (N,) metres (inf: none), the shape
    hit (N,) (cast_kernel's marks: -1 the ground, -2 nothing) and the surface normal (N, 3)."""
    n = dirs.shape[0]
    prims = world.prims
    t = np.empty(n)
    prim = np.empty(n, np.int64)
    normal = np.empty((n, 3))
    hf = world.ground
    cast_kernel(
        origin,
        dirs,
        tiles.rays,
        tile_ptr,
        tile_prims,
        prims.kind,
        prims.center,
        prims.half,
        world.cos_yaw,
        world.sin_yaw,
        hf.amplitude,
        np.ascontiguousarray(hf.wavevector[:, 0]),
        np.ascontiguousarray(hf.wavevector[:, 1]),
        hf.phase,
        float(hf.base),
        hf.slope_bound,
        *_step_arrays(hf),
        float(max_range),
        1e-3,
        t,
        prim,
        normal,
    )
    return t, prim, normal


_NO_STEPS = (np.zeros((0, 0)), np.zeros((1, 1)), np.zeros(5))


def _step_arrays(ground: Heightfield) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ground's step offsets, block maxima and grid as cast_kernel reads them (empty: none)."""
    if ground.steps is None:
        return _NO_STEPS
    st = ground.steps
    return np.ascontiguousarray(st.offsets, np.float64), np.ascontiguousarray(st.block_max, np.float64), st.grid()


def _hit_labels(
    world: World, origin: np.ndarray, dirs: np.ndarray, t: np.ndarray, prim: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """class_id, instance_id (N,) int32 and base colour (N, 3) uint8 of each ray's hit: the shape's,
    the terrain class under the ground hit, or 0 for no hit."""
    n = dirs.shape[0]
    prims = world.prims
    class_id = np.zeros(n, np.int32)
    instance_id = np.zeros(n, np.int32)
    color = np.zeros((n, 3), np.uint8)
    shape = prim >= 0
    ps = prim[shape]
    class_id[shape] = prims.class_id[ps]
    instance_id[shape] = prims.instance_id[ps]
    color[shape] = prims.color[ps]
    gi = np.flatnonzero(prim == -1)
    if gi.size:
        cls = world.terrain.class_at(origin[:2] + t[gi, None] * dirs[gi, :2])
        class_id[gi] = cls
        color[gi] = CLASS_COLORS[cls]
    return class_id, instance_id, color
