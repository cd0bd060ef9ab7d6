"""Places at the gaps of a curb: where two terrains meet level inside a line of steps (a curb cut,
a driveway, a ramp), a place on the gap linked to the nearest places on each side.

Why: places of different terrains are otherwise joined only from dead ends of one terrain's GVD
(the paper's rule, terra.graph.linking.link_dead_ends) and by bridges. A walk that meets the road
through a 3 m curb cut ends in no dead end near the cut, so no edge ran through it, and a robot
that cannot climb the curb (terra.tasks.robot: a wheelchair's 5 cm) found no way across the road
although one was there. The graph stays the same for every robot: a crossing is geometry (where
the ground is level across the boundary), and a robot's profile still judges every edge.

Frames and units: the grid's (terra.graph.grid: cell (row r, col c), rows grow with y); positions
in the map frame, metres; steps in metres (terra.graph.ground's step layer).

Rule (`curb_gaps`): a boundary cell is a traversable cell with a 4-neighbour of another terrain
(both inside `traversable`). Boundary cells joined 8-connected form boundary lines; a line is a
curb when at least `min_width` metres of its cells have a step above `max_step` within
GAP_MARGIN of them (a curb reads its step unevenly). A gap is a run (8-connected) of cells of a
curb whose step is known and, with every step within GAP_MARGIN, at most `max_step`; its width,
the run's diagonal plus the margin it keeps on each side, lies between `min_width` and
`max_width` metres. Its place sits on the run's cell nearest the run's centroid, with that
cell's terrain and ground height, and clearance half the gap's width (the passage). Each of the
run's terrains is linked to the gap (`crossing_links`): the nearest of its places within
`max_distance` whose straight line crosses only traversable cells and no step above `max_step`;
a gap that reaches fewer than two terrains so is dropped.

Level links (`level_links`): a strip of one terrain can meet another level along its whole length
and still reach it only over a curb (a grass verge between a curb and a walk: its GVD runs along
it with no dead end, and its boundary with the walk holds no step, so no gap). Each place tries
the nearest places of other terrains that the graph's level edges (step at most `max_step`) do
not already join it to, and links to the first whose straight line is clear, observed all along,
away from obstacles, and level.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

from terra.graph import raster
from terra.graph.ground import edge_geometry
from terra.graph.gvd import EIGHT
from terra.graph.linking import first_passing, grid_line_clear

if TYPE_CHECKING:
    from terra.graph.grid import TerrainGrid
    from terra.graph.ground import GroundLayers

GAP_MARGIN = 0.4  # metres from any step above the limit that a gap's cells keep


@dataclass(frozen=True)
class CrossingRule:
    """What counts as a gap in a curb and how far it reaches (module docstring): steps in metres
    (`max_step`), widths in metres, the link range `max_distance` metres and the `candidates`
    tried per terrain."""

    max_step: float
    min_width: float
    max_width: float
    max_distance: float
    candidates: int


@dataclass
class CurbGaps:
    """Gaps found in curbs: the cell (k, 2) row/col of each gap's place, its terrain (k,), its
    width (k,) metres, and the terrains (k, T) bool each gap touches."""

    cell: np.ndarray
    terrain: np.ndarray
    width: np.ndarray
    touches: np.ndarray


def boundary_cells(label: np.ndarray) -> np.ndarray:
    """(H, W) bool: cells with a terrain (label >= 0) that have a 4-neighbour of another terrain."""
    out = np.zeros(label.shape, dtype=bool)
    for axis in (0, 1):
        a = np.take(label, np.arange(label.shape[axis] - 1), axis=axis)
        b = np.take(label, np.arange(1, label.shape[axis]), axis=axis)
        differ = (a >= 0) & (b >= 0) & (a != b)
        lo = [slice(None), slice(None)]
        hi = [slice(None), slice(None)]
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        out[tuple(lo)] |= differ
        out[tuple(hi)] |= differ
    return out


def curb_gaps(
    label: np.ndarray,
    step: np.ndarray,
    cell_size: float,
    max_step: float,
    min_width: float,
    max_width: float,
    terrains: int,
    margin: float = GAP_MARGIN,
) -> CurbGaps:
    """The gaps in the curbs of a grid (module docstring). label: (H, W) terrain index of each
    traversable cell, -1 elsewhere; step: (H, W) metres, NaN where unknown; `terrains`: the number
    of terrain classes."""
    boundary = boundary_cells(label)
    lines, count = raster.label(boundary, EIGHT, np.int32)
    empty = CurbGaps(np.zeros((0, 2), np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, terrains), bool))
    if count == 0:
        return empty
    # A curb reads its step unevenly along its length (a cell straddling the face holds points of
    # both levels and reads two half steps, or none): a cell is level only when no cell within
    # `margin` metres reads a step above the limit.
    reach = 2 * max(int(round(margin / cell_size)), 0) + 1
    with np.errstate(invalid="ignore"):  # NaN (unknown) is no step
        near_step = raster.grown(step > max_step, reach // 2)
    stepped = boundary & near_step
    stepped_length = np.bincount(lines[stepped], minlength=count + 1) * cell_size
    curb = stepped_length >= min_width
    curb[0] = False
    level = curb[lines] & np.isfinite(step) & ~near_step
    runs, found = raster.label(level, EIGHT, np.int32)
    if found == 0:
        return empty
    rows, cols = np.nonzero(runs)
    run = runs[rows, cols] - 1
    # The passage between the steps: the run and the margin it keeps from them on each side.
    width = _run_widths(run, rows, cols, found) * cell_size + 2.0 * (reach // 2) * cell_size
    keep = (width >= min_width) & (width <= max_width)
    anchor = _nearest_to_centroid(run, rows, cols, found)
    touches = np.zeros((found, terrains), dtype=bool)
    touches[run, label[rows, cols]] = True
    cell = np.column_stack([rows[anchor], cols[anchor]])[keep]
    return CurbGaps(cell, label[cell[:, 0], cell[:, 1]].astype(np.int64), width[keep], touches[keep])


def _run_widths(run: np.ndarray, rows: np.ndarray, cols: np.ndarray, count: int) -> np.ndarray:
    """(count,) cells: the diagonal of each run's bounding box, plus one cell (a run of one cell
    is one cell wide)."""
    spans = []
    for v in (rows, cols):
        lo = np.full(count, np.iinfo(np.int64).max)
        hi = np.full(count, np.iinfo(np.int64).min)
        np.minimum.at(lo, run, v)
        np.maximum.at(hi, run, v)
        spans.append(hi - lo)
    return np.hypot(spans[0], spans[1]) + 1.0


def _nearest_to_centroid(run: np.ndarray, rows: np.ndarray, cols: np.ndarray, count: int) -> np.ndarray:
    """(count,) index into rows/cols of each run's cell nearest the run's centroid."""
    size = np.bincount(run, minlength=count)
    centre_r = np.bincount(run, weights=rows, minlength=count) / size
    centre_c = np.bincount(run, weights=cols, minlength=count) / size
    d = (rows - centre_r[run]) ** 2 + (cols - centre_c[run]) ** 2
    order = np.lexsort((d, run))  # by run, nearest first
    first = np.flatnonzero(np.r_[True, run[order][1:] != run[order][:-1]])
    return order[first]


def crossing_links(
    gap_xy: np.ndarray,
    touches: np.ndarray,
    place_xy: np.ndarray,
    place_terrain: np.ndarray,
    traversable: np.ndarray,
    grid: TerrainGrid,
    layers: GroundLayers,
    max_step: float,
    max_distance: float,
    candidates: int,
) -> np.ndarray:
    """For gaps at `gap_xy` (k, 2) metres touching terrains `touches` (k, T): pairs (m, 2) of
    (gap index, place index) linking each gap to the nearest place of each terrain it touches
    (module docstring), among `candidates` nearest within `max_distance` metres."""
    clear = grid_line_clear(traversable, grid.origin, grid.cell_size)
    found = []
    for t in np.flatnonzero(touches.any(axis=0)):
        gaps, places = np.flatnonzero(touches[:, t]), np.flatnonzero(place_terrain == t)
        if places.size == 0:
            continue
        k = min(candidates, places.size)
        dist, idx = cKDTree(place_xy[places]).query(gap_xy[gaps], k=k, distance_upper_bound=max_distance)
        dist, idx = dist.reshape(len(gaps), k), idx.reshape(len(gaps), k)

        def passes(rows: np.ndarray, c: int, gaps=gaps, places=places, idx=idx) -> np.ndarray:
            # no step above the gap's own along the line
            return _clear_and_level(clear, layers, gap_xy[gaps[rows]], place_xy[places[idx[rows, c]]], max_step)

        first = first_passing(np.isfinite(dist), passes)
        has = first >= 0
        found.append(np.column_stack([gaps[has], places[idx[has, first[has]]]]))
    return np.vstack(found) if found else np.zeros((0, 2), dtype=np.int64)


def gap_places(
    grid: TerrainGrid,
    traversable: np.ndarray,
    layers: GroundLayers,
    place_xy: np.ndarray,
    place_terrain: np.ndarray,
    settings: CrossingRule,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The places on the curb gaps of `grid` that reach two terrains or more: positions (k, 3)
    metres, terrain (k,), clearance (k,) metres, and their links (m, 2) as (gap index, index into
    the existing places at `place_xy` (P, 2) of terrains `place_terrain` (P,))."""
    label = np.where(traversable, grid.label, np.int16(-1))
    step = np.full(grid.shape[0] * grid.shape[1], np.nan, dtype=np.float32)  # a full grid, as small as the grid's own
    step[layers.cells] = layers.step
    step = step.reshape(grid.shape)
    terrains = int(max(label.max(initial=-1), place_terrain.max(initial=-1))) + 1
    gaps = curb_gaps(label, step, grid.cell_size, settings.max_step, settings.min_width, settings.max_width, terrains)
    xy = grid.cell_centres(gaps.cell)
    links = crossing_links(
        xy, gaps.touches, place_xy, place_terrain, traversable, grid, layers,
        settings.max_step, settings.max_distance, settings.candidates,
    )  # fmt: skip
    reached = np.bincount(links[:, 0], minlength=len(xy)) >= 2
    keep = np.flatnonzero(reached)
    renumber = np.full(len(xy), -1, dtype=np.int64)
    renumber[keep] = np.arange(len(keep))
    links = links[reached[links[:, 0]]]
    links[:, 0] = renumber[links[:, 0]]
    position = np.column_stack([xy[keep], grid.ground_at(gaps.cell[keep])])
    return position, gaps.terrain[keep], gaps.width[keep] / 2, links


