"""Ground geometry beyond the smooth height field: curbs, curb cuts, ramps beside stairs, a steep
hill and sloped lawns, as step offsets on the terrain raster's cells (`StepRaster`, added to the
smooth height; config: `GeometryConfig`).

Built once the layout is painted and furnished (`build_steps`, called by `WorldBuilder.finish`):
- curbs: every cell that is not asphalt is raised by the curb height;
- curb cuts: where a walkway (a path the robot drives) crosses from asphalt onto a raised cell, the
  raised cells within half the cut's width of the walkway and within the cut's run (curb height /
  grade) of the crossing climb linearly from the road: offset = curb height x along / run;
- ramps beside stairs: along the building front, on the stairs' +x side (their own frame: x along
  the flight's width, +y toward the door), offset + rise x (1 - distance from the flight / run);
- mounds on open lawn (grass far from objects and walkways): a raised cosine
  a (1 + cos(pi r / R)) / 2, whose steepest slope is a pi / (2 R); the steep hill first, on the
  widest lawn, then the gentle lawns.
Offsets are constant per cell, so a slope is a staircase of small risers (1:12 on 0.25 m cells:
2.1 cm); the ray caster sees the risers as walls. Frames: map frame, metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
from scipy import ndimage

from terra.sim.classes import class_id
from terra.sim.config import GeometryConfig
from terra.sim.heightfield import StepRaster
from terra.sim.world import TerrainGrid


@dataclass
class Flight:
    """A flight of stairs as placed: centre (x, y) metres, yaw radians (its +y toward the door),
    half width and half depth (metres, along its own x and y) and total rise (metres)."""

    x: float
    y: float
    yaw: float
    half_width: float
    half_depth: float
    rise: float


@dataclass
class _Cells:
    """Cell-centre coordinates (H, W) of the raster, metres."""

    x: np.ndarray
    y: np.ndarray

    def near(self, x: float, y: float, radius: float) -> tuple[slice, slice]:
        """(rows, cols) of the cells whose centres lie within `radius` metres of (x, y) along both
        axes: a feature touches only these, so a kilometre raster is not swept per feature."""
        xs, ys = self.x[0], self.y[:, 0]
        cols = slice(int(np.searchsorted(xs, x - radius)), int(np.searchsorted(xs, x + radius, side="right")))
        rows = slice(int(np.searchsorted(ys, y - radius)), int(np.searchsorted(ys, y + radius, side="right")))
        return rows, cols


def build_steps(
    terrain: TerrainGrid,
    walkways: list[np.ndarray],
    flights: list[Flight],
    occupied: np.ndarray,
    config: GeometryConfig,
) -> StepRaster:
    """The step offsets of a furnished layout: terrain classes (H, W), walkways (polylines (K, 2)),
    flights of stairs, occupied (H, W) bool (cells under or beside objects). See the module docstring."""
    xs, ys = terrain.cell_centres()
    gx, gy = np.meshgrid(xs, ys)
    cells = _Cells(gx, gy)
    shape = terrain.classes.shape
    offsets = np.zeros(shape)
    curb_cut, ramp, hill, lawn = (np.zeros(shape, bool) for _ in range(4))
    if config.curbs:
        raised = terrain.classes != class_id("asphalt")
        offsets[raised] = config.curb_height_m
        for point, direction in walkway_crossings(terrain, walkways, raised):
            _curb_cut(offsets, curb_cut, cells, raised, point, direction, config)
    if config.stairs_ramps:
        for flight in flights:
            _stairs_ramp(offsets, ramp, cells, flight, config)
    open_lawn = (terrain.classes == class_id("grass")) & ~occupied & ~curb_cut & ~ramp
    open_lawn &= ~_near_walkways(terrain, walkways, 1.5)
    mounds = [(config.hill_slope_deg, config.hill_height_m, hill)] if config.steep_hill else []
    mounds += [(config.lawn_slope_deg, config.lawn_height_m, lawn)] * config.sloped_lawns
    for slope_deg, height, mask in mounds:
        _mound(offsets, mask, cells, open_lawn, terrain.resolution, slope_deg, height)
    return StepRaster(offsets, terrain.origin.copy(), terrain.resolution, curb_cut, ramp, hill, lawn)


def walkway_crossings(
    terrain: TerrainGrid, walkways: list[np.ndarray], raised: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Where walkways cross between asphalt and raised cells: (point (2,), unit direction (2,) from
    the asphalt onto the raised side), one per crossing (crossings within 1 m of another dropped)."""
    found: list[tuple[np.ndarray, np.ndarray]] = []
    step = terrain.resolution / 4
    for line in walkways:
        for a, b in zip(line[:-1], line[1:]):
            length = float(np.linalg.norm(b - a))
            if length < 1e-9:
                continue
            n = max(int(np.ceil(length / step)), 1)
            samples = a + (b - a) * (np.arange(n + 1) / n)[:, None]
            up = _raised_at(terrain, raised, samples)
            for i in np.flatnonzero(up[1:] != up[:-1]):
                point = (samples[i] + samples[i + 1]) / 2
                direction = (b - a) / length * (1.0 if up[i + 1] else -1.0)
                if all(np.linalg.norm(point - p) > 1.0 for p, _ in found):
                    found.append((point, direction))
    return found


