"""Ground truth written beside a simulated dataset (`<root>/ground_truth/`), read by evaluation.

Files (all in the map frame, metres, radians):
- `objects.json`: {"objects": [{"instance_id", "class_id", "class_name", "center": [x, y, z],
  "size": [sx, sy, sz], "yaw"}]} with gravity-aligned boxes: `size` is along the box axes before
  the yaw rotation about +z; `center` is the box centre. `objects.csv` holds the same rows.
- `terrain.npy`: (H, W) int32 class ids of the source ClassTable. Cell (row r, col c) covers
  x in [x0 + c*res, x0 + (c+1)*res), y in [y0 + r*res, y0 + (r+1)*res): rows grow with y, no flip.
- `ground_height.npy`: (H, W) float32 ground height z at each cell centre, same grid.
- `terrain.json`: {"origin": [x0, y0], "resolution": res, "legend": {"<id>": "<name>"}}.
- `regions.json`: {"regions": [{"name", "description", "polygon": [[x, y], ...]}]}.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from terra.errors import TerraError
from terra.npy import write_npy

GROUND_TRUTH_DIR = "ground_truth"


@dataclass
class ObjectBox:
    """A gravity-aligned oriented box: centre and size in metres, yaw in radians about +z."""

    instance_id: int
    class_id: int
    class_name: str
    center: np.ndarray
    size: np.ndarray
    yaw: float


@dataclass
class NamedRegion:
    """A human-labelled region: a 2D polygon (map frame x, y in metres) and a one-sentence description."""

    name: str
    description: str
    polygon: np.ndarray  # (K, 2)


@dataclass
class TerrainRaster:
    """Ground-truth terrain class per cell and ground height, on an axis-aligned grid."""

    classes: np.ndarray  # (H, W) int32 class ids
    ground_height: np.ndarray  # (H, W) float32 metres
    origin: np.ndarray  # (2,) x0, y0 metres: lower-left corner of cell (0, 0)
    resolution: float  # metres per cell
    legend: dict[int, str]

    def cell_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, cols, inside) of map-frame points (N, 2)."""
        rc = np.floor((np.asarray(xy)[:, :2] - self.origin) / self.resolution).astype(np.int64)
        rows, cols = rc[:, 1], rc[:, 0]
        inside = (rows >= 0) & (rows < self.classes.shape[0]) & (cols >= 0) & (cols < self.classes.shape[1])
        return np.clip(rows, 0, self.classes.shape[0] - 1), np.clip(cols, 0, self.classes.shape[1] - 1), inside

    def class_at(self, xy: np.ndarray) -> np.ndarray:
        """Terrain class id at map-frame points (N, 2); -1 outside the raster."""
        rows, cols, inside = self.cell_of(xy)
        return np.where(inside, self.classes[rows, cols], -1)

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        """Ground height (metres) at map-frame points (N, 2); NaN outside the raster."""
        rows, cols, inside = self.cell_of(xy)
        return np.where(inside, self.ground_height[rows, cols], np.nan)

    def neighbour_geometry(self) -> tuple[np.ndarray, np.ndarray]:
        """`neighbour_geometry` of this raster's ground heights: step (H, W, 4) metres and slope
        (H, W, 4) degrees of the move to each neighbour in NEIGHBOURS order."""
        return neighbour_geometry(self.ground_height, self.resolution)


NEIGHBOURS = ((0, 1), (1, 0), (0, -1), (-1, 0))
"""(row, column) offsets of a cell's four neighbours: +x, +y, -x, -y (rows grow with y)."""