def level_links(
    position: np.ndarray,
    terrain: np.ndarray,
    edges: np.ndarray,
    traversable: np.ndarray,
    grid: TerrainGrid,
    layers: GroundLayers,
    max_step: float,
    max_distance: float,
    candidates: int,
) -> np.ndarray:
    """Links (m, 2) (i < j, unique) from places that the level edges cannot take to a place of
    another terrain nearby: each place at `position` (P, 3) metres of `terrain` (P,) tries its
    `candidates` nearest places of other terrains within `max_distance` metres that lie in another
    component of the graph of `edges` (E, 2) whose step reads at most `max_step` metres, and links
    to the first whose straight line crosses only traversable cells and observed ground, with no
    step above `max_step` (a strip of grass between a curb and a walk, whose GVD runs along it with
    no dead end, reached the walk only across the curb)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(position)
    xy = np.asarray(position, dtype=np.float64)[:, :2]
    flat = np.column_stack([xy, np.zeros(n)])
    level = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    level = level[edge_geometry(layers, flat, level, unseen_ends=False)[:, 0] <= max_step]
    graph = coo_matrix((np.ones(len(level)), (level[:, 0], level[:, 1])), shape=(n, n))
    _, component = connected_components(graph, directed=False)
    k = min(candidates + 1, n)
    dist, idx = cKDTree(xy).query(xy, k=k, distance_upper_bound=max_distance)
    dist, idx = dist.reshape(n, k), idx.reshape(n, k)
    other = np.minimum(idx, n - 1)
    valid = np.isfinite(dist) & (terrain[other] != terrain[:, None]) & (component[other] != component[:, None])
    clear = grid_line_clear(traversable, grid.origin, grid.cell_size)

    def passes(rows: np.ndarray, c: int) -> np.ndarray:
        a, b = rows, other[rows, c]
        ok = _clear_and_level(clear, layers, xy[a], xy[b], max_step)
        ok[ok] = _observed_line(layers, xy, np.column_stack([a[ok], b[ok]]))
        return ok

    first = first_passing(valid, passes)
    has = np.flatnonzero(first >= 0)
    pairs = np.sort(np.column_stack([has, other[has, first[has]]]), axis=1)
    return np.unique(pairs, axis=0).reshape(-1, 2).astype(np.int64)


def _clear_and_level(
    clear: Callable[[np.ndarray, np.ndarray], np.ndarray],
    layers: GroundLayers,
    a: np.ndarray,
    b: np.ndarray,
    max_step: float,
) -> np.ndarray:
    """(m,) bool: whether each straight line from `a` to `b` (m, 2) metres crosses only the cells
    `clear` (grid_line_clear) passes and no step above `max_step` metres (edge_geometry)."""
    ok = clear(a, b)
    if ok.any():
        m = int(ok.sum())
        ends = np.column_stack([np.vstack([a[ok], b[ok]]), np.zeros(2 * m)])
        pairs = np.column_stack([np.arange(m), np.arange(m) + m])
        ok[ok] = edge_geometry(layers, ends, pairs, unseen_ends=False)[:, 0] <= max_step
    return ok


def _observed_line(layers: GroundLayers, xy: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """(m,) bool: whether every cell the straight segment of each pair (m, 2) of places at `xy`
    (P, 2) metres crosses (sampled every half cell) holds ground with a known step, away from
    obstacles: across unobserved ground nothing says a link is level (a curb in its own LiDAR
    shadow), and beside an obstacle a curb's step is read along one axis only, maybe along the
    curb (`grid_layers`)."""
    if len(pairs) == 0:
        return np.zeros(0, dtype=bool)
    a, delta = xy[pairs[:, 0]], xy[pairs[:, 1]] - xy[pairs[:, 0]]
    samples = np.ceil(np.linalg.norm(delta, axis=1) / (layers.cell_size / 2)).astype(np.int64) + 1
    starts = np.concatenate([[0], np.cumsum(samples)[:-1]])
    which = np.repeat(np.arange(len(pairs)), samples)
    t = (np.arange(int(samples.sum())) - starts[which]) / np.maximum(samples[which] - 1, 1)
    at = layers.lookup(a[which] + t[:, None] * delta[which])
    known = (at >= 0) & np.isfinite(layers.step[np.maximum(at, 0)])
    if layers.near_obstacle is not None:  # beside an obstacle a curb's step may read along the curb only
        known &= ~layers.near_obstacle[np.maximum(at, 0)]
    return np.logical_and.reduceat(known, starts)
