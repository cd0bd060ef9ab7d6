"""The 2D terrain grid: majority terrain class, local ground height and blocked cells per cell.

Grid convention (same as the ground-truth raster): cell (row r, col c) covers
x in [x0 + c*s, x0 + (c+1)*s), y in [y0 + r*s, y0 + (r+1)*s) of the map frame, s = cell size in
metres; rows grow with y (no flip). Cell centres are at x0 + (c + 0.5) s, y0 + (r + 0.5) s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from terra.graph import raster
from terra.graph.gvd import EIGHT, component_sizes, label_components

OBSTACLE_BAND = (0.3, 2.0)  # metres above the ground a point blocks its cell in (build.grid.obstacle_height's default)
OBSTACLE_MIN_POINTS = 2  # such points a cell needs to be blocked (build.grid.obstacle_min_points's default)


@dataclass
class TerrainGrid:
    """label: (H, W) int16 terrain index per cell (majority of its terrain points, -1 = none or
    blocked). ground: (H, W) float32 local ground height (metres, map frame; cells without terrain
    points take the nearest cell's). blocked: (H, W) bool cells holding obstacle points.
    origin: (2,) lower-left corner of cell (0, 0), metres. cell_size: metres. offset: (row, col)
    of this grid's cell (0, 0) when it is a window of a larger grid whose cell (0, 0) lies at
    `origin` (see GridFrame); (0, 0) for a whole grid."""

    label: np.ndarray
    ground: np.ndarray
    blocked: np.ndarray
    origin: np.ndarray
    cell_size: float
    offset: tuple[int, int] = (0, 0)

    @property
    def shape(self) -> tuple[int, int]:
        return self.label.shape

    @property
    def frame(self) -> GridFrame:
        """Where the grid lies (origin, shape, cell size, offset)."""
        return GridFrame((float(self.origin[0]), float(self.origin[1])), self.shape, self.cell_size, self.offset)

    def cell_centres(self, cells: np.ndarray) -> np.ndarray:
        """(n, 2) map-frame x, y (metres) of the centres of (n, 2) row/col cells."""
        cells = np.asarray(cells, dtype=np.float64).reshape(-1, 2) + np.asarray(self.offset, dtype=np.float64)
        return self.origin + (cells[:, ::-1] + 0.5) * self.cell_size

    def cell_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, cols, inside) of map-frame points (n, 2+); rows/cols clipped into the grid."""
        rc = np.floor((np.asarray(xy)[:, :2] - self.origin) / self.cell_size).astype(np.int64)
        rows, cols = rc[:, 1] - self.offset[0], rc[:, 0] - self.offset[1]
        H, W = self.shape
        inside = (rows >= 0) & (rows < H) & (cols >= 0) & (cols < W)
        return np.clip(rows, 0, H - 1), np.clip(cols, 0, W - 1), inside

    def ground_at(self, cells: np.ndarray) -> np.ndarray:
        """Ground height (metres) at (n, 2) row/col cells."""
        cells = np.asarray(cells).reshape(-1, 2)
        return self.ground[cells[:, 0], cells[:, 1]].astype(np.float64)

    def terrain_mask(
        self, terrain: int, close_iterations: int = 1, open_iterations: int = 1, min_cells: int = 0
    ) -> tuple[np.ndarray, int]:
        """Free cells of one terrain class, cleaned morphologically, and how many patches were dropped.

        A closing fills holes left by sparse points, but only with cells that no other terrain
        claims and nothing blocks (the paper's opening of the obstacle mask); an opening then
        removes slivers; patches smaller than `min_cells` are dropped.
        """
        mask = self.label == terrain
        if close_iterations > 0:
            # In place: a full-grid temporary per operator would cost more than the mask itself.
            fillable = self.label < 0
            fillable &= ~self.blocked
            fillable |= mask
            mask = np.asarray(ndimage.binary_closing(mask, structure=EIGHT, iterations=close_iterations), dtype=bool)
            mask &= fillable
            del fillable
        if open_iterations > 0:
            mask = np.asarray(ndimage.binary_opening(mask, structure=EIGHT, iterations=open_iterations), dtype=bool)
        dropped = 0
        if min_cells > 1 and mask.any():
            labels, n = label_components(mask)
            sizes = component_sizes(labels, n)
            small = sizes < min_cells
            small[0] = False
            dropped = int(small.sum())
            if dropped:
                mask &= ~small[labels]
        return mask, dropped


@dataclass(frozen=True)
class GridFrame:
    """Where a grid lies: origin (2,) metres, the lower-left corner of cell (0, 0) of the whole
    grid, whose cell `offset` (row, col) is this frame's first; shape (H, W) cells; cell_size
    metres. A window of a frame is a frame too (`window`): it keeps
    the origin and moves the offset, so a point falls in the same cell of both, to the last bit."""

    origin: tuple[float, float]
    shape: tuple[int, int]
    cell_size: float
    offset: tuple[int, int] = (0, 0)

    def window(self, rows: slice, cols: slice) -> GridFrame:
        """The frame of cells [rows, cols] of this one (slices with explicit, in-range bounds)."""
        offset = (self.offset[0] + rows.start, self.offset[1] + cols.start)
        return GridFrame(self.origin, (rows.stop - rows.start, cols.stop - cols.start), self.cell_size, offset)


def grid_frame(points: np.ndarray, terrain: np.ndarray, cell_size: float = 0.4, margin_cells: int = 4) -> GridFrame:
    """The frame `build_terrain_grid` puts around the terrain points (N, 3) (terrain (N,) >= 0):
    their 2D bounds, snapped to the cell size, plus `margin_cells` on every side. Raises
    ValueError when there is no terrain point."""
    is_terrain = np.asarray(terrain) >= 0
    if not is_terrain.any():
        raise ValueError("the map has no terrain points")
    points = np.asarray(points)
    # Bounds without copying the points (the min of float32 values is exact in float64 too).
    low = [float(np.min(points[:, k], where=is_terrain, initial=np.inf)) for k in (0, 1)]
    high = [float(np.max(points[:, k], where=is_terrain, initial=-np.inf)) for k in (0, 1)]
    lo = np.floor(np.array(low) / cell_size) * cell_size - margin_cells * cell_size
    hi = np.array(high)
    W, H = np.floor((hi - lo) / cell_size).astype(np.int64) + 1 + margin_cells
    return GridFrame((float(lo[0]), float(lo[1])), (int(H), int(W)), float(cell_size))


def hysteresis_steps(
    cell_size: float, support_radius: float, min_support: float, weak_support: float | None, weak_reach: float | None
) -> int | None:
    """Cells: the longest chain `build_terrain_grid`'s hysteresis extends a class along (0 = the
    step is off; None = unbounded, `weak_reach` None: a label can then depend on cells at any
    distance)."""
    if weak_support is None or support_radius <= 0 or weak_support >= min_support:
        return 0
    if weak_reach is None:
        return None
    return max(int(round(weak_reach / cell_size)), 1)


def terrain_grid_reach(
    cell_size: float, support_radius: float, fill_radius: float, chain: int = 0, support_cell: float | None = None
) -> int:
    """Cells: how far a cell's label and blocked flag in `build_terrain_grid` depend on the points
    around it. The support window (half side w = round(support_radius / cell_size)) decides the
    majority label, the weak majority and, once more, which cells are densely scanned; the
    hysteresis follows a chain of `chain` cells (`hysteresis_steps`; it must be bounded), each
    cell of which reads its window; the fill takes labels within fill_radius. Ground is the
    exception (the nearest cell with terrain points or unlabelled ground, at any distance);
    terra.graph.tiled_grid checks it per cell. Keep this in step with the algorithm: the tiled
    build relies on it (and tests/graph/test_graph_tiling.py compares tiled and whole grids). The
    coverage shares of every window depend on points within ceil(support_cell / cell_size) cells
    (cell_coverage)."""
    w = int(round(support_radius / cell_size))
    coverage = int(np.ceil(support_cell / cell_size)) if support_cell is not None else 0
    return 2 * w + chain + int(np.ceil(fill_radius / cell_size)) + 2 + 2 * coverage


def build_terrain_grid(
    points: np.ndarray,
    terrain: np.ndarray,
    cell_size: float = 0.4,
    obstacle_height: tuple[float, float] | None = OBSTACLE_BAND,
    obstacle_min_points: int = OBSTACLE_MIN_POINTS,
    support_radius: float = 1.6,
    min_support: float = 0.6,
    margin_cells: int = 4,
    fill_radius: float = 0.0,
    weak_support: float | None = None,
    weak_reach: float | None = None,
    frame: GridFrame | None = None,
    support_cell: float | None = None,
) -> TerrainGrid:
    """Grid over the terrain points (N, 3) map frame, metres, with `terrain` (N,) class index per
    point (-1 = not terrain). Raises ValueError when there is no terrain point.

    Each cell's class is the majority of the cells with terrain points in a square window of half
    side `support_radius` metres, kept where at least `min_support` of the window's area holds
    terrain points (counted on squares of `support_cell` metres, see cell_coverage; None: whole
    cells, where one point of a distant scan ring covers a coarse cell): this fills the gaps
    between nearby scan lines and drops the isolated rings of distant, sparsely scanned ground,
    on which no place should sit.

    Where the cameras labelled the ground only sparsely (a road seen at a glancing angle, the far
    side of a block), a window with at least `weak_support` (< min_support) of its cells labelled
    also takes its majority (a labelled cell in a sparser window keeps its own class), on densely
    scanned ground, but only where it continues a patch of that class that meets `min_support`
    (hysteresis, connected through such cells): a strip keeps its class through a sparsely
    labelled stretch, while an isolated patch that one mislabelled image left stays unlabelled
    (None = never), reaching at most `weak_reach` metres from it along the chain (None = any
    distance: the connection is then global). Shares are of area, as above.

    Cells of ground the LiDAR scanned but no camera labelled (points without terrain votes, less
    than `obstacle_height[0]` above the local ground) take the class of the labelled cells within
    `fill_radius` metres when those all agree (0 = never): a road the cameras missed for a few
    metres stays one road instead of breaking in two, and no boundary is guessed.
    """
    points, terrain = np.asarray(points, dtype=np.float64), np.asarray(terrain)
    is_terrain = terrain >= 0
    frame = frame or grid_frame(points, terrain, cell_size, margin_cells)
    grid = empty_grid(frame)
    n_classes, has = _vote_terrain(grid, points[is_terrain], terrain[is_terrain].astype(np.int64))
    other = _scan_other_points(grid, has, points[~is_terrain], obstacle_height)
    window = 2 * int(round(support_radius / frame.cell_size)) + 1
    labelled, ground = _coverages(grid, points, is_terrain, other, obstacle_height, support_cell)
    dense = _densely_scanned(ground, window, min_support)
    raw = grid.label.copy()
    if support_radius > 0:
        grid.label[:] = _window_majority(raw, n_classes, window, min_support, labelled)
    if obstacle_height is not None:
        _block_obstacles(grid, other, obstacle_height, obstacle_min_points)
    steps = hysteresis_steps(frame.cell_size, support_radius, min_support, weak_support, weak_reach)
    if steps != 0 and weak_support is not None:  # steps is 0 when weak_support is None
        _extend_weak_labels(grid, raw, n_classes, window, weak_support, dense, steps or 0, labelled)
    if fill_radius > 0:
        _fill_from_nearest_label(grid.label, other.ground_cells & dense & ~grid.blocked, fill_radius / frame.cell_size)
    return grid


def _coverages(
    grid: TerrainGrid,
    points: np.ndarray,
    is_terrain: np.ndarray,
    other: _OtherPoints,
    obstacle_height: tuple[float, float] | None,
    support_cell: float | None,
) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) float32 coverage (cell_coverage) of the terrain points `points[is_terrain]`, and of
    all ground points: those and the other points low above the ground (`other`, located)."""
    labelled = cell_coverage(grid, points[is_terrain], support_cell)
    low = obstacle_height[0] if obstacle_height is not None else 0.3
    low_points = points[~is_terrain][other.inside & (other.height < low)]
    ground = cell_coverage(grid, np.vstack([points[is_terrain][:, :2], low_points[:, :2]]), support_cell)
    return labelled, ground


def empty_grid(frame: GridFrame) -> TerrainGrid:
    """A grid over `frame` with no label (-1), ground 0 and no blocked cell."""
    H, W = frame.shape
    return TerrainGrid(
        np.full((H, W), -1, np.int16),
        np.zeros((H, W), np.float32),
        np.zeros((H, W), bool),
        np.asarray(frame.origin, dtype=np.float64),
        float(frame.cell_size),
        frame.offset,
    )


def _vote_terrain(grid: TerrainGrid, tp: np.ndarray, tt: np.ndarray) -> tuple[int, np.ndarray]:
    """In place, from the terrain points `tp` (n, 3) and their classes `tt` (n,) int64: each cell's
    majority class and the ground of every cell. Returns the number of classes and the (H, W) bool
    cells that hold terrain points; ValueError without any."""
    if len(tt) == 0:
        raise ValueError("the map has no terrain points")
    H, W = grid.shape
    rows, cols, _ = grid.cell_of(tp)
    flat = rows * W + cols

    # Majority terrain per cell over unique (cell, class) pairs, ties to the lower class index.
    n_classes = int(tt.max()) + 1
    pair, votes = np.unique(flat * n_classes + tt, return_counts=True)
    cell, cls = pair // n_classes, pair % n_classes
    order = np.lexsort((cls, -votes, cell))
    first = np.ones(len(order), dtype=bool)
    first[1:] = cell[order][1:] != cell[order][:-1]
    grid.label.ravel()[cell[order][first]] = cls[order][first]

    # Ground: mean height of the terrain points per cell, then nearest filled cell elsewhere.
    total = np.bincount(flat, weights=tp[:, 2], minlength=H * W)
    count = np.bincount(flat, minlength=H * W)
    has = (count > 0).reshape(H, W)
    mean = (total / np.maximum(count, 1)).reshape(H, W)
    # Indices only: the distances would cost 8 bytes a cell and nothing reads them.
    nr, nc = raster.nearest_zero(~has)
    grid.ground[:] = mean[nr, nc]
    return n_classes, has


@dataclass
class _OtherPoints:
    """The points without a terrain class in a grid: their cells (row, col (n,), clipped; inside (n,)
    bool), their height above the terrain-based ground (n,) metres, and the (H, W) bool cells that
    hold unlabelled ground (such points less than the obstacle band's low end above it)."""

    row: np.ndarray
    col: np.ndarray
    inside: np.ndarray
    height: np.ndarray
    ground_cells: np.ndarray


def _scan_other_points(
    grid: TerrainGrid, has: np.ndarray, other: np.ndarray, obstacle_height: tuple[float, float] | None
) -> _OtherPoints:
    """Locate the points without a terrain class `other` (n, 3) and, in place, give the cells only
    they scanned as unlabelled ground their mean height (`has`: cells with terrain points)."""
    H, W = grid.shape
    orow, ocol, inside = grid.cell_of(other)
    height = other[:, 2] - grid.ground[orow, ocol]
    low = obstacle_height[0] if obstacle_height is not None else 0.3
    unlabelled_ground = np.zeros((H, W), dtype=bool)
    low_point = inside & (height < low)
    unlabelled_ground[orow[low_point], ocol[low_point]] = True
    # Cells scanned only by such points take their own mean height rather than that of the nearest
    # terrain cell, which can lie metres away on other ground (a bank, a field beyond a road): the
    # support window, hysteresis and filling below can label these cells, and places sit on them.
    _ground_from_unlabelled(grid.ground, has, other[low_point, 2], orow[low_point] * W + ocol[low_point])
    return _OtherPoints(orow, ocol, inside, height, unlabelled_ground)


def cell_coverage(grid: TerrainGrid, points: np.ndarray, support_cell: float | None) -> np.ndarray:
    """(H, W) float32: the share of each cell's area covered by the squares of `support_cell`
    metres that hold one of the points (n, 2+) (map frame, metres). The squares lie on the lattice
    of multiples of support_cell nearest the grid's origin, like the map's voxels
    (terra.geometry.voxel keys), so with support_cell = the map's voxel size they are its occupied
    voxel columns, whatever the cell size. None, or support_cell = cell_size: 1 where the cell
    itself holds a point, points outside the grid counting in the border cell they are clipped to
    (the grid's own rule). The coverage of a cell depends on points within
    ceil(support_cell / cell_size) cells of it."""
    H, W = grid.shape
    if support_cell is None or abs(support_cell - grid.cell_size) < 1e-9 * grid.cell_size or len(points) == 0:
        covered = np.zeros((H, W), dtype=np.float32)
        rows, cols, _ = grid.cell_of(points)
        covered[rows, cols] = 1.0
        return covered
    anchor = np.round(grid.origin / support_cell) * support_cell  # depends on the whole grid's origin only
    squares = np.unique(np.floor((np.asarray(points, dtype=np.float64)[:, :2] - anchor) / support_cell), axis=0)
    total = np.zeros(H * W, dtype=np.float64)
    start = anchor - grid.origin  # metres from the grid's origin to square 0's corner
    xs = _overlaps(squares[:, 0], support_cell, -start[0], grid.cell_size, grid.offset[1], W)
    ys = _overlaps(squares[:, 1], support_cell, -start[1], grid.cell_size, grid.offset[0], H)
    for col, width in xs:
        for row, height in ys:
            keep = (col >= 0) & (row >= 0) & (width > 0) & (height > 0)
            total += np.bincount(row[keep] * W + col[keep], weights=width[keep] * height[keep], minlength=H * W)
    return np.minimum(total / grid.cell_size**2, 1.0).astype(np.float32).reshape(H, W)


def _overlaps(
    index: np.ndarray, size: float, origin: float, cell_size: float, offset: int, n: int
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Along one axis, for squares [index * size, (index + 1) * size) (metres in the map frame):
    the cells of a grid starting at `origin` (local index, -1 outside 0..n-1) they overlap and the
    overlap lengths (metres), one (cells, lengths) pair per k-th overlapped cell."""
    lo, hi = index * size - origin, (index + 1) * size - origin
    first = np.floor(lo / cell_size + 1e-9).astype(np.int64)
    out = []
    for k in range(int(np.ceil(size / cell_size)) + 1):
        cell = first + k
        length = np.minimum(hi, (cell + 1) * cell_size) - np.maximum(lo, cell * cell_size)
        local = cell - offset
        # Lengths below a nanometre are rounding where a square's edge falls on a cell's edge.
        out.append((np.where((local >= 0) & (local < n), local, -1), np.where(length > 1e-9, length, 0.0)))
    return out


def _densely_scanned(ground: np.ndarray, window: int, min_support: float) -> np.ndarray:
    """(H, W) bool: densely scanned ground, where enough of the window's area holds ground points,
    labelled or not (`ground`: coverage per cell; sparse distant scan rings are not densely
    scanned, and are never filled)."""
    return ndimage.uniform_filter(ground, size=window, mode="constant") >= min_support - 1e-6


def _block_obstacles(
    grid: TerrainGrid, other: _OtherPoints, obstacle_height: tuple[float, float], obstacle_min_points: int
) -> None:
    """In place: cells with at least `obstacle_min_points` points in the obstacle height band are
    blocked, and lose their label."""
    H, W = grid.shape
    hit = other.inside & (other.height >= obstacle_height[0]) & (other.height <= obstacle_height[1])
    counts = np.bincount(other.row[hit] * W + other.col[hit], minlength=H * W).reshape(H, W)
    grid.blocked[:] = counts >= obstacle_min_points
    grid.label[grid.blocked] = -1


def _extend_weak_labels(
    grid: TerrainGrid,
    raw: np.ndarray,
    n_classes: int,
    window: int,
    weak_support: float,
    dense: np.ndarray,
    steps: int,
    coverage: np.ndarray | None = None,
) -> None:
    """In place: the hysteresis step, the weak majority of the cells' own labels `raw` carried along
    densely scanned, unblocked cells at most `steps` cells (0 = any number) from a label
    (`coverage`: the labelled share of each cell, see _window_majority)."""
    weak = _window_majority(raw, n_classes, window, weak_support, coverage)
    weak = np.where(weak >= 0, weak, raw)  # a labelled cell is evidence for its own class
    _extend_by_hysteresis(grid.label, np.where(dense & ~grid.blocked, weak, -1), steps)


def _ground_from_unlabelled(ground: np.ndarray, has: np.ndarray, z: np.ndarray, flat: np.ndarray) -> None:
    """In place: `ground` (H, W) metres where `has` (cells with terrain points) is False and ground
    points without a terrain class (heights `z` (n,) in flat cells `flat` (n,)) fall: their mean
    height, then, for cells with neither, the nearest cell with either."""
    H, W = ground.shape
    total = np.bincount(flat, weights=z, minlength=H * W).reshape(H, W)
    count = np.bincount(flat, minlength=H * W).reshape(H, W)
    own = ~has & (count > 0)
    if not own.any():
        return
    ground[own] = (total[own] / count[own]).astype(ground.dtype)
    nr, nc = raster.nearest_zero(~(has | own))
    ground[:] = ground[nr, nc]


def _fill_from_nearest_label(label: np.ndarray, fillable: np.ndarray, radius: float) -> None:
    """In place: `fillable` cells without a label (-1) take the class of the labelled cells within
    `radius` cells when they all have one class (a hole inside one terrain); cells near two
    classes stay unlabelled, since which side of the boundary they are on is unknown."""
    todo = fillable & (label < 0)
    classes = [int(t) for t in np.unique(label[label >= 0])]
    if not todo.any() or not classes:
        return
    rows, cols = np.nonzero(todo)
    near = np.zeros((len(classes), len(rows)), dtype=bool)
    for k, t in enumerate(classes):
        near[k] = raster.distance_to_zero(label != t)[rows, cols] <= radius
    one = near.sum(axis=0) == 1
    label[rows[one], cols[one]] = np.asarray(classes, dtype=label.dtype)[np.argmax(near[:, one], axis=0)]


def _extend_by_hysteresis(label: np.ndarray, weak: np.ndarray, max_steps: int = 0) -> None:
    """In place: unlabelled cells take their `weak` class (-1 = none) where they are 8-connected,
    through cells of that class (strong or weak), to a cell already labelled with it, within
    `max_steps` cells along that chain (0 = any number)."""
    for t in np.unique(weak[weak >= 0]):
        strong = label == t
        reached = np.asarray(
            ndimage.binary_dilation(strong, structure=EIGHT, iterations=max_steps, mask=(weak == t) | strong),
            dtype=bool,
        )
        label[reached & (label < 0)] = t


def _window_majority(
    label: np.ndarray, n_classes: int, window: int, min_support: float, coverage: np.ndarray | None = None
) -> np.ndarray:
    """Majority class of each `window` x `window` neighbourhood (ties to the lower class), -1 where
    less than `min_support` of it is labelled: of its cells, or of its area where `coverage` (H, W)
    gives the labelled share of each cell (cell_coverage)."""
    best = np.full(label.shape, -1, dtype=np.int16)
    best_count = np.zeros(label.shape, dtype=np.float32)
    support = np.zeros(label.shape, dtype=np.float32)
    for t in range(n_classes):
        share = ndimage.uniform_filter((label == t).astype(np.float32), size=window, mode="constant")
        support += share
        better = share > best_count + 1e-6
        best[better] = t
        best_count[better] = share[better]
    if coverage is not None:
        support = ndimage.uniform_filter(coverage, size=window, mode="constant")
    best[support < min_support - 1e-6] = -1
    return best


def block_under_objects(grid: TerrainGrid, max_extent: float) -> int:
    """In place: block the free cells inside the convex hull of each object-sized outline of
    blocked cells (an 8-connected blocked component whose bounding box is at most `max_extent`
    metres on each side), and take their label; returns how many cells it blocked.

    A LiDAR that sees a parked car from the road sees its near side and the ground under its body
    through the gap beneath the sills, but not its roof: the car is a ring of blocked cells around
    free ground, and a place there would sit under the car, linked out across its sides (and
    across the curb it stands against). Larger outlines (buildings, hedges, fences) are left alone:
    the hull of an L-shaped building would swallow the yard it frames."""
    labels, _ = raster.label(grid.blocked, EIGHT)
    limit = max_extent / grid.cell_size
    added = 0
    for k, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is None:
            continue
        rows, cols = box[0].stop - box[0].start, box[1].stop - box[1].start
        if rows < 3 or cols < 3 or max(rows, cols) > limit:
            continue  # nothing can lie inside a strip one or two cells wide
        inside = _inside_hull(labels[box] == k) & ~grid.blocked[box]
        if inside.any():
            grid.blocked[box] |= inside
            grid.label[box][inside] = -1
            added += int(inside.sum())
    return added


def _inside_hull(mask: np.ndarray) -> np.ndarray:
    """(h, w) bool: the cells whose centre lies in the convex hull of the centres of `mask`'s
    (h, w) True cells (on its boundary included); all False when they lie on one line."""
    from scipy.spatial import ConvexHull, QhullError

    cells = np.argwhere(mask).astype(np.float64)
    try:
        hull = ConvexHull(cells)
    except QhullError:  # collinear: a straight wall encloses nothing
        return np.zeros_like(mask)
    grid = np.indices(mask.shape).reshape(2, -1).T.astype(np.float64)
    distance = grid @ hull.equations[:, :2].T + hull.equations[:, 2]
    return (distance <= 1e-9).all(axis=1).reshape(mask.shape)