def _raised_at(terrain: TerrainGrid, raised: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(N,) bool: the raised mask at map points (N, 2), clamped to the raster's edge."""
    rc = np.floor((xy - terrain.origin) / terrain.resolution).astype(np.int64)
    h, w = raised.shape
    return raised[np.clip(rc[:, 1], 0, h - 1), np.clip(rc[:, 0], 0, w - 1)]


def _curb_cut(
    offsets: np.ndarray,
    mask: np.ndarray,
    cells: _Cells,
    raised: np.ndarray,
    point: np.ndarray,
    direction: np.ndarray,
    config: GeometryConfig,
) -> None:
    """Lower the raised cells of one curb cut (module docstring) in place and mark them in `mask`."""
    run = config.curb_height_m / config.curb_cut_grade
    win = cells.near(float(point[0]), float(point[1]), run + config.curb_cut_width_m)
    rx, ry = cells.x[win] - point[0], cells.y[win] - point[1]
    along = rx * direction[0] + ry * direction[1]
    across = -rx * direction[1] + ry * direction[0]
    inside = raised[win] & (along > -run / 4) & (along <= run) & (np.abs(across) <= config.curb_cut_width_m / 2)
    lowered = np.minimum(offsets[win], config.curb_height_m * np.clip(along, 0.0, run) / run)
    offsets[win] = np.where(inside, lowered, offsets[win])
    mask[win] |= inside


def _stairs_ramp(offsets: np.ndarray, mask: np.ndarray, cells: _Cells, flight: Flight, config: GeometryConfig) -> None:
    """Add the ramp beside one flight of stairs (module docstring) in place and mark it in `mask`."""
    run = flight.rise / config.ramp_grade
    c, s = np.cos(flight.yaw), np.sin(flight.yaw)
    win = cells.near(flight.x, flight.y, flight.half_width + run + flight.half_depth + config.ramp_width_m)
    rx, ry = cells.x[win] - flight.x, cells.y[win] - flight.y
    lx, ly = c * rx + s * ry, -s * rx + c * ry
    beyond = lx - flight.half_width
    inside = (
        (beyond >= 0.0) & (beyond < run) & (ly <= flight.half_depth) & (ly > flight.half_depth - config.ramp_width_m)
    )
    offsets[win] += np.where(inside, flight.rise * (1.0 - beyond / run), 0.0)
    mask[win] |= inside


def _near_walkways(terrain: TerrainGrid, walkways: list[np.ndarray], margin: float) -> np.ndarray:
    """(H, W) bool: cells within `margin` metres of a walkway's vertices or segments (sampled every half cell)."""
    h, w = terrain.classes.shape
    near = np.zeros((h, w), bool)
    for line in walkways:
        for a, b in zip(line[:-1], line[1:]):
            n = max(int(np.ceil(np.linalg.norm(b - a) / (terrain.resolution / 2))), 1)
            samples = a + (b - a) * (np.arange(n + 1) / n)[:, None]
            rc = np.floor((samples - terrain.origin) / terrain.resolution).astype(np.int64)
            ok = (rc[:, 0] >= 0) & (rc[:, 0] < w) & (rc[:, 1] >= 0) & (rc[:, 1] < h)
            near[rc[ok, 1], rc[ok, 0]] = True
    distance = cast(np.ndarray, ndimage.distance_transform_edt(~near)) * terrain.resolution
    return distance <= margin


def _mound(
    offsets: np.ndarray,
    mask: np.ndarray,
    cells: _Cells,
    open_lawn: np.ndarray,
    resolution: float,
    slope_deg: float,
    height: float,
) -> None:
    """Raise one raised-cosine mound (module docstring) on the widest part of `open_lawn`, keeping
    `slope_deg` as its steepest slope (lower than `height` where the lawn is narrower than the
    mound would be); mark it in `mask` and take it and a 2 m margin out of `open_lawn`. Nothing
    where the widest open lawn is under 2 m in radius."""
    padded = np.pad(open_lawn, 1)  # beyond the raster's edge is no lawn
    room = cast(np.ndarray, ndimage.distance_transform_edt(padded))[1:-1, 1:-1] * resolution
    r, c = (int(v) for v in np.unravel_index(int(np.argmax(room)), room.shape))
    tangent = np.tan(np.radians(slope_deg))
    radius = min(np.pi * height / (2.0 * tangent), float(room[r, c]))
    if radius < 2.0:
        return
    peak = 2.0 * radius * tangent / np.pi
    distance = np.hypot(cells.x - cells.x[r, c], cells.y - cells.y[r, c])
    inside = distance < radius
    offsets[inside] += peak * 0.5 * (1.0 + np.cos(np.pi * distance[inside] / radius))
    mask |= inside
    open_lawn &= distance >= radius + 2.0