def neighbour_geometry(height: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Step and slope of the move from each cell to each of its four neighbours (NEIGHBOURS order)
    on a raster of true ground heights at cell centres (H, W) metres, `resolution` metres apart.

    The height difference `jump` between two neighbours splits into what the surface on both sides
    explains and a step: `outer` is the smaller of the two differences that continue the line on
    either side (the cell before the first and after the second; the one inside at the raster's
    edge, 0 on a raster two cells long), the
    slope is atan(min(|jump|, outer) / resolution) in degrees and the step max(|jump| - outer, 0)
    in metres. A curb between flat road and flat walk is a step of its height and slope 0; a
    constant slope or a ramp of small risers is that slope and step 0; a flight of stairs is steps.
    Returns step (H, W, 4) float64 metres and slope (H, W, 4) float64 degrees, NaN where the
    neighbour lies outside the raster; a move and its reverse share both values."""
    height = np.asarray(height, dtype=np.float64)
    step = np.full(height.shape + (4,), np.nan)
    slope = np.full(height.shape + (4,), np.nan)
    for axis, forward, backward in ((1, 0, 2), (0, 1, 3)):
        h = np.moveaxis(height, axis, -1)
        jump = np.abs(np.diff(h, axis=-1))  # (..., W - 1): between cell c and c + 1
        pad = np.full(h.shape[:-1] + (1,), np.nan)
        before = np.concatenate([pad, jump[..., :-1]], axis=-1)
        after = np.concatenate([jump[..., 1:], pad], axis=-1)
        outer = np.nan_to_num(np.fmin(before, after), nan=0.0)
        smooth = np.minimum(jump, outer)
        edge_step, edge_slope = jump - smooth, np.degrees(np.arctan(smooth / resolution))
        for out, values in ((step, edge_step), (slope, edge_slope)):
            view = np.moveaxis(out, axis, -2)  # (..., W, 4)
            view[..., :-1, forward] = values
            view[..., 1:, backward] = values
    return step, slope


def neighbour_side_slope(slope: np.ndarray) -> np.ndarray:
    """The side slope of each move of `neighbour_geometry` (slope (H, W, 4) degrees, NEIGHBOURS
    order): (H, W, 4) degrees, the ground's tilt across the direction of travel, which tips a robot
    sideways (a profile's `max_cross_slope`). A cell's tilt across a move along x is the mean of its
    moves' slopes to its -y and +y neighbours (the smooth part of each: a curb beside the move is a
    step, no tilt), and across a move along y that of its -x and +x moves; a move takes the larger
    tilt of its two cells. NaN where the neighbour lies outside the raster; a cell with one
    neighbour across takes that one's slope."""
    slope = np.asarray(slope, dtype=np.float64)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a raster one cell wide has no slope across
        across_y = np.nanmean(slope[..., [1, 3]], axis=-1)  # tilt across a move along x
        across_x = np.nanmean(slope[..., [0, 2]], axis=-1)
    side = np.full(slope.shape, np.nan)
    side[:, :-1, 0] = np.fmax(across_y[:, :-1], across_y[:, 1:])
    side[:, 1:, 2] = side[:, :-1, 0]
    side[:-1, :, 1] = np.fmax(across_x[:-1, :], across_x[1:, :])
    side[1:, :, 3] = side[:-1, :, 1]
    return side


@dataclass
class PathGeometry:
    """What a path meets on a true ground raster: its largest step (metres) and steepest slope
    (degrees) over the cell moves it makes, the two cells (row, col) of the move with the largest
    step, the cells (rows, cols) (k,) it passes, in order, and its steepest side slope (degrees;
    NaN where not judged)."""

    step: float
    slope: float
    step_cells: tuple[tuple[int, int], tuple[int, int]]
    rows: np.ndarray
    cols: np.ndarray
    side_slope: float = float("nan")


def path_geometry(
    raster: TerrainRaster,
    step: np.ndarray,
    slope: np.ndarray,
    waypoints: np.ndarray,
    side: np.ndarray | None = None,
) -> PathGeometry:
    """The true geometry of a path of straight segments between `waypoints` (n, 2+) (map frame,
    metres) on `raster`, whose moves' step and slope (H, W, 4) come from `neighbour_geometry` (and
    side slope (H, W, 4) degrees from `neighbour_side_slope`, when given). The path is sampled
    every quarter cell; a move between cells that share only a corner takes the better of its two
    detours through a neighbour (a robot may pass either side of the corner); unknown moves (off
    the raster) count as 0."""
    tilt = np.zeros_like(slope) if side is None else side
    xy = np.asarray(waypoints, dtype=np.float64)[:, :2]
    pieces = [xy[:1]]
    for a, b in zip(xy[:-1], xy[1:]):
        n = max(int(np.ceil(np.linalg.norm(b - a) / (raster.resolution / 4))), 1)
        pieces.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
    rows, cols, _ = raster.cell_of(np.vstack(pieces))
    keep = np.concatenate([[True], (np.diff(rows) != 0) | (np.diff(cols) != 0)])
    rows, cols = rows[keep], cols[keep]
    worst = (0.0, 0.0, 0.0)
    step_cells = ((int(rows[0]), int(cols[0])), (int(rows[0]), int(cols[0])))
    for r0, c0, r1, c1 in zip(rows[:-1], cols[:-1], rows[1:], cols[1:]):
        dr, dc = int(r1 - r0), int(c1 - c0)
        if abs(dr) + abs(dc) == 1:
            detours = [[(r0, c0, dr, dc)]]
        else:  # a corner: through (r0, c1) or (r1, c0)
            detours = [[(r0, c0, 0, dc), (r0, c1, dr, 0)], [(r0, c0, dr, 0), (r1, c0, 0, dc)]]
        options = []
        for moves in detours:
            k = [NEIGHBOURS.index((mr, mc)) for _, _, mr, mc in moves]
            found = np.array([(step[r, c, j], slope[r, c, j], tilt[r, c, j]) for (r, c, _, _), j in zip(moves, k)])
            options.append(tuple(np.nan_to_num(found).max(axis=0)))
        best = min(options, key=lambda v: v[0] + (v[1] + v[2]) / 90.0)
        if best[0] > worst[0]:
            step_cells = ((int(r0), int(c0)), (int(r1), int(c1)))
        worst = tuple(max(w, b) for w, b in zip(worst, best))
    side_slope = float("nan") if side is None else float(worst[2])
    return PathGeometry(float(worst[0]), float(worst[1]), step_cells, rows, cols, side_slope)


def cell_slope(height: np.ndarray, resolution: float) -> np.ndarray:
    """(H, W) degrees: the steepest slope (`neighbour_geometry`) of a cell's moves to its neighbours."""
    _, slope = neighbour_geometry(height, resolution)
    return np.nanmax(np.where(np.isnan(slope), -np.inf, slope), axis=-1)


@dataclass
class GroundTruth:
    """Objects, terrain and named regions of a dataset (map frame). Real datasets may lack some:
    `terrain` None and no regions (KITTI labels hold objects only); `notes` says what and why."""

    objects: list[ObjectBox]
    terrain: TerrainRaster | None
    regions: list[NamedRegion]
    notes: list[str] = field(default_factory=list)

    def translated(self, offset: np.ndarray) -> GroundTruth:
        """The same ground truth in a frame shifted by `offset` (3,) metres: p_new = p + offset."""
        offset = np.asarray(offset, np.float64).reshape(3)
        objects = [replace(o, center=np.asarray(o.center, np.float64) + offset) for o in self.objects]
        terrain = None
        if self.terrain is not None:
            heights = (self.terrain.ground_height + offset[2]).astype(np.float32)
            terrain = replace(self.terrain, origin=self.terrain.origin + offset[:2], ground_height=heights)
        regions = [replace(r, polygon=np.asarray(r.polygon, np.float64) + offset[:2]) for r in self.regions]
        return GroundTruth(objects, terrain, regions, list(self.notes))


def write_ground_truth(root: Path, gt: GroundTruth) -> None:
    """Write `gt` under `root/ground_truth/` (plain files; the caller makes the whole folder atomic)."""
    if gt.terrain is None:
        raise ValueError("ground truth without a terrain raster cannot be written as ground_truth/")
    out = Path(root) / GROUND_TRUTH_DIR
    out.mkdir(parents=True, exist_ok=True)
    rows = [
        {
            "instance_id": int(o.instance_id),
            "class_id": int(o.class_id),
            "class_name": o.class_name,
            "center": [round(float(v), 6) for v in o.center],
            "size": [round(float(v), 6) for v in o.size],
            "yaw": round(float(o.yaw), 6),
        }
        for o in gt.objects
    ]
    (out / "objects.json").write_text(json.dumps({"frame": "map", "objects": rows}, indent=1) + "\n")
    header = "instance_id,class_name,class_id,center_x,center_y,center_z,size_x,size_y,size_z,yaw\n"
    lines = [
        f"{r['instance_id']},{r['class_name']},{r['class_id']},"
        + ",".join(f"{v:.6f}" for v in (*r["center"], *r["size"], r["yaw"]))
        for r in rows
    ]
    (out / "objects.csv").write_text(header + "\n".join(lines) + "\n")
    write_npy(out / "terrain.npy", gt.terrain.classes.astype(np.int32))
    write_npy(out / "ground_height.npy", gt.terrain.ground_height.astype(np.float32))
    meta = {
        "origin": [float(v) for v in gt.terrain.origin],
        "resolution": float(gt.terrain.resolution),
        "legend": {str(k): v for k, v in sorted(gt.terrain.legend.items())},
    }
    (out / "terrain.json").write_text(json.dumps(meta, indent=1) + "\n")
    regions = [
        {
            "name": r.name,
            "description": r.description,
            "polygon": [[round(float(x), 6), round(float(y), 6)] for x, y in r.polygon],
        }
        for r in gt.regions
    ]
    (out / "regions.json").write_text(json.dumps({"frame": "map", "regions": regions}, indent=1) + "\n")


def load_ground_truth(root: str | Path) -> GroundTruth:
    """Read `root/ground_truth/` (checked against terra.schemas' ground-truth models and array
    specs); TerraError naming the file when something is missing or malformed."""
    from terra.npy import ArraySpec, read_npy
    from terra.schemas import GroundTruthObjects, GroundTruthRegions, GroundTruthTerrain, read_model

    gt_dir = Path(root) / GROUND_TRUTH_DIR
    if not gt_dir.is_dir():
        raise TerraError(
            f"{gt_dir}: no ground truth folder (expected a dataset written by `terra sim`, "
            "or a KITTI raw drive with label_02/ or label_2/ labels)"
        )
    objects = [
        ObjectBox(
            o.instance_id, o.class_id, o.class_name, np.asarray(o.center, float), np.asarray(o.size, float), o.yaw
        )
        for o in read_model(gt_dir / "objects.json", GroundTruthObjects, "ground-truth objects file").objects
    ]
    meta = read_model(gt_dir / "terrain.json", GroundTruthTerrain, "ground-truth terrain file")
    classes = read_npy(gt_dir / "terrain.npy", ArraySpec(("int32",), (None, None), what="terrain class per cell"))
    heights = read_npy(
        gt_dir / "ground_height.npy", ArraySpec(("float32",), classes.shape, what="ground height per cell")
    )
    terrain = TerrainRaster(
        classes=classes,
        ground_height=heights,
        origin=np.asarray(meta.origin, float),
        resolution=float(meta.resolution),
        legend={int(k): v for k, v in meta.legend.items()},
    )
    regions = [
        NamedRegion(r.name, r.description, np.asarray(r.polygon, float))
        for r in read_model(gt_dir / "regions.json", GroundTruthRegions, "ground-truth regions file").regions
    ]
    return GroundTruth(objects, terrain, regions)
