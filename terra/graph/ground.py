"""Ground geometry from the LiDAR points alone (DESIGN.md decision 19): which map points are
ground, and per terrain-grid cell the ground's height, slope, step and roughness.

Frames and units: points and heights are in the map frame, metres; slopes are degrees from the
horizontal; the grid follows terra.graph.grid (cell (row r, col c) covers x in [x0 + c s, x0 +
(c + 1) s), y in [y0 + r s, ...), rows grow with y).

Ground segmentation (`segment_ground`) works on the whole map, not per scan: a map keeps no
sensor origin per point, which scan-based methods (Patchwork++'s concentric zones around the
sensor) need, and the LiDAR-only maps Terra is asked to build on are already fused. It is a
progressive morphological filter (Zhang et al., IEEE TGRS 2003): the lowest point of each cell
forms a surface; grey openings with growing windows remove what stands on the ground (a car
vanishes under a 2 m window, a building under 8 m), and a cell whose lowest point rises above the
opened surface by more than the window's allowance (`base_height` + `slope` x the window's
growth) is not ground. Points at most `tolerance` above the lowest point of the nearest ground
cell are ground.

Layers (`ground_layers`), per cell, from the ground points in it:
- gradient: dz/dx, dz/dy of the least-squares plane through the mean heights of the observed
  cells of its 3 x 3 neighbourhood, each taken where its points' centroid lies (NaN with fewer
  than three cells, or all on one line); slope = atan |gradient|;
- height: mean height of its ground points, carried from their centroid to the cell's centre
  along that gradient (a map keeps one point per voxel, rarely at the centre: on a slope the raw
  means read as steps between cells), unless the gradient is steeper than 45 degrees
  (`STEEPEST_FIT`: a fit on cells nearly in a line, its mean is kept); a cell more than 3 cm
  above or below all its neighbours takes their median (`despike`: one stray point is no step);
- step: the height jump at the cell that a smooth surface does not explain, the larger of the two
  axes: along x, |h[c+1] - h[c-1]| minus twice the larger of the neighbouring differences
  |h[c-1] - h[c-2]|, |h[c+2] - h[c+1]| (the local slope; the gradient's where neither is
  observed), floored at 0. A 15 cm curb reads 15 cm on both cells beside it, or on the cell it
  runs through; a constant slope reads 0 (it is the slope layer's business), and so do the top
  and the bottom of a ramp (a curb cut's 7 degrees met the level there and read 4-6 cm with the
  mean of the two sides: the wheelchair's own ramps closed to it); stairs read as a steep slope
  with small steps. Where a neighbour holds no ground (the road in a curb's own LiDAR shadow),
  the difference between the nearest observed cells up to four cells away on each side,
  less the slope over the cells between: the one read just beyond those two cells, else the
  cell's gradient (a plane fitted on a curb's face takes the curb for a slope); where the cell
  across the gap holds both levels (a curb's face runs through it), it reads the step and the cell
  before the gap does not; where the ground across the gap is the higher and its cell holds the
  step, the cell on the low edge reads only its other side (`held_across_gaps`: a curb's shadow
  lies behind its top). Within two cells
  of a blocked cell, where an object's lowest points pass for ground, read only along an axis
  clear of blocked cells, and across a gap from heights that are not blocked (`grid_layers`);
- roughness: the standard deviation of the cell's ground point heights, less what the plane's
  tilt explains within the cell (s^2 |gradient|^2 / 12), metres.

Edges (`edge_geometry`): each place edge is sampled along its straight segment every half cell;
its step is the largest step of the cells it crosses (at least `line_step` where it crosses one of
the layers' `lines`, the lines of steps of a LiDAR-only ground, `step_lines`), or the step it
hides: the height difference across a stretch of cells beside an obstacle or without ground,
between clear ground on both sides (on an edge with no clear ground at all, the ground beside the
obstacle), less what the ground's slope on either side explains (`_steps_across_gaps`; a curb
beside a parked car, or in a stretch the sensor never saw; an end in a cell without ground reads
the gap it stands in, to the first ground up to `BEYOND` metres past it,
`_ground_past_unseen_ends`); its rise (fall) the steepest climb (descent) along its
direction i -> j over 1 m of travel, from the cells' heights (a slope a wheelchair feels), and at
least the steepest climb (descent) of those cells' own planes along it (`_steepest_along`: a curb
read as a ramp over two cells), leaving out the cells beside an obstacle when the edge has others
near both of its ends (`_slope_samples`). How far an edge runs over cells without ground is its
fourth figure, `unobserved_m`: the longest stretch of it (metres) whose cells in the grid hold no
ground, where nothing but the heights on its two sides is known (a curb in it reads only if they
differ), for robot profiles to refuse (terra.tasks.robot). Its fifth, `cross_deg`, is the
steepest slope of the ground across it: the largest |gradient . normal| of the planes of the cells
it crosses whose step and whose neighbours' steps read at most `CROSS_STEP` (a plane fitted across
a curb takes the curb for a slope; the step is the step column's business) and whose
neighbourhood holds ground in at least `CROSS_CELLS` of its nine cells (a plane through three
cells in a near line is no plane), away from obstacles (an object's foot tilted the planes
beside a bench 10 degrees on ground 0.5 degrees steep). A contour across a 13 degree hillside
climbs 6 degrees along the edge and tips a wheelchair 11.5 degrees sideways; the profile's
`max_cross_slope` refuses it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import ndimage

from terra.graph import raster
from terra.graph.grid import OBSTACLE_BAND, OBSTACLE_MIN_POINTS, GridFrame, TerrainGrid
from terra.graph.gvd import EIGHT, component_sizes, label_components
from terra.graph.scene_graph import EDGE_GEOMETRY_COLUMNS
from terra.graph.storage import GROUND_FILES  # prefix of the layer arrays in a bundle

if TYPE_CHECKING:
    from terra.bundle import BundleWriter
    from terra.graph.config import GroundSection
    from terra.mapping.semantic_map import MetricSemanticMap

GROUND_TERRAIN = "ground"  # the terrain class of a map without camera terrain classes
LAYER_UNITS = {
    "cells": "flat cell index row * W + col of each observed cell (cells holding ground points)",
    "height": "m, map frame",
    "gradient": "dz/dx, dz/dy (m/m); slope = atan |gradient|, degrees from horizontal",
    "step": "m",
    "roughness": "m",
}
EDGE_GEOMETRY_UNITS = list(EDGE_GEOMETRY_COLUMNS)  # the columns of each place edge's geometry


def segment_ground(
    points: np.ndarray,
    cell_size: float = 0.5,
    windows: tuple[float, ...] = (1.0, 2.0, 4.0, 8.0),
    slope: float = 0.2,
    base_height: float = 0.1,
    max_height: float = 2.5,
    tolerance: float = 0.15,
    standing_tolerance: float | None = 0.05,
) -> np.ndarray:
    """(N,) bool: which map points (N, 3) (map frame, metres) are ground, by a progressive
    morphological filter on the lowest point per `cell_size` cell (module docstring). `windows`:
    opening widths, metres, increasing; `slope`: m of height allowed per m of window growth;
    `base_height`, `max_height`: the least and most a cell may rise above the opened surface, m;
    `tolerance`: how far above the ground surface (the lowest point of the nearest ground cell) a
    point is still ground, m; `standing_tolerance`: the same in a cell where something stands (a
    point STANDING[0] to STANDING[1] m above the cell's lowest point), at most `tolerance`; None
    for `tolerance` everywhere. A point without a finite position is not ground."""
    pts = _float_points(points)
    if not np.isfinite(pts).all():  # a scan's NaN returns (no echo): judged apart, never ground
        finite = np.isfinite(pts).all(axis=1)
        out = np.zeros(len(pts), dtype=bool)
        out[finite] = segment_ground(
            pts[finite], cell_size, windows, slope, base_height, max_height, tolerance, standing_tolerance
        )
        return out
    if len(pts) == 0:
        return np.zeros(0, dtype=bool)
    cells = _cell_of(pts, np.array([pts[:, 0].min(), pts[:, 1].min()], dtype=np.float64), cell_size)
    W, H = int(cells[:, 0].max()) + 1, int(cells[:, 1].max()) + 1
    flat = cells[:, 1] * W + cells[:, 0]
    del cells
    z = pts[:, 2].astype(np.float64)  # the heights in float64, whatever the points' type
    # float32 relative to the lowest point: the filters below run twice as fast, to 1e-5 m
    base = float(z.min())
    lowest = np.full(H * W, np.inf, dtype=np.float32)
    np.minimum.at(lowest, flat, (z - base).astype(np.float32))
    lowest = lowest.reshape(H, W)
    ground_cell = _ground_cells(lowest, cell_size, windows, slope, base_height, max_height)
    if not ground_cell.any():
        return np.zeros(len(pts), dtype=bool)
    rows, cols = raster.nearest_zero(~ground_cell)
    floor = lowest[rows, cols].ravel().astype(np.float64) + base
    del rows, cols
    allowed = np.full(H * W, tolerance)
    if standing_tolerance is not None:
        allowed[_standing_cells(z - base - lowest.ravel()[flat], flat, H * W)] = min(tolerance, standing_tolerance)
    floor += allowed  # the highest ground height of each cell (the floor's and the allowance's sum, as per point)
    return z <= floor[flat]


def _ground_cells(
    lowest: np.ndarray,
    cell_size: float,
    windows: tuple[float, ...],
    slope: float,
    base_height: float,
    max_height: float,
) -> np.ndarray:
    """(H, W) bool: the cells of the lowest-point surface `lowest` (H, W) (metres, +inf where a cell
    holds no point) that the progressive openings keep as ground (`segment_ground`'s arguments)."""
    has = np.isfinite(lowest)
    rows, cols = raster.nearest_zero(~has)
    surface = lowest[rows, cols]  # empty cells take the nearest lowest point
    del rows, cols
    ground_cell = has
    previous = 0.0
    for width in windows:
        size = max(3, 2 * int(round(width / (2 * cell_size))) + 1)
        opened = np.asarray(ndimage.grey_opening(surface, size=(size, size)))
        allowance = min(base_height + slope * (width - previous), max_height)
        ground_cell &= surface - opened <= allowance
        surface, previous = opened, width
    return ground_cell


def _float_points(points: np.ndarray) -> np.ndarray:
    """Points (N, 3) as an (N, 3) float32 or float64 array: a map's float32 points stay as they
    are, without a float64 copy of the whole map (their coordinates are exact in float64, which
    every computation on them is promoted to); anything else becomes float64."""
    pts = np.asarray(points)
    if pts.dtype not in (np.float32, np.float64):
        pts = pts.astype(np.float64)
    return pts.reshape(-1, 3)


def _cell_of(points: np.ndarray, origin: np.ndarray, cell_size: float) -> np.ndarray:
    """(N, 2) int64 column and row of the `cell_size` cell of each point (N, 3+) (metres) on a
    grid whose cell (0, 0) starts at `origin` (x, y metres, float64): floor((xy - origin) /
    cell_size), in float64 (float32 points are promoted by the float64 origin)."""
    # In place on one (N, 2) copy: numpy's operations on the strided (N, 2) view of an (N, 3) array
    # (a reduction along axis 0 above all) take several times as long as these.
    cells = points[:, :2] - origin
    cells /= cell_size
    return np.floor(cells, out=cells).astype(np.int64)


def _standing_cells(above: np.ndarray, flat: np.ndarray, cells: int) -> np.ndarray:
    """(cells,) bool: cells where something stands, from each point's height (N,) above its cell's
    lowest point and its cell (N,). The foot of what stands in a cell (a car's sills and wheels, a
    bush, a wall's base, a fence) lies within `tolerance` of the ground: on real labelled scans most
    false ground was the lowest 15 cm of vegetation, buildings, cars and fences."""
    standing = np.zeros(cells, dtype=bool)
    standing[flat[(above > STANDING[0]) & (above <= STANDING[1])]] = True
    return standing


@dataclass
class GroundLayers:
    """Ground geometry of the observed cells of a grid frame (module docstring), stored sparsely:
    a kilometre map has tens of millions of cells. cells: (n,) int64 flat indices row * W + col of
    the cells holding ground points, increasing; height (n,) float32 metres; gradient (n, 2)
    float32 dz/dx, dz/dy; step (n,) float32 metres; roughness (n,) float32 metres (NaN where
    unknown); shape (H, W), origin (2,) metres, cell_size metres and offset (row, col) as in
    terra.graph.grid.TerrainGrid."""

    cells: np.ndarray
    height: np.ndarray
    gradient: np.ndarray
    step: np.ndarray
    roughness: np.ndarray
    shape: tuple[int, int]
    origin: np.ndarray
    cell_size: float
    offset: tuple[int, int] = (0, 0)
    # (n,) bool, in memory only (not stored): cells within a few cells of a blocked cell (grid_layers),
    # whose heights may be an object's lowest points; None where no obstacle is known.
    near_obstacle: np.ndarray | None = None
    # (H, W) bool, in memory only: lines of steps (step_lines) that split a LiDAR-only ground's GVD;
    # an edge over one climbs at least `line_step` metres (edge_geometry). None: no lines.
    lines: np.ndarray | None = None
    line_step: float = 0.0
    # In memory only: the cells (indices into the layers) whose step across a gap is left to the
    # gap's high edge (held_across_gaps), and the step (metres) each read before; None: none. Kept
    # for the cells alone: a copy of the whole step layer costs 4 bytes a cell on a kilometre map.
    held_cells: np.ndarray | None = None
    held_step: np.ndarray | None = None

    @property
    def slope(self) -> np.ndarray:
        """(n,) degrees from the horizontal (NaN where the gradient is unknown)."""
        return np.degrees(np.arctan(np.hypot(self.gradient[:, 0], self.gradient[:, 1])))

    @property
    def observed(self) -> np.ndarray:
        """(H, W) bool: the cells holding ground points."""
        out = np.zeros(self.shape[0] * self.shape[1], dtype=bool)
        out[self.cells] = True
        return out.reshape(self.shape)

    def as_grid(self, values: np.ndarray) -> np.ndarray:
        """(H, W, ...) float64 grid of per-cell `values` (n, ...), NaN on unobserved cells."""
        values = np.asarray(values, dtype=np.float64)
        out = np.full((self.shape[0] * self.shape[1],) + values.shape[1:], np.nan)
        out[self.cells] = values
        return out.reshape(self.shape + values.shape[1:])

    def flat_cells(self, xy: np.ndarray) -> np.ndarray:
        """(m,) flat cell index row * W + col of each map-frame point (m, 2+) (metres), -1 where
        it lies outside the grid."""
        H, W = self.shape
        rc = np.floor((np.asarray(xy, dtype=np.float64)[:, :2] - self.origin) / self.cell_size).astype(np.int64)
        rows, cols = rc[:, 1] - self.offset[0], rc[:, 0] - self.offset[1]
        inside = (rows >= 0) & (rows < H) & (cols >= 0) & (cols < W)
        return np.where(inside, rows * W + cols, -1)

    def lookup(self, xy: np.ndarray) -> np.ndarray:
        """(m,) index into the observed cells of each map-frame point (m, 2+) (metres), -1 where
        its cell is outside the grid or holds no ground."""
        return self.observed_index(self.flat_cells(xy))

    def observed_index(self, flat: np.ndarray) -> np.ndarray:
        """(m,) index into the observed cells of flat cell indices (m,) (`flat_cells`), -1 where
        the cell is -1 (outside the grid) or holds no ground."""
        if len(self.cells) == 0:
            return np.full(len(flat), -1, dtype=np.int64)
        at = np.minimum(np.searchsorted(self.cells, flat), len(self.cells) - 1)
        return np.where((flat >= 0) & (self.cells[at] == flat), at, -1)

    def centres(self, index: np.ndarray) -> np.ndarray:
        """(m, 2) map-frame x, y (metres) of the centres of observed cells `index` (m,)."""
        flat = self.cells[np.asarray(index, dtype=np.int64)]
        rows, cols = flat // self.shape[1] + self.offset[0], flat % self.shape[1] + self.offset[1]
        return self.origin + (np.column_stack([cols, rows]).astype(np.float64) + 0.5) * self.cell_size

    def fitted_gradient(self, index: np.ndarray) -> np.ndarray:
        """(m, 2) float64 gx, gy (m/m) of the observed cells `index` (m,), NaN where unknown or
        steeper than `STEEPEST_FIT`: such a plane was fitted on cells nearly in a line (the layers
        keep its cell's mean height, not carried along it), not on the ground's slope. A cell beside
        a bench on the simulated LiDAR-only campus fitted a plane 80 degrees steep on level ground,
        and an edge past it read a 70 degree rise; ground that steep shows in the heights around it."""
        gradient = self.gradient[np.asarray(index, dtype=np.int64)].astype(np.float64)
        with np.errstate(invalid="ignore"):
            steep = np.hypot(gradient[:, 0], gradient[:, 1]) > STEEPEST_FIT
        gradient[steep] = np.nan
        return gradient

    def height_at(self, index: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """(m,) float64 metres: the ground height at map-frame points `xy` (m, 2) (metres) in the
        observed cells `index` (m,): each cell's height carried along its gradient (level where
        the gradient is unknown or no slope of the ground, `fitted_gradient`) from the cell's
        centre to the point."""
        tilt = np.nan_to_num(self.fitted_gradient(index))
        return self.height[index] + (tilt * (np.asarray(xy, dtype=np.float64) - self.centres(index))).sum(axis=1)

    def info(self) -> dict[str, Any]:
        """The manifest's description of the layers (components.graph.ground)."""
        return {
            "origin": [float(v) for v in self.origin],
            "cell_size": float(self.cell_size),
            "offset": [int(v) for v in self.offset],
            "shape": [int(v) for v in self.shape],
            "observed_cells": len(self.cells),
            "units": dict(LAYER_UNITS),
            "edge_geometry": list(EDGE_GEOMETRY_UNITS),
        }


STANDING = (0.3, 2.0)  # metres above a cell's lowest point: something stands there (the grid's obstacle band)
# Steepest plane (|gradient|, 45 degrees) along which a cell's mean height is carried to its centre.
# Steeper fits come from three or four cells nearly on a line (the ground beside a pole or a wall):
# carried 20 cm off its centroid such a plane put a flat cell 86 cm below its neighbours, a step
# that cut places off; ground that steep is no one's route, and its mean height is as good.
STEEPEST_FIT = 1.0
# metres: a cell whose step reads more than this holds a step (a curb), and its plane, fitted across
# the step, is no slope across an edge (edge_geometry's cross slope).
CROSS_STEP = 0.05
CROSS_CELLS = 6  # of the 9 cells of a neighbourhood with ground, for its plane to tell a slope across
# metres: a cell across a gap whose height lies this far inside the heights on its two sides stands
# on the step (its points are of both levels), which it reads itself (_bridge_gaps).
STRADDLE = 0.02
SPIKE = 0.03  # metres a cell may stand above or below all its neighbours before `despike` replaces it
BESIDE = 2  # cells next to a blocked cell whose step is unknown (grid_layers)
POINT_CHUNK = 1 << 22  # map points read at once by `block_above_ground`
SLOPE_BASELINE = 1.0  # metres of travel an edge's rise and fall are measured over
BEYOND = 2.0  # metres past an edge's end without ground its line is read for ground (_ground_past_unseen_ends)
# Cells per band of rows computed at once: its temporaries stay in the CPU caches (2x faster than 4M),
# about 185 bytes a cell at their peak; 2^16 to 2^18 take the same time on the campus map.
BAND_CELLS = 1 << 17
# Rows a cell's layers read on each side: the step reads heights up to BRIDGE + 1 rows away, each the
# median of heights 1 row further, each moved to its cell's centre by a gradient reading 1 row further.
# Cells a step may look across for the nearest observed height (axis_step): a 15 cm curb seen from its
# top hid three cells of road in its shadow on the simulated campus (heights four cells apart), which
# a reach of three left unread.
BRIDGE = 4
CONTEXT = BRIDGE + 3
STEP_LINE_CELLS = 3  # cells of a line of steps that splits a LiDAR-only ground's GVD (step_lines): 1.2 m at 0.4 m
STEP_LINE_CLOSE = 1  # closing iterations of those lines: gaps of up to 2 cells (0.8 m) filled; a curb cut is 3 m


def ground_layers(points: np.ndarray, frame: GridFrame, band_cells: int = BAND_CELLS) -> GroundLayers:
    """The layers of the ground points (n, 3) (map frame, metres) on `frame` (points outside it
    are left out), computed in bands of rows of about `band_cells` cells with CONTEXT rows on each
    side, so memory follows the band, not the grid."""
    H, W = frame.shape
    s = float(frame.cell_size)
    origin = np.asarray(frame.origin, dtype=np.float64)
    pts = _float_points(points)
    rc = _cell_of(pts, origin, s)
    rows, cols = rc[:, 1] - frame.offset[0], rc[:, 0] - frame.offset[1]
    inside = np.flatnonzero((rows >= 0) & (rows < H) & (cols >= 0) & (cols < W))
    del rows, cols
    # The points inside, by row: numpy sorts 16-bit integers by radix, several times faster.
    key = rc[inside, 1] - frame.offset[0]
    order = inside[np.argsort(key.astype(np.int16) if H < 1 << 15 else key, kind="stable")]
    del inside, key
    rc, ordered = rc[order], pts[order]
    del order
    rows, cols, z = rc[:, 1] - frame.offset[0], rc[:, 0] - frame.offset[1], ordered[:, 2].astype(np.float64)
    # Where each point lies in its cell, metres from the centre: the mean height of a cell is
    # that of its points' centroid, which on a slope is not the centre's.
    within = (ordered[:, :2] - origin) - (rc + 0.5) * s
    del rc, ordered
    reference = float(z.mean()) if len(z) else 0.0  # one for every band: bands equal the whole
    band = max(1, band_cells // max(W, 1))
    parts: list[tuple[np.ndarray, ...]] = []
    for r0 in range(0, H, band):
        r1 = min(H, r0 + band)
        lo, hi = max(0, r0 - CONTEXT), min(H, r1 + CONTEXT)
        sel = slice(int(np.searchsorted(rows, lo)), int(np.searchsorted(rows, hi)))
        if sel.start == sel.stop:
            continue
        # Only the columns within CONTEXT of the band's points: the cells beyond hold no ground and
        # reach no kept cell (on the campus map a band's points span 35 to 95 % of its width).
        c0, c1 = max(0, int(cols[sel].min()) - CONTEXT), min(W, int(cols[sel].max()) + 1 + CONTEXT)
        shape, keep = (hi - lo, c1 - c0), slice(r0 - lo, r1 - lo)
        observed, *layers = _band_layers(rows[sel] - lo, cols[sel] - c0, z[sel], within[sel], shape, s, reference, keep)
        row, col = np.divmod(observed, c1 - c0)
        # Stored as float32 band by band: the whole map's float64 layers are never held at once.
        parts.append(((r0 + row) * W + col + c0, *(layer.astype(np.float32) for layer in layers)))
    del rows, cols, z, within
    cells, height, gradient, step, roughness = (
        np.concatenate([p[k] for p in parts]) if parts else np.zeros(0, np.float32) for k in range(5)
    )
    parts.clear()
    return GroundLayers(
        cells.astype(np.int64, copy=False),
        height.reshape(-1),
        gradient.reshape(-1, 2),
        step.reshape(-1),
        roughness.reshape(-1),
        (int(H), int(W)),
        origin,
        s,
        frame.offset,
    )


def _band_layers(
    rows: np.ndarray,
    cols: np.ndarray,
    z: np.ndarray,
    within: np.ndarray,
    shape: tuple[int, int],
    cell_size: float,
    reference: float,
    keep: slice,
) -> tuple[np.ndarray, ...]:
    """The observed cells of the rows `keep` of one band (h, w) (flat indices (n,) row * w + col
    from the first kept row) and their height (n,), gradient (n, 2), step (n,) and roughness (n,),
    from the band-local cells (rows, cols), heights z and offsets from their cell's centre `within`
    (n, 2) (x, y metres) of its ground points; `reference`: plane_fit's reference height, metres."""
    h, w = shape
    flat = rows * w + cols
    count = np.bincount(flat, minlength=h * w).reshape(h, w).astype(np.float64)
    # float64 also for a band without points (bincount of nothing gives int64)
    total = np.bincount(flat, weights=z, minlength=h * w).reshape(h, w).astype(np.float64, copy=False)
    observed = count > 0
    mean = np.divide(total, count, out=np.zeros_like(total), where=observed)
    centroid = [
        np.divide(bins, count, out=np.zeros_like(bins), where=observed)
        for bins in (
            np.bincount(flat, weights=within[:, k], minlength=h * w).reshape(h, w).astype(np.float64, copy=False)
            for k in (0, 1)
        )
    ]
    # Each cell's height at its centre: its mean height carried along the gradient of the plane
    # through its neighbourhood's mean heights, each where its points' centroid lies (exact on a
    # plane); that plane's gradient is the cell's.
    centred, first = plane_fit(np.where(observed, mean, np.nan), cell_size, (centroid[0], centroid[1]), reference)
    moved = mean - np.nan_to_num(first[..., 0]) * centroid[0] - np.nan_to_num(first[..., 1]) * centroid[1]
    with np.errstate(invalid="ignore"):  # NaN gradients compare False: those cells keep their mean
        carried = np.isfinite(centred) & (np.hypot(first[..., 0], first[..., 1]) <= STEEPEST_FIT)
    height = despike(np.where(observed, np.where(carried, moved, mean), np.nan))
    # Everything below is per cell: computed on the kept observed cells only.
    cells = np.flatnonzero(observed[keep])
    at = cells + (keep.start or 0) * w
    gradient = first.reshape(h * w, 2)[at]
    r, c = np.divmod(at, w)
    rise = np.abs((gradient * cell_size).astype(np.float64))  # metres per cell along x, y
    step = np.fmax(steps_at(height, (r, c), rise[:, 0]), steps_at(height.T, (c, r), rise[:, 1]))
    tilt = np.nan_to_num(gradient[:, 0] ** 2 + gradient[:, 1] ** 2) * cell_size**2 / 12.0
    n, mean_at = count.ravel()[at], mean.ravel()[at]
    squares = np.bincount(flat, weights=z * z, minlength=h * w).astype(np.float64, copy=False)[at]
    roughness = np.sqrt(np.maximum(squares / n - mean_at**2 - tilt, 0.0))
    return cells, height.ravel()[at], gradient, step, roughness


def despike(height: np.ndarray, tolerance: float = SPIKE) -> np.ndarray:
    """(H, W): each observed (finite) height that lies more than `tolerance` metres above or below
    all of its observed 4-neighbours (at least three) replaced by their median. One stray point (a
    car's sill taken for ground, a cell of one point) then makes no step and no edge slope, while an
    edge (a curb: every cell beside it has a neighbour on each level), a plane and a smooth hill
    (a cell between its neighbours, or within centimetres of them) keep their heights."""
    padded = np.pad(height, 1, constant_values=np.nan)
    around = [padded[:-2, 1:-1], padded[2:, 1:-1], padded[1:-1, :-2], padded[1:-1, 2:]]
    known = sum(np.isfinite(a).astype(np.int8) for a in around)
    lowest = np.fmin(np.fmin(around[0], around[1]), np.fmin(around[2], around[3]))
    highest = np.fmax(np.fmax(around[0], around[1]), np.fmax(around[2], around[3]))
    with np.errstate(invalid="ignore"):  # NaN compares False: cells without neighbours stay
        spike = (known >= 3) & ((height > highest + tolerance) | (height < lowest - tolerance))
    out = height.copy()
    if spike.any():  # rare: the median only where it is needed
        rows, cols = np.nonzero(spike)
        neighbours = np.stack([a[rows, cols] for a in around])  # (4, k), NaN sorts last
        neighbours.sort(axis=0)
        count = np.isfinite(neighbours).sum(axis=0)
        pick = np.arange(len(rows))
        out[rows, cols] = (neighbours[(count - 1) // 2, pick] + neighbours[count // 2, pick]) / 2
    return out


def _taps(values: np.ndarray, kind: str, axis: int) -> np.ndarray:
    """One 3-tap correlation of `values` along `axis`, zero outside: out[i] = a values[i - 1] +
    b values[i] + c values[i + 1] with (a, b, c) = (1, 1, 1) for "one", (-1, 0, 1) for "odd",
    (1, 0, 1) for "even" (slices, not a general filter: these are most of the layers' time; they
    keep the values' memory layout, where a copy of an axis moved to the front transposed it)."""
    lower = tuple(slice(None, -1) if a == axis else slice(None) for a in range(values.ndim))
    upper = tuple(slice(1, None) if a == axis else slice(None) for a in range(values.ndim))
    first = tuple(slice(0, 1) if a == axis else slice(None) for a in range(values.ndim))
    # Each term written where a copy or zeros and an update in place read and wrote twice; the
    # same operations on the same operands (values[i] + values[i - 1], 0 + values[i - 1], ...).
    out = np.empty_like(values)
    if kind == "one":
        out[first] = values[first]
        np.add(values[upper], values[lower], out=out[upper])
    else:
        out[first] = 0.0
        (np.subtract if kind == "odd" else np.add)(0.0, values[lower], out=out[upper])
    out[lower] += values[upper]
    return out


def _window_sums(values: np.ndarray, along_y: str, along_x: str) -> np.ndarray:
    """The 3 x 3 window sums of values weighted by the taps (`_taps`) along y (rows) and x (columns)."""
    return _taps(_taps(values, along_y, 0), along_x, 1)


def _row_passes(values: np.ndarray, *kinds: str) -> list[np.ndarray]:
    """`_taps` of values along y (rows) for each kind: the first half of `_window_sums`, shared by
    the sums that differ only along x."""
    return [_taps(values, kind, 0) for kind in kinds]


def plane_fit(
    height: np.ndarray,
    cell_size: float,
    offset: tuple[np.ndarray, np.ndarray] | None = None,
    reference: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares plane z = a + gx dx + gy dy through the observed (finite) heights (H, W)
    of each cell's 3 x 3 neighbourhood, dx, dy (metres) from the cell's centre to where each
    height was measured: the cells' centres, moved by `offset` (x (H, W), y (H, W) metres from
    each cell's centre) when given. Returns a (H, W), the plane's height at the cell's centre, and
    (H, W, 2) gx, gy (m/m); NaN where fewer than three cells, or only collinear ones, are observed.
    `reference`: a height (metres) near the heights, subtracted before the float32 sums (default
    their mean; pass one for the whole map so that bands of it give the same results)."""
    # float32 on heights relative to the area's mean: twice as fast as float64, and the terms of
    # the solution stay within 1e-5 of their size (heights within tens of metres of the mean).
    w = np.isfinite(height).astype(np.float32)
    if reference is None:
        reference = float(np.nanmean(height)) if w.any() else 0.0
    relative = np.nan_to_num(height - reference).astype(np.float32)
    wh = w * relative
    one, odd, even = "one", "odd", "even"
    s1, s2 = cell_size, cell_size * cell_size
    w_one, w_odd, w_even = _row_passes(w, one, odd, even)
    wh_one, wh_odd = _row_passes(wh, one, odd)
    n, sx, sxx = _taps(w_one, one, 1), _taps(w_one, odd, 1) * s1, _taps(w_one, even, 1) * s2
    sy, sxy, syy = _taps(w_odd, one, 1) * s1, _taps(w_odd, odd, 1) * s2, _taps(w_even, one, 1) * s2
    sz, szx, szy = _taps(wh_one, one, 1), _taps(wh_one, odd, 1) * s1, _taps(wh_odd, one, 1) * s1
    if offset is not None:
        sx, sy, sxx, syy, sxy, szx, szy = _offset_sums(w, relative, offset, s1, (sx, sy, sxx, syy, sxy, szx, szy))
    # Cramer's rule on the 3 x 3 normal equations, cell by cell; the 2 x 2 minors that two
    # determinants share are computed once.
    syy_xx = sxx * syy - sxy * sxy
    x_yy = sx * syy - sxy * sy
    x_xy = sx * sxy - sxx * sy
    zx_yy = szx * syy - sxy * szy
    x_zy = sx * szy - szx * sy
    det = n * syy_xx - sx * x_yy + sy * x_xy
    det_a = sz * syy_xx - sx * zx_yy + sy * (szx * sxy - sxx * szy)
    det_x = n * zx_yy - sz * x_yy + sy * x_zy
    det_y = n * (sxx * szy - szx * sxy) - sx * x_zy + sz * x_xy
    solvable = (n >= 3) & (np.abs(det) > 1e-9 * cell_size**4)  # det ~ n^3 s^4; collinear: rounding
    safe = np.where(solvable, det, 1.0)
    intercept = np.where(solvable, det_a / safe + reference, np.nan)
    gradient = np.stack([np.where(solvable, det_x / safe, np.nan), np.where(solvable, det_y / safe, np.nan)], axis=-1)
    return intercept, gradient


def _offset_sums(
    w: np.ndarray,
    relative: np.ndarray,
    offset: tuple[np.ndarray, np.ndarray],
    s1: float,
    centred: tuple[np.ndarray, ...],
) -> tuple[np.ndarray, ...]:
    """plane_fit's window sums sx, sy, sxx, syy, sxy, szx, szy (`centred`, from the cells' centres)
    with each height measured at its cell's centre moved by `offset` (x, y (H, W) metres): dx =
    column offset + ex, dy = row offset + ey, expanded (w (H, W) is 0 or 1; `relative` (H, W) the
    heights less the reference, metres; s1 the cell size, metres)."""
    sx, sy, sxx, syy, sxy, szx, szy = centred
    one, odd = "one", "odd"
    ex, ey = (w * np.nan_to_num(o).astype(np.float32) for o in offset)
    ex_one, ex_odd = _row_passes(ex, one, odd)
    ey_one, ey_odd = _row_passes(ey, one, odd)
    sx, sy = sx + _taps(ex_one, one, 1), sy + _taps(ey_one, one, 1)
    sxx = sxx + 2 * s1 * _taps(ex_one, odd, 1) + _window_sums(ex * ex, one, one)
    syy = syy + 2 * s1 * _taps(ey_odd, one, 1) + _window_sums(ey * ey, one, one)
    sxy = sxy + s1 * (_taps(ey_one, odd, 1) + _taps(ex_odd, one, 1)) + _window_sums(ex * ey, one, one)
    hx, hy = ex * relative, ey * relative
    szx, szy = szx + _window_sums(hx, one, one), szy + _window_sums(hy, one, one)
    return sx, sy, sxx, syy, sxy, szx, szy


def axis_step(height: np.ndarray, axis: int, rise: np.ndarray | None = None) -> np.ndarray:
    """(H, W) metres: the step at each cell along one axis (module docstring), NaN where the two
    cells beside it are not both observed. Where neither outer neighbour is observed (holes of a
    sparse map), the local slope comes from `rise` (H, W), metres of height per cell along the
    axis (the plane's gradient x cell size), and the step is unknown (NaN) where that is NaN too;
    without `rise`, such a cell's surroundings count as level. With `rise`, a step unknown for a
    missing neighbour is read across the gap (`_bridge_gaps`)."""
    h = np.moveaxis(np.asarray(height, dtype=np.float64), axis, -1)
    at = tuple(np.indices(h.shape).reshape(h.ndim, -1))
    level = None
    if rise is not None:
        level = np.abs(np.moveaxis(np.asarray(rise, dtype=np.float64), axis, -1)[at])
    return np.moveaxis(steps_at(h, at, level).reshape(h.shape), -1, axis)


def steps_at(
    h: np.ndarray, at: tuple[np.ndarray, ...], level: np.ndarray | None = None, past: np.ndarray | None = None
) -> np.ndarray:
    """(m,) metres: `axis_step` along the last axis of heights h (..., n) (metres, NaN where
    unobserved) at the cells `at` (index arrays (m,), one per axis of h), with `level` (m,) the
    cells' |rise| (metres per cell) or None. The layers keep only observed cells (28 % of the campus
    grid's): reading each one's five heights along the axis at once costs less than passes over
    the whole raster, and the heights up to `BRIDGE` + 1 cells away only for the cells beside a
    gap (`_bridge_gaps`), which asks whether the cell across a gap stands on the step of the
    heights `past` (shaped as h; h itself by default)."""
    reach, n = BRIDGE + 1, h.shape[-1]
    # float64 (the layers store float32), padded with `reach` unobserved cells at both ends of the
    # axis: the heights around the cells are one gather, without clipping and masking at the ends.
    padded = np.full(h.shape[:-1] + (n + 2 * reach,), np.nan)
    padded[..., reach : n + reach] = h
    lead = np.ravel_multi_index(at[:-1], h.shape[:-1]) if h.ndim > 1 else np.zeros_like(at[-1])
    centre = lead * (n + 2 * reach) + at[-1] + reach  # each cell's index in the flat padded heights
    flat = padded.reshape(-1)
    before2, before, middle, after, after2 = (flat[centre + k] for k in (-2, -1, 0, 1, 2))
    jump = np.abs(after - before)
    # The local slope: the steeper side's (a ramp's ends, where its slope meets the level, read no step).
    outer = np.fmax(np.abs(before - before2), np.abs(after2 - after))
    # Where neither side is observed, the cell's own |rise|: unknown (NaN) where the neighbourhood
    # does not fix a plane either; level without it.
    outer = np.where(np.isfinite(outer), outer, 0.0 if level is None else level)
    step = np.where(np.isfinite(jump), np.maximum(jump - 2.0 * outer, 0.0), np.nan)
    if level is not None:
        gaps = np.flatnonzero(np.isfinite(middle) & np.isnan(step))
        window = centre[gaps, None] + np.arange(-reach, reach + 1)
        around = flat[window]
        if past is not None:  # padded is no longer needed: it now holds the heights `past`
            padded[..., reach : n + reach] = past
        step[gaps] = _bridge_gaps(around, level[gaps], past=flat[window])
    return step


def _side_slope(before: np.ndarray, after: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mean of the height differences (metres) on the two sides of each cell, `before` and
    `after` (same shapes), where known (0 where neither is), and where either is known (bool)."""
    known_before, known_after = np.isfinite(before), np.isfinite(after)
    total = np.where(known_before, before, 0.0) + np.where(known_after, after, 0.0)
    count = np.add(known_before, known_after, dtype=np.int8)
    return total / np.maximum(count, 1), known_before | known_after


def _bridge_gaps(
    around: np.ndarray, rise: np.ndarray, bridge: int = BRIDGE, past: np.ndarray | None = None
) -> np.ndarray:
    """(m,) metres: the step of observed cells whose step is unknown because a neighbour holds no
    ground (NaN where it stays unknown), from their heights `around` (m, 2 reach + 1) along the
    axis (the cell in the middle, reach > bridge): the height difference between the nearest
    observed cells within `bridge` cells on each side, less what the ground's slope explains over
    the cells between them, floored at 0. The slope is the mean of the differences just beyond
    those two cells (each with its next cell outwards, where observed; not the steeper of the two,
    as `steps_at` reads a cell's own sides), else the cell's own (`rise` (m,), metres per cell): a
    curb's low side lies in its own LiDAR shadow (the road within a few decimetres of it holds no
    point when seen from the walk), which left every curb seen from its top unknown, and the plane
    fitted at a cell on the curb's face takes the curb for a slope.

    A side whose nearest observed cell lies across a gap and stands on the step itself (its height
    between the cell's and the next observed height beyond it, more than `STRADDLE` from each:
    the cell holds both levels, a curb's face) is read as level with the cell: that cell reads the
    step, and the gap lies before it. Read here too, the step landed on the cell at the gap's edge,
    80 cm from a simulated curb, and on every edge running along that cell. The height beyond it
    is read from `past` (shaped as around; around itself by default): `steps_clear_of` bridges to
    no blocked cell, yet the lowest points of one still tell whether the cell before it stands on
    a step (a simulated curb top 1.6 m from a place, beside a parked car, read 9 cm without)."""
    centre, m = around.shape[1] // 2, len(around)
    middle = around[:, centre]
    sides = []
    for sign in (-1, 1):
        value, distance, beyond = np.full(m, np.nan), np.zeros(m), np.full(m, np.nan)
        for k in range(bridge, 0, -1):  # the nearest observed cell wins
            v, w = around[:, centre + sign * k], around[:, centre + sign * (k + 1)]
            found = np.isfinite(v)
            value, distance, beyond = (
                np.where(found, v, value),
                np.where(found, k, distance),
                np.where(found, w, beyond),
            )
        further = _next_observed(around if past is None else past, sign, distance)
        on_step = (distance > 1) & _straddles(value, middle, further)
        sides.append(
            (
                np.where(on_step, middle, value),
                np.where(on_step, 0, distance),
                np.where(on_step, np.nan, np.abs(beyond - value)),
            )
        )
    (before, db, out_b), (after, da, out_a) = sides
    outer, known = _side_slope(out_b, out_a)
    slope = np.where(known, outer, rise)
    bridged = np.maximum(np.abs(after - before) - (da + db) * slope, 0.0)
    return np.where(np.isfinite(before) & np.isfinite(after) & np.isfinite(slope), bridged, np.nan)


def _next_observed(around: np.ndarray, sign: int, distance: np.ndarray) -> np.ndarray:
    """(m,) metres: the first observed height of `around` (m, 2 reach + 1) more than `distance`
    (m,) cells from the middle on the side `sign` (-1, 1), NaN where none within reach."""
    centre = around.shape[1] // 2
    out = np.full(len(around), np.nan)
    for k in range(centre, 0, -1):  # the nearest wins
        v = around[:, centre + sign * k]
        out = np.where((k > distance) & np.isfinite(v), v, out)
    return out


def _straddles(value: np.ndarray, a: np.ndarray, b: np.ndarray, margin: float = STRADDLE) -> np.ndarray:
    """(m,) bool: `value` lies between `a` and `b` (metres), more than `margin` from each."""
    return ((value - a) * (b - value) > 0) & (np.minimum(np.abs(value - a), np.abs(b - value)) > margin)


def edge_geometry(
    layers: GroundLayers,
    position: np.ndarray,
    edges: np.ndarray,
    baseline: float = SLOPE_BASELINE,
    unseen_ends: bool = True,
) -> np.ndarray:
    """(E, 5) float32 per place edge (E, 2) between places at `position` (P, 3+) (map frame,
    metres): the largest step it crosses (m), its steepest rise and fall going from edges[:, 0] to
    edges[:, 1] (degrees, >= 0) over `baseline` metres of travel (the whole edge when shorter),
    from the ground heights along it, and at least the cells' own gradients along it (0 where the
    cells along it hold no ground), the longest stretch of it over cells of the grid that hold no
    ground (m), and the steepest slope across it (degrees, >= 0) of the planes of the cells it
    crosses that neither hold a step nor lie beside one or an obstacle, on enough ground (module
    docstring). With `unseen_ends`, an end whose cell (inside the layers' grid) holds no ground
    steps across the gap it stands in, to the ground past it (`_ground_past_unseen_ends`), or
    where none lies there by the difference between its place's height and the first ground along
    the edge (`_unseen_end_steps`); callers whose `position` carries no heights pass False."""
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    E = len(edges)
    if E == 0:
        return np.zeros((0, len(EDGE_GEOMETRY_COLUMNS)), dtype=np.float32)
    a = np.asarray(position, dtype=np.float64)[edges[:, 0], :2]
    delta = np.asarray(position, dtype=np.float64)[edges[:, 1], :2] - a
    length = np.linalg.norm(delta, axis=1)
    samples = np.ceil(length / (layers.cell_size / 2)).astype(np.int64) + 1
    starts = np.concatenate([[0], np.cumsum(samples)[:-1]])
    edge = np.repeat(np.arange(E), samples)
    t = (np.arange(int(samples.sum())) - starts[edge]) / np.maximum(samples[edge] - 1, 1)
    point = a[edge] + t[:, None] * delta[edge]
    flat = layers.flat_cells(point)
    at = layers.observed_index(flat)
    known = at >= 0
    unobserved = _longest_unobserved(known | (flat < 0), starts, length / np.maximum(samples - 1, 1))
    if len(layers.cells) == 0:
        return np.column_stack([np.zeros((E, 3)), unobserved, np.zeros(E)]).astype(np.float32)
    step = _sampled_steps(layers, at, flat)
    travelled = t * length[edge]
    clear, heights = _slope_samples(layers, at, edge, travelled, length, baseline)
    # The ground's height at each sample: its cell's, carried along the cell's gradient.
    height = layers.height_at(at[heights], point[heights])
    rise = _rise_along(edge[heights], travelled[heights], height, E, baseline)
    unit = delta / np.maximum(length, 1e-9)[:, None]
    along = np.where(known, (layers.fitted_gradient(np.maximum(at, 0)) * unit[edge]).sum(axis=1), np.nan)
    rise = np.fmax(rise, _steepest_along(edge[heights], along[heights], E))
    cross = _steepest_across(layers, SampleCells(at, flat, step, edge), clear, unit, E)
    largest = np.fmax.reduceat(step, starts)
    if unseen_ends:
        z = np.asarray(position, dtype=np.float64)[:, 2]
        profile = _gap_profile(edge, travelled, height, along, clear, heights, E)
        ends = EdgeEnds(starts, samples, length)
        past = _ground_past_unseen_ends(layers, a, unit, ends, known, flat)
        beyond = past.ends_beyond(length)
        largest = np.fmax(largest, _unseen_end_steps(layers, at, flat, ends, z[edges], beyond))
        profile = profile.with_place_ends(known, along, ends, z[edges], past)
        largest = np.fmax(largest, _steps_across_gaps(profile, E, layers.cell_size, baseline))
    out = np.column_stack([largest, np.degrees(np.arctan(rise)), unobserved, np.degrees(np.arctan(cross))])
    return np.maximum(np.nan_to_num(out, nan=0.0), 0.0).astype(np.float32)


def _gap_profile(
    edge: np.ndarray,
    travelled: np.ndarray,
    height: np.ndarray,
    along: np.ndarray,
    clear: np.ndarray,
    heights: np.ndarray,
    edges: int,
) -> EdgeProfile:
    """The ground along each of the `edges` edges that its gaps' steps are read on (`_steps_across_gaps`): its
    `clear` (S,) samples (`_slope_samples`) or, on an edge with none, every sample its slope is
    read on (`heights` (S,), whose ground `height` (h,) metres holds): a curb whose top lies beside
    a bench all along reads across the gap before it rather than not at all (on the simulated
    LiDAR-only small site, seed 1, a 15 cm curb read 0.5 cm). `edge` (S,) each sample's edge,
    `travelled` (S,) metres from its start, `along` (S,) the gradient along it."""
    read = clear | (heights & (np.bincount(edge[clear], minlength=edges) == 0)[edge])
    return EdgeProfile(edge[read], travelled[read], height[read[heights]], along[read])


def _sampled_steps(layers: GroundLayers, at: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """(S,) metres: the step layer at samples whose observed cell is `at` (S,) (-1: none, NaN) and
    grid cell `flat` (S,) (-1: outside), at least the layers' `line_step` on their lines of steps."""
    step = np.where(at >= 0, layers.step[at], np.nan)
    if layers.lines is not None:  # a line of steps: its cells read unevenly, or not at all in its shadow
        on_line = (flat >= 0) & layers.lines.ravel()[np.maximum(flat, 0)]
        step = np.where(on_line, np.fmax(step, layers.line_step), step)
    return step


@dataclass
class SampleCells:
    """What edge_geometry knows of its samples' cells: the observed cell `at` (S,) (-1: none), the
    grid cell `flat` (S,) (-1: outside the grid), the step read there `step` (S,) metres (NaN:
    unknown) and the edge `edge` (S,) each sample belongs to."""

    at: np.ndarray
    flat: np.ndarray
    step: np.ndarray
    edge: np.ndarray


def _steepest_across(
    layers: GroundLayers, samples: SampleCells, clear: np.ndarray, unit: np.ndarray, edges: int
) -> np.ndarray:
    """(E,) m/m: the steepest slope across each edge (direction `unit` (E, 2)) of the planes of
    its samples' cells that are `clear` (S,) of obstacles, hold no step above CROSS_STEP and whose
    plane tells a slope across (`_plane_across_holds`); 0 where none does."""
    normal = np.column_stack([-unit[:, 1], unit[:, 0]])
    level = clear & (np.nan_to_num(samples.step, nan=np.inf) <= CROSS_STEP)
    cells, inverse = np.unique(samples.flat[level], return_inverse=True)  # two samples a cell: judge each once
    level[level] = _plane_across_holds(layers, cells)[inverse]
    edge = samples.edge[level]
    across = np.abs((layers.gradient[samples.at[level]] * normal[edge]).sum(axis=1))
    return _steepest_along(edge, across, edges)[:, 0]  # its "rise": the largest per edge


def _plane_across_holds(layers: GroundLayers, flat: np.ndarray) -> np.ndarray:
    """(m,) bool: grid cells `flat` (m,) (inside the grid) whose plane, fitted on their 3 x 3
    neighbourhood, tells the slope across an edge: at least CROSS_CELLS of its cells hold ground
    (a plane through three cells, nearly in a line, read 22 degrees on ground 0.5 degrees steep)
    and none of its neighbours' steps reads more than CROSS_STEP metres (`_sampled_steps`: a cell
    on a curb's top beside the cell the curb runs through read 8.5 degrees across an edge along
    the curb)."""
    H, W = layers.shape
    rows, cols = flat // W, flat % W
    observed = np.zeros(len(flat), dtype=np.int64)
    beside = np.zeros(len(flat), dtype=bool)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            r, c = rows + dr, cols + dc
            near = np.where((r >= 0) & (r < H) & (c >= 0) & (c < W), r * W + c, -1)
            at = layers.observed_index(near)
            observed += at >= 0
            if dr != 0 or dc != 0:
                beside |= np.nan_to_num(_sampled_steps(layers, at, near), nan=0.0) > CROSS_STEP
    return (observed >= CROSS_CELLS) & ~beside


def _slope_samples(
    layers: GroundLayers, at: np.ndarray, edge: np.ndarray, travelled: np.ndarray, length: np.ndarray, baseline: float
) -> tuple[np.ndarray, ...]:
    """(S,) bool twice: the samples (observed cell `at` (S,), -1 for none; edge index `edge` (S,)
    of the edges of `length` (E,) metres, `travelled` (S,) metres from its start) on ground clear
    of obstacles, and those an edge's slope is read on. Beside an object the lowest points may be
    the object's (a bench's feet read as a bump of a few centimetres, a 10 degree slope on a 5
    degree lawn): an edge's slope is read on the samples away from obstacles when it has two and
    some within `baseline` metres of each end, else on all it has. Clear samples at one end only
    say nothing of the rest: an edge from the top of a curb down past a planter beside it, every
    sample past its first 0.4 m beside the planter, read 0.2 degrees over a 14 cm drop."""
    known = at >= 0
    if layers.near_obstacle is None:
        return known, known
    clear = known & ~layers.near_obstacle[np.maximum(at, 0)]
    edges = len(length)
    head = np.bincount(edge[clear & (travelled <= baseline)], minlength=edges) > 0
    tail = np.bincount(edge[clear & (travelled >= length[edge] - baseline)], minlength=edges) > 0
    enough = (np.bincount(edge[clear], minlength=edges) >= 2) & head & tail
    return clear, clear | (known & ~enough[edge])


def _longest_unobserved(seen: np.ndarray, starts: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """(E,) metres: the longest run of samples of each edge that are not `seen` (S,) bool (samples
    of the edges in order, edge k's from starts[k], `spacing` (E,) metres apart), each sample
    standing for `spacing` metres of travel."""
    index = np.arange(len(seen))
    # The last seen sample at or before each sample, or the sample before its edge's first: a
    # running maximum that each edge's first sample resets (the previous edge's samples lie before).
    marker = np.where(seen, index, -1)
    marker[starts] = np.maximum(marker[starts], starts - 1)
    run = index - np.maximum.accumulate(marker)
    return np.maximum.reduceat(run, starts) * spacing


@dataclass
class EdgeProfile:
    """The clear ground along place edges, one row per sample, ordered by edge and travel: edge
    index (n,), metres travelled from its start (n,), ground height (n,) metres and the ground's
    gradient along the edge (n,) (dimensionless, NaN where unknown) (edge_geometry)."""

    edge: np.ndarray
    travelled: np.ndarray
    height: np.ndarray
    along: np.ndarray

    def ends_beyond(self, length: np.ndarray) -> np.ndarray:
        """(E, 2) bool: the edges (of lengths `length` (E,) metres) whose first (last) end this
        profile, the ground past their ends (_ground_past_unseen_ends), holds ground before (after)."""
        beyond = np.zeros((len(length), 2), dtype=bool)
        beyond[self.edge[self.travelled < 0], 0] = True
        beyond[self.edge[self.travelled > length[self.edge]], 1] = True
        return beyond

    def with_place_ends(
        self, known: np.ndarray, along: np.ndarray, ends: EdgeEnds, z: np.ndarray, past: EdgeProfile
    ) -> EdgeProfile:
        """The profile with the places' heights z (E, 2) metres added at each end whose sample's
        cell holds no ground (`known` (S,) bool), with that sample's gradient `along` (S,) the
        edge (NaN there): a place beside a car on the raised side of a curb, in a cell the car hid
        from the sensor, has no other height. Where `past` (_ground_past_unseen_ends) holds the
        ground beyond such an end, that ground is added instead: the place's own height is then
        only the nearest ground's, one side of the gap it stands in."""
        E = len(ends.starts)
        tail = ends.starts + ends.samples - 1
        beyond = past.ends_beyond(ends.length)
        first, last = ~known[ends.starts] & ~beyond[:, 0], ~known[tail] & ~beyond[:, 1]
        index = np.arange(E)
        rows = (
            np.concatenate([self.edge, index[first], index[last], past.edge]),
            np.concatenate([self.travelled, np.zeros(int(first.sum())), ends.length[last], past.travelled]),
            np.concatenate([self.height, z[first, 0], z[last, 1], past.height]),
            np.concatenate([self.along, along[ends.starts[first]], along[tail[last]], past.along]),
        )
        order = np.lexsort((rows[1], rows[0]))
        return EdgeProfile(*(r[order] for r in rows))


@dataclass
class EdgeEnds:
    """Where each of E edges' samples lie in edge_geometry's sample arrays: its first sample
    `starts` (E,), its number of `samples` (E,), and its `length` (E,) metres."""

    starts: np.ndarray
    samples: np.ndarray
    length: np.ndarray


def _ground_past_unseen_ends(
    layers: GroundLayers, a: np.ndarray, unit: np.ndarray, ends: EdgeEnds, known: np.ndarray, flat: np.ndarray
) -> EdgeProfile:
    """The first clear ground (not beside an obstacle, `near_obstacle`) on each edge's line past
    an end whose cell lies in the grid but holds no ground, looked for every half cell up to
    `BEYOND` metres on (rows travelled < 0 before the start, > the edge's length past its end).
    Edges run from `a` (E, 2) along `unit` (E, 2); `known` (S,) and `flat` (S,) say which samples'
    cells hold ground and are in the grid. Why: a place in
    a cell without ground takes the nearest ground's height, and may stand across a curb from it.
    On the simulated camera campus two places at a curb's top edge, in cells without points, took
    the road's height, and their edges from the road read level; with places on ground scanned in
    sparse rings (tried, benchmarks/RESULTS.md), edges from a curb's top to places on the road
    below, in holes between the rings, read level too. The ground just past the place tells; 1 m
    of it was too little between sparse rings. Beside an obstacle the lowest points may be the
    object's: a car's sill 35 cm up past a place in a curb's shadow made its edge to the curb's top
    read level on the simulated LiDAR-only small world."""
    step = layers.cell_size / 2
    reach = np.arange(1, int(np.ceil(BEYOND / step)) + 1) * step
    tail = ends.starts + ends.samples - 1
    parts = []
    for end, sign, base in ((ends.starts, -1.0, 0.0), (tail, 1.0, 1.0)):
        todo = np.flatnonzero(~known[end] & (flat[end] >= 0))
        origin = a[todo] + base * ends.length[todo, None] * unit[todo]
        point = origin[:, None, :] + sign * reach[None, :, None] * unit[todo, None, :]
        at = layers.observed_index(layers.flat_cells(point.reshape(-1, 2))).reshape(len(todo), len(reach))
        ground = at >= 0
        if layers.near_obstacle is not None:  # clear ground only, as along the edge (_slope_samples)
            ground &= ~layers.near_obstacle[np.maximum(at, 0)]
        found = ground.any(axis=1)
        k = np.argmax(ground, axis=1)[found]
        cell, todo = at[found, k], todo[found]
        along = (layers.fitted_gradient(cell) * unit[todo]).sum(axis=1)
        height = layers.height_at(cell, point[found, k])
        parts.append((todo, base * ends.length[todo] + sign * reach[k], height, along))
    return EdgeProfile(*(np.concatenate([p[i] for p in parts]) for i in range(4)))


def _steps_across_gaps(profile: EdgeProfile, edges: int, cell_size: float, baseline: float) -> np.ndarray:
    """(E,) metres: the largest step each edge hides across a gap of more than a cell between two
    samples of its clear-ground `profile` (cells beside an obstacle, or without ground): the
    height difference across the gap less what the ground's slope explains over it. The slope
    (along the edge, signed) of each side is read over `baseline` metres of the profile beside the
    gap, else (less than half of it) from the gradient at the gap's end; the step is the least any
    slope between the two sides' leaves (a valley or a ridge hides none, one noisy side makes none
    up), and is not read where neither side's slope is known. Why: beside a parked car the step
    layer reads a curb only along it (grid_layers), and an edge from the road past the car onto
    the raised side of the curb read level; across the car, 15 cm of height is not what the road's
    slope explains. The same across ground the sensor never saw: two bridges on the LiDAR-only
    campus crossed 3.5 m without ground with a 15 cm curb in it, and read level."""
    out = np.zeros(edges)
    p = profile
    run = np.diff(p.travelled)
    gaps = np.flatnonzero((p.edge[1:] == p.edge[:-1]) & (run > cell_size))
    if len(gaps) == 0:
        return out
    # Edges laid end to end, far apart (ground past an edge's start lies at negative travel).
    lowest = min(float(p.travelled.min()), 0.0)
    span = float(p.travelled.max()) - lowest + 2.0 * baseline + 1.0
    coordinate = p.edge * span + (p.travelled - lowest)
    first, last = gaps, gaps + 1
    back = np.searchsorted(coordinate, coordinate[first] - baseline)
    ahead = np.searchsorted(coordinate, coordinate[last] + baseline, side="right") - 1
    sides = []
    for near, far in ((first, back), (last, ahead)):
        rise, distance = p.height[far] - p.height[near], p.travelled[far] - p.travelled[near]
        wide = np.abs(distance) >= baseline / 2
        sides.append(np.where(wide, rise / np.where(wide, distance, 1.0), p.along[near]))
    low, high = np.fmin(*sides), np.fmax(*sides)
    read = np.isfinite(low)
    first, rise, gap = first[read], (p.height[last] - p.height[first])[read], run[first][read]
    to_low, to_high = rise - gap * low[read], rise - gap * high[read]
    hidden = np.where(to_low * to_high <= 0, 0.0, np.minimum(np.abs(to_low), np.abs(to_high)))
    np.fmax.at(out, p.edge[first], hidden)
    return out


def _unseen_end_steps(
    layers: GroundLayers, at: np.ndarray, flat: np.ndarray, ends: EdgeEnds, z: np.ndarray, beyond: np.ndarray
) -> np.ndarray:
    """(E,) metres: for each edge whose first (last) sample's cell lies in the grid but holds no
    ground, and whose line finds no ground past that end (`beyond` (E, 2) bool, first and last:
    EdgeProfile.ends_beyond), the height difference between its first (last) place, at heights z
    (E, 2) metres, and the ground of the first observed sample from that end; 0 elsewhere. A place
    on a curb's low side, in the curb's own LiDAR shadow, takes its height from the nearest ground,
    and an edge from it to the top whose only observed cells are on the top read level: 14 cm over
    1.1 m on the simulated small campus, under a wheelchair's slope limit, where the curb's step
    was not seen. Where ground lies past the end, the step across the gap the place stands in is
    read from it, less what the slope on its two sides explains (_steps_across_gaps); the raw
    difference read slopes as steps: a route's place in a hole between rings on a simulated lawn
    falling 3 degrees read the lawn's fall to the first ground along its edge as an 8 cm step.
    `at` (S,) the observed cell of each sample (-1: none), `flat` (S,) its grid cell (-1: outside
    the grid)."""
    starts, samples = ends.starts, ends.samples
    index = np.arange(len(at))
    first = np.minimum.reduceat(np.where(at >= 0, index, len(at)), starts)
    last = np.maximum.reduceat(np.where(at >= 0, index, -1), starts)
    seen = first < len(at)
    tail = starts + samples - 1
    out = np.zeros(len(starts))
    for side, (nearest, end) in enumerate(((first, starts), (last, tail))):
        unseen = seen & (nearest != end) & (flat[end] >= 0) & ~beyond[:, side]
        ground = layers.height[at[nearest[unseen]]].astype(np.float64)
        out[unseen] = np.fmax(out[unseen], np.abs(ground - z[unseen, side]))
    return out


def _steepest_along(edge: np.ndarray, along: np.ndarray, edges: int) -> np.ndarray:
    """(E, 2) the steepest rise and fall (m/m, >= 0) of the cells' own planes along each edge, from
    the gradient along its direction `along` (n,) (m/m; NaN unknown) at its samples (edge index
    (n,)). Why: a curb the step layer reads as a ramp (16 cm over two cells: their planes climb 11
    degrees along the edge) reads 7.7 degrees over the 1 m baseline when it lies at the edge's end,
    under a wheelchair's 8."""
    out = np.zeros((edges, 2))
    known = np.isfinite(along)
    np.fmax.at(out[:, 0], edge[known], along[known])
    np.fmax.at(out[:, 1], edge[known], -along[known])
    return np.maximum(out, 0.0)


def _rise_along(edge: np.ndarray, travelled: np.ndarray, height: np.ndarray, edges: int, baseline: float) -> np.ndarray:
    """(E, 2) steepest rise and fall (m/m, >= 0) of each edge from the heights (n,) of its known
    samples (edge index (n,), increasing within an edge; metres travelled from its start (n,)):
    over `baseline` metres, or from its first to its last known sample when it has less."""
    out = np.zeros((edges, 2))
    if len(edge) < 2:
        return out
    span = float(travelled.max()) + 2.0 * baseline + 1.0
    coordinate = edge * span + travelled  # edges laid end to end, far apart
    found = np.searchsorted(coordinate, coordinate + baseline - 1e-9)
    ahead = np.minimum(found, len(edge) - 1)
    full = (found < len(edge)) & (edge[ahead] == edge)  # a whole baseline of this edge lies ahead
    ends = np.concatenate([np.flatnonzero(np.diff(edge)), [len(edge) - 1]])  # each edge's last sample
    firsts = np.concatenate([[0], ends[:-1] + 1])
    short = ~np.isin(edge[firsts], edge[full])  # edges with less than a baseline: first to last
    pairs = np.concatenate([np.flatnonzero(full), firsts[short]])
    targets = np.concatenate([ahead[full], ends[short]])
    run = travelled[targets] - travelled[pairs]
    valid = run > 1e-6
    pairs, targets, run = pairs[valid], targets[valid], run[valid]
    slope = (height[targets] - height[pairs]) / run
    np.fmax.at(out[:, 0], edge[pairs], slope)
    np.fmax.at(out[:, 1], edge[pairs], -slope)
    return np.maximum(out, 0.0)


# ------------------------------------------------------------------ the build's use of the layers


def has_terrain_votes(msm: MetricSemanticMap) -> bool:
    """Whether any map point has a terrain vote: a map without (a LiDAR-only log, or a dataset
    whose legend names terrain classes but whose scans carry no labels) builds on `ground`."""
    return bool(msm.terrain_classes) and bool(np.any(msm.terrain_votes))


def points_ground(points: np.ndarray, section: GroundSection) -> np.ndarray:
    """(N,) bool ground flag of map points (N, 3) (metres), by `segment_ground` with the section's values."""
    return segment_ground(
        points,
        section.cell_size,
        tuple(section.windows),
        section.slope,
        section.base_height,
        section.max_height,
        section.tolerance,
        section.standing_tolerance,
    )


def as_ground_terrain(msm: MetricSemanticMap, ground: np.ndarray) -> MetricSemanticMap:
    """A map without terrain votes seen as one with a single terrain class, `ground`,
    voted once by each ground point (N,) bool. Its terrain embedding is the first unit vector of
    the embedding space: the map carries no semantics to embed, every place gets the same vector,
    and regions come from positions alone (terra find and monitor refuse such maps)."""
    dim = msm.dim
    embedding = np.zeros((1, dim), dtype=np.float32)
    embedding[0, 0] = 1.0
    votes = np.asarray(ground, dtype=np.uint16).reshape(-1, 1)
    return replace(msm, terrain_classes=[GROUND_TERRAIN], terrain_votes=votes, terrain_embeddings=embedding)


def grid_layers(
    points: np.ndarray,
    ground: np.ndarray,
    grid: TerrainGrid,
    beside: int = BESIDE,
    band: tuple[float, float] | None = OBSTACLE_BAND,
    min_points: int = OBSTACLE_MIN_POINTS,
) -> GroundLayers:
    """The layers of the ground points (`points` (N, 3) where `ground` (N,)) on the terrain grid's
    cells, after the grid's cells with `min_points` points `band` metres above that ground are
    blocked (`block_above_ground`, in place). Within `beside` cells of a blocked cell
    (`near_obstacle`) a step is read only along an axis whose heights (the cell and two on each
    side, or one on each side: `steps_clear_of`) are all clear of blocked cells, and is unknown
    where neither axis is: in a blocked cell the lowest points of an object (a car's sill, a
    planter's rim) pass for ground and read as steps of a few centimetres, while a curb in the gap
    between two cars parked nose to it is read across the curb, clear of both cars."""
    return layers_on_grid(ground_layers(np.asarray(points)[ground], grid.frame), grid, points, beside, band, min_points)


def layers_on_grid(
    layers: GroundLayers,
    grid: TerrainGrid,
    points: np.ndarray,
    beside: int = BESIDE,
    band: tuple[float, float] | None = OBSTACLE_BAND,
    min_points: int = OBSTACLE_MIN_POINTS,
) -> GroundLayers:
    """`layers` (`ground_layers` on the frame of `grid`) with what they take of the grid, the one
    path of the full build and the incremental update: first the grid's cells whose map points
    (N, 3+) stand in the obstacle `band` above that ground are blocked (`block_above_ground`, in
    place), then the steps beside its blocked cells are read again (`beside_obstacles`)."""
    block_above_ground(grid, points, layers, band, min_points)
    return beside_obstacles(layers, grid.blocked, beside)


def block_above_ground(
    grid: TerrainGrid,
    points: np.ndarray,
    layers: GroundLayers,
    band: tuple[float, float] | None = OBSTACLE_BAND,
    min_points: int = OBSTACLE_MIN_POINTS,
) -> int:
    """In place: blocks the cells of `grid` (which lose their label) that hold at least
    `min_points` of the map points (N, 3+) (map frame, metres), of any terrain class or none,
    standing `band` (low, high) metres above the segmented ground there (the height of the layers
    on the grid's frame, in their observed cells) and none above the band in or beside them, and
    returns how many it blocked. Why: the grid measures heights above the mean of its terrain
    points, and a camera's terrain mask that bleeds onto a picnic table (its top's points voted
    sidewalk) raised that ground to the table, whose points then stood less than the band above
    it: on the simulated curb worlds 51 usable place edges ran through picnic tables, benches,
    bicycles and their racks (34 with this rule). The segmentation takes no camera vote."""
    if band is None or len(layers.cells) == 0:
        return 0
    if tuple(layers.shape) != tuple(grid.shape):
        raise ValueError(f"the ground layers' grid {layers.shape} is not the terrain grid's {grid.shape}")
    n, tilt = len(layers.cells), STEEPEST_FIT * layers.cell_size / np.sqrt(2.0)
    counts, above = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)  # per observed cell
    for start in range(0, len(points), POINT_CHUNK):
        xyz = np.asarray(points[start : start + POINT_CHUNK], dtype=np.float64)
        at = layers.lookup(xyz[:, :2])
        # Only points that may stand in the band: a cell's plane (at most STEEPEST_FIT steep)
        # moves the ground's height within it by at most `tilt` from the cell's.
        known = np.flatnonzero(at >= 0)
        known = known[xyz[known, 2] - layers.height[at[known]] >= band[0] - tilt]
        height = xyz[known, 2] - layers.height_at(at[known], xyz[known, :2])
        counts += np.bincount(at[known[(height >= band[0]) & (height <= band[1])]], minlength=n)
        above += np.bincount(at[known[height > band[1]]], minlength=n)
    # Only cells with nothing above the band in or beside them: their points are the fringe of
    # something overhanging, left to the grid's own rule (a crown's lowest leaves, 1.97 to 2.0 m
    # up under a simulated tree, blocked a curb's top, and the curb beside them read no step).
    overhung = np.zeros(grid.shape, dtype=bool)
    overhung.ravel()[layers.cells[above > 0]] = True
    overhung = raster.grown(overhung, 1)
    flat = layers.cells[counts >= min_points]
    flat = flat[~overhung.ravel()[flat] & ~grid.blocked.ravel()[flat]]
    rows, cols = np.divmod(flat, grid.shape[1])
    grid.blocked[rows, cols] = True
    grid.label[rows, cols] = -1
    return len(flat)


def beside_obstacles(layers: GroundLayers, blocked: np.ndarray, beside: int = BESIDE) -> GroundLayers:
    """`layers` (of the ground points alone, `ground_layers`) with the steps within `beside` cells
    of a `blocked` (H, W) bool cell of their grid read again clear of the blocked cells, and
    those cells flagged `near_obstacle` (`grid_layers`); in place, and returned. The steps of the
    cells up to BRIDGE + 1 cells from one are read again too, clear of the blocked cells
    (`steps_clear_of`): a clear cell read a wall's foot (its lowest returns, 17 cm up) across a
    gap of two cells, and a simulated place 1.2 m from the wall was cut off. The only part of
    the layers that needs the terrain grid: the rest is computed beside it (terra.graph.pipeline).
    Last, a step read across a gap is left to the gap's high side where that holds it
    (`held_across_gaps`): it needs every cell's final step, those beside obstacles included."""
    if beside > 0 and blocked.any():
        near = raster.grown(blocked, beside)
        layers.near_obstacle = near.ravel()[layers.cells]
        # Beyond `beside` cells too, as far as a step read across a gap reaches (BRIDGE cells, and
        # the slope one further): a blocked cell's lowest points are no ground to bridge to.
        reach = raster.grown(blocked, max(beside, BRIDGE + 1))
        index = np.flatnonzero(reach.ravel()[layers.cells])
        layers.step[index] = steps_clear_of(layers, blocked, index)
    return held_across_gaps(layers)


def held_across_gaps(layers: GroundLayers) -> GroundLayers:
    """`layers` with the step a cell reads across a gap on its side (a neighbour without ground,
    the ground beyond it higher) replaced by what it reads on its other side alone (at most what
    it read: the cell gives a read up, it takes none on), where the cell across the gap (the
    nearest observed one, within BRIDGE cells) reads a step at least as large, less STRADDLE: that
    cell holds it, and the step lies at the gap's high edge. Why: a
    curb seen from its top hides the road within a metre of it (its LiDAR shadow); the step layer
    read the curb on both edges of the shadow, and road cells up to 1.6 m from a simulated curb
    read 15 cm, closed every level route past a road place there and took the place's edges with
    them. A cell beside an obstacle (its read `steps_clear_of`'s) gives its read up only to a far
    cell clear of obstacles: on the simulated LiDAR-only campus a road place 1 m from a curb, beside
    an object, read the curb across the shadow and was cut off. Left as they are: a cell that holds
    both levels itself (its height between its two sides', `_straddles`); a gap the far side does
    not hold (a curb's top beside a car, read only along the curb: the road's edge is then all
    that reads it). The read on both edges is kept in memory for the cells that gave it up
    (`held_cells`, `held_step`): the lines of steps that split a LiDAR-only ground's GVD are drawn
    from it (`step_lines`), so the GVD still keeps out of the shadow. In place, and returned."""
    index = _beside_gaps(layers)
    if len(index) == 0:
        return layers
    m, reach = len(index), BRIDGE + 1
    reads, released = [], np.zeros(m, dtype=bool)
    for axis in (0, 1):  # rows (y), then columns (x)
        at, height = _axis_ground(layers, layers.cells[index], axis, reach)
        level = np.abs(layers.gradient[index, 1 - axis].astype(np.float64) * layers.cell_size)
        read = steps_at(height, (np.arange(m), np.full(m, reach)), level)
        for sign in (-1, 1):
            held, own = _held_across(layers, height, at, read, level, sign)
            read = np.where(held, own, read)
            released |= held
        reads.append(read)
    before = layers.step[index[released]].copy()
    layers.step[index[released]] = np.fmin(np.fmax(*reads)[released], before).astype(np.float32)
    layers.held_cells, layers.held_step = index[released], before
    return layers


def heights_in_gaps(layers: GroundLayers, xy: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(m,) metres: the heights `z` (m,) of points `xy` (m, 2+) (map frame, metres), with each point
    whose cell holds no ground (inside the layers' grid) given the lowest of the nearest observed
    heights along the grid's four axis directions within BRIDGE cells (unchanged where none lies
    there). Why: a cell without ground beside a step lies in its LiDAR shadow, behind the step's top
    (`held_across_gaps`), so at its low level; the nearest ground is as often the top's. A place
    0.8 m from a simulated curb, in its shadow on the road, took the curb top's height 2 cells away
    (the road lay 2.2 cells away): its edges to the road read the curb, the ones up to the top
    crossed it, and no route reached it. The heights are the cells' own, not carried along their
    gradients: beside a curb the planes are fitted across it (carried, LiDAR-only campus lost
    routes: share missed 0.069 -> 0.074). A cell whose two neighbours along an axis both hold
    ground within twice STRADDLE of each other is a hole in that ground, not a shadow, and takes
    their mean (the axis whose two agree best): a place on a curb's top in a cell without ground,
    the top on three sides of it, took the road's height four cells away, and its edge down to the
    road, with no ground along it, read no step."""
    z = np.array(z, dtype=np.float64)
    flat = layers.flat_cells(xy)
    todo = np.flatnonzero((flat >= 0) & (layers.observed_index(flat) < 0))
    if len(todo) == 0:
        return z
    pick, lowest = np.arange(len(todo)), np.full(len(todo), np.nan)
    between, spread = np.full(len(todo), np.nan), np.full(len(todo), 2.0 * STRADDLE)
    for axis in (0, 1):
        _, height = _axis_ground(layers, flat[todo], axis, BRIDGE)
        for sign in (-1, 1):  # NaN where no ground lies within BRIDGE cells on that side
            lowest = np.fmin(lowest, height[pick, BRIDGE + sign * _nearest_observed(height, sign)])
        # A hole of one cell in level ground: both neighbours observed, at one level.
        before, after = height[:, BRIDGE - 1], height[:, BRIDGE + 1]
        with np.errstate(invalid="ignore"):  # NaN: a neighbour without ground, no hole
            hole = np.abs(after - before) <= spread
        between = np.where(hole, (before + after) / 2.0, between)
        spread = np.where(hole, np.abs(after - before), spread)
    found = np.isfinite(lowest)
    z[todo[found]] = lowest[found]
    z[todo[np.isfinite(between)]] = between[np.isfinite(between)]
    return z


def _beside_gaps(layers: GroundLayers) -> np.ndarray:
    """(m,) the observed cells (indices into the layers) that read a step of more than STRADDLE
    metres (less is one level's noise, as `_straddles` takes it) and have a 4-neighbour in the grid
    without ground: the cells a step across a gap is read on, those beside an obstacle included
    (`_held_across` asks more of them). (On the campus map 5 % of the cells with any step: the rule
    takes 22 ms there, not 215.)"""
    index = np.flatnonzero(np.nan_to_num(layers.step, nan=0.0) > STRADDLE)
    H, W = layers.shape
    rows, cols = np.divmod(layers.cells[index], W)
    gap = np.zeros(len(index), dtype=bool)
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        r, c = rows + dr, cols + dc
        inside = (r >= 0) & (r < H) & (c >= 0) & (c < W)
        gap |= inside & (layers.observed_index(np.where(inside, r * W + c, -1)) < 0)
    return index[gap]


def _axis_ground(layers: GroundLayers, flat: np.ndarray, axis: int, reach: int) -> tuple[np.ndarray, np.ndarray]:
    """(m, 2 reach + 1) int64 and float64 twice: the observed cells (indices into the layers, -1
    for none or outside the grid) from `reach` cells before to `reach` cells after each grid cell
    `flat` (m,) (row * W + col, inside the grid) along the grid's `axis` (0: rows, 1: columns), and
    their heights (metres, NaN for none)."""
    H, W = layers.shape
    rows, cols = np.divmod(flat, W)
    taps = np.arange(-reach, reach + 1)
    r, c = np.broadcast_arrays(rows[:, None] + (taps if axis == 0 else 0), cols[:, None] + (taps if axis == 1 else 0))
    inside = (r >= 0) & (r < H) & (c >= 0) & (c < W)
    at = layers.observed_index(np.where(inside, r * W + c, -1).ravel()).reshape(r.shape)
    return at, np.where(at >= 0, layers.height[np.maximum(at, 0)], np.nan).astype(np.float64)


def _held_across(
    layers: GroundLayers, height: np.ndarray, at: np.ndarray, read: np.ndarray, level: np.ndarray, sign: int
) -> tuple[np.ndarray, np.ndarray]:
    """(m,) bool and (m,) metres: which cells' step `read` (m,) (along one axis, from the heights
    `height` (m, 2 reach + 1) of the cells `at` (same shape) around each) the cell across a gap
    on the side `sign` (-1, 1) holds (`held_across_gaps`; where both lie beside an obstacle, none),
    and what each reads on its other side alone: the height difference to its neighbour there less
    the slope beyond it (that neighbour's difference to the next, else |rise| `level` (m,), metres
    per cell)."""
    centre, pick = height.shape[1] // 2, np.arange(len(read))
    middle, near, near2 = height[:, centre], height[:, centre - sign], height[:, centre - 2 * sign]
    distance = _nearest_observed(height, sign)  # more than 1: a gap lies between
    far, far_at = height[pick, centre + sign * distance], at[pick, centre + sign * distance]
    far_step = np.where(far_at >= 0, layers.step[np.maximum(far_at, 0)], np.nan)
    if layers.near_obstacle is not None:  # a cell beside an obstacle gives its read to clear ground only
        beside = layers.near_obstacle[at[:, centre]] & layers.near_obstacle[np.maximum(far_at, 0)]
        far_step = np.where(beside, np.nan, far_step)
    with np.errstate(invalid="ignore"):  # NaN compares False: no gap, no far cell, nothing held
        held = (
            (distance > 1)
            & np.isfinite(near)
            & (far > middle)
            & ~_straddles(middle, near, far)
            & (far_step >= read - STRADDLE)
        )
    outer = np.where(np.isfinite(near2), np.abs(near - near2), level)
    return held, np.maximum(np.abs(middle - near) - outer, 0.0)


def _nearest_observed(height: np.ndarray, sign: int) -> np.ndarray:
    """(m,) int64: how many cells from the middle of each row of `height` (m, 2 reach + 1), metres
    (NaN: no ground), its nearest observed cell lies on the side `sign` (-1, 1), within BRIDGE
    cells (reach >= BRIDGE); 0 where none does (the middle itself)."""
    centre = height.shape[1] // 2
    distance = np.zeros(len(height), dtype=np.int64)
    for k in range(BRIDGE, 0, -1):  # the nearest wins
        distance = np.where(np.isfinite(height[:, centre + sign * k]), k, distance)
    return distance


def steps_clear_of(layers: GroundLayers, blocked: np.ndarray, index: np.ndarray) -> np.ndarray:
    """(m,) float32 metres: the step (`axis_step`, the larger of the two axes) of the observed
    cells `index` (m,) read only along the axes whose five heights (the cell, two on each side)
    lie in cells that are not `blocked` (H, W) bool, on the layers' grid, and across a gap
    without ground from heights further out that are not blocked either; along an axis where
    the cell, its two neighbours and the next cell on one side only are clear, the jump between
    the neighbours less twice the slope on that side; where only the cell and its two neighbours
    are, the larger of their two height differences less the smaller; NaN where no axis is clear.
    Whether a cell across a gap stands on a step (`_bridge_gaps`) is read with the blocked cells'
    heights too."""
    H, W = layers.shape
    flat = layers.cells[index]
    rows, cols = flat // W, flat % W
    reach = BRIDGE + 1  # a step across a gap reads up to BRIDGE cells away, and its slope one further
    taps = np.arange(-reach, reach + 1)
    inner = slice(reach - 2, reach + 3)
    out = np.full(len(index), np.nan)
    for axis, gradient in ((0, layers.gradient[index, 1]), (1, layers.gradient[index, 0])):
        r = rows[:, None] + (taps if axis == 0 else 0)
        c = cols[:, None] + (taps if axis == 1 else 0)
        inside = (r >= 0) & (r < H) & (c >= 0) & (c < W)
        r, c = np.clip(r, 0, H - 1), np.clip(c, 0, W - 1)
        free = inside & ~blocked[r, c]
        clear = free[:, inner].all(axis=1)
        at = np.minimum(np.searchsorted(layers.cells, r * W + c), len(layers.cells) - 1)
        ground = np.where(inside & (layers.cells[at] == r * W + c), layers.height[at], np.nan)
        height = np.where(free, ground, np.nan)
        level = np.abs(gradient.astype(np.float64) * layers.cell_size)
        step = steps_at(height, (np.arange(len(index)), np.full(len(index), reach)), level, past=ground)
        # With an obstacle two cells away on one side only, the jump across the cell less the slope
        # of the clear side (a curb through a cell holding both its levels, a wall beyond it);
        # with obstacles on both sides, the cell and its two neighbours: the larger of the two
        # differences less the smaller (a slope cancels, a curb beside a car's nose stays).
        near = free[:, reach - 1 : reach + 2].all(axis=1) & ~clear
        before2, before, middle, after, after2 = height[:, reach - 2 : reach + 3].T
        outer = np.where(free[:, reach - 2], np.abs(before - before2), np.abs(after2 - after))
        one_side = near & (free[:, reach - 2] | free[:, reach + 2]) & np.isfinite(outer)
        step = np.where(near, np.abs(np.abs(after - middle) - np.abs(middle - before)), step)
        step = np.where(one_side, np.maximum(np.abs(after - before) - 2.0 * outer, 0.0), step)
        out = np.fmax(out, np.where(clear | near, step, np.nan))
    return out.astype(np.float32)


def step_lines(
    layers: GroundLayers, min_step: float, min_cells: int = STEP_LINE_CELLS, close: int = STEP_LINE_CLOSE
) -> np.ndarray:
    """(H, W) bool on the layers' grid: the observed cells whose step reads above `min_step`
    metres, with gaps of up to 2 x `close` cells between them filled (a binary closing: a curb
    reads its step unevenly along its length, and its LiDAR shadow holds no ground, so its cells
    come as two broken rows), in 8-connected lines of at least `min_cells` cells (a curb, the foot
    of a low wall; a lone cell is a stone or a stray height, no line a robot meets). A cell whose
    step across a gap its high edge holds counts with the step it read before, not its own
    (`held_cells`, `held_step`: `held_across_gaps`): lines on both edges of a curb's shadow,
    closed across it, keep the GVD out of the shadow."""
    stepped = np.nan_to_num(layers.step, nan=0.0) > min_step
    if layers.held_cells is not None and layers.held_step is not None:
        stepped[layers.held_cells] = layers.held_step > min_step
    out = np.zeros(layers.shape[0] * layers.shape[1], dtype=bool)
    out[layers.cells[stepped]] = True
    out = out.reshape(layers.shape)
    if close > 0:  # padded: a closing erodes from outside the grid too
        padded = ndimage.binary_closing(np.pad(out, close), EIGHT, iterations=close)
        out = np.asarray(padded)[close:-close, close:-close]
    lines, count = label_components(out)
    if count == 0:
        return out
    long_enough = component_sizes(lines, count) >= min_cells
    long_enough[0] = False
    return long_enough[lines]


def write_ground_layers(writer: BundleWriter, layers: GroundLayers) -> None:
    """The layers as arrays graph/ground_<name> of the bundle being written (one row per observed
    cell: cells int64, height float32, gradient, step and roughness float16), described in
    components.graph.ground (call after terra.graph.storage.write_scene_graph)."""
    writer.put_array(GROUND_FILES + "cells", layers.cells.astype(np.int64))
    writer.put_array(GROUND_FILES + "height", layers.height.astype(np.float32))
    writer.put_array(GROUND_FILES + "gradient", layers.gradient.astype(np.float16))
    writer.put_array(GROUND_FILES + "step", layers.step.astype(np.float16))
    writer.put_array(GROUND_FILES + "roughness", layers.roughness.astype(np.float16))
    writer.update_component("graph", ground=layers.info())
