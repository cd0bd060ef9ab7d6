"""Ground from LiDAR (terra.graph.ground): segmentation against hand-made scenes, the simulator's
labels and a real KITTI scan; geometry layers and edge geometry against hand-worked values; and
the LiDAR-only path end to end (bag without images -> map -> build -> plan; find refused)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.cli import run
from terra.graph import pipeline
from terra.graph.config import BuildConfig
from terra.graph.grid import GridFrame
from terra.graph.ground import (
    BESIDE,
    GroundLayers,
    axis_step,
    block_above_ground,
    despike,
    edge_geometry,
    grid_layers,
    ground_layers,
    heights_in_gaps,
    segment_ground,
    step_lines,
)
from terra.graph.pipeline import build_scene_graph
from terra.graph.storage import load_scene_graph
from tests.graph.fixtures_ground import points_map

DATA = Path(__file__).resolve().parents[1] / "data" / "kitti"
CELL = 0.4
TAN10 = np.tan(np.radians(10.0))


def f1(found: np.ndarray, truth: np.ndarray) -> float:
    tp = int((found & truth).sum())
    return 2 * tp / (2 * tp + int((found & ~truth).sum()) + int((~found & truth).sum()))


def uniform(rng: np.random.Generator, lo, hi, n: int) -> np.ndarray:
    return rng.uniform(lo, hi, (n, len(lo)))


def street(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A hand-made street, metres: a road (z = 0) rising 2 % along x, a sidewalk 0.15 m above it
    beyond y = 6, a car (a hollow box 0.3..1.5 m high), a wall 4 m high and a tree (trunk and
    canopy). Returns the points (N, 3) and which are ground (N,)."""
    rng = np.random.default_rng(seed)
    road = uniform(rng, [0, 0], [30, 6], 30000)
    walk = uniform(rng, [0, 6], [30, 10], 20000)
    ground = np.vstack([np.column_stack([road, 0.02 * road[:, 0]]), np.column_stack([walk, 0.02 * walk[:, 0] + 0.15])])
    ground[:, 2] += rng.normal(0.0, 0.01, len(ground))
    car = uniform(rng, [10, 1, 0.3], [14.5, 2.8, 1.5], 4000)
    car[: len(car) // 2, 1] = 1.0  # its near side and its roof
    car[len(car) // 2 :, 2] = 1.5
    car[:, 2] += 0.02 * car[:, 0]
    wall = uniform(rng, [0, 10.05, 0.3], [30, 10.1, 4.0], 6000)
    trunk = uniform(rng, [20, 8, 0.4], [20.3, 8.3, 2.5], 500)
    canopy = uniform(rng, [18, 6, 2.5], [23, 10, 5.0], 3000)
    points = np.vstack([ground, car, wall, trunk, canopy])
    truth = np.zeros(len(points), dtype=bool)
    truth[: len(ground)] = True
    return points, truth


def test_segmentation_of_a_hand_made_street():
    points, truth = street()
    found = segment_ground(points)
    assert f1(found, truth) > 0.995
    assert found[truth].mean() > 0.995  # the road, the 15 cm step and the sidewalk are ground
    above = points[:, 2] - 0.02 * points[:, 0] - np.where(points[:, 1] >= 6.0, 0.15, 0.0)
    assert not found[above > 0.5].any()  # nothing half a metre above the ground is


def test_segmentation_against_the_simulators_labels(tiny_campus):
    from terra.datasets.sim_classes import SIM_CLASSES, class_id

    ground_ids = [c.id for c in SIM_CLASSES if c.terrain] + [class_id("crosswalk")]
    points, labels = [], []
    for i in range(0, 40, 4):
        frame = tiny_campus[i]
        T = frame.T_map_lidar
        points.append(frame.points @ T[:3, :3].T + T[:3, 3])
        labels.append(frame.point_labels)
    truth = np.isin(np.concatenate(labels), ground_ids)
    assert f1(segment_ground(np.vstack(points)), truth) > 0.98  # 0.99 measured


def test_segmentation_of_a_real_kitti_scan_agrees_with_patchworkpp():
    scan = np.fromfile(DATA / "000000_every12th.bin", dtype=np.float32).reshape(-1, 4)
    reference = np.load(DATA / "000000_every12th_patchworkpp_ground.npy", allow_pickle=False).astype(bool)
    found = segment_ground(scan[:, :3])
    assert f1(found, reference) > 0.94  # 0.956 measured (0.972 on the full scan)
    assert 0.5 < found.mean() < 0.75  # a street scan: about 60 % of its points hit the ground


@pytest.mark.parametrize("scan", ["00/000000", "00/000002", "07/000964"])
def test_a_real_roads_interior_reads_no_step_and_its_curbs_do(scan):
    """Real SemanticKITTI scans (tests/data/semantickitti, forward wedges) and their human labels:
    the step layer on segment_ground's ground reads no step (at most 5 cm) on at least 98 % of the
    cells whose points are all road with no other ground within two cells (0.2 to 0.7 % read more,
    measured), and does read the curbs of 07/000964 (road cells beside a sidewalk: 99th percentile
    65 cm, measured)."""
    from scipy import ndimage

    from terra.eval.ground_segmentation import read_labelled_scan

    sequence = DATA.parent / "semantickitti" / "sequences" / scan.split("/")[0]
    name = scan.split("/")[1]
    points, labels = read_labelled_scan(sequence / "velodyne" / f"{name}.bin", sequence / "labels" / f"{name}.label")
    ground = segment_ground(points)
    xy, labels = points[ground, :2].astype(np.float64), labels[ground]
    low = xy.min(axis=0) - 1.0
    size = np.ceil((xy.max(axis=0) + 1.0 - low) / CELL).astype(int)
    shape = (int(size[1]), int(size[0]))
    layers = ground_layers(points[ground], GridFrame((float(low[0]), float(low[1])), shape, CELL))
    cell = np.floor((xy - low) / CELL).astype(np.int64)
    flat = cell[:, 1] * shape[1] + cell[:, 0]
    count = np.bincount(flat, minlength=shape[0] * shape[1])
    road = np.asarray((np.bincount(flat, labels == 40, len(count)) == count) & (count > 0), dtype=bool).reshape(shape)
    other = (count > 0).reshape(shape) & ~road
    interior = road & ~np.asarray(ndimage.binary_dilation(other, np.ones((5, 5), dtype=bool)), dtype=bool)
    step = layers.as_grid(layers.step)
    read = step[interior & np.isfinite(step)]
    assert len(read) > 100 and np.mean(read > 0.05) <= 0.02
    if scan == "07/000964":
        walk = (np.bincount(flat[labels == 48], minlength=len(count)) > 0).reshape(shape)
        beside = step[road & ndimage.binary_dilation(walk, np.ones((3, 3), dtype=bool)) & np.isfinite(step)]
        assert np.percentile(beside, 99) > 0.15


def test_a_real_kitti_scan_alone_builds_places_on_the_road():
    # One real scan, no labels, no camera: the LiDAR-only path on real data. The sensor is 1.73 m
    # above the road (KITTI's mount), and the street around it lies 1.6 to 2.1 m below it; every
    # place stands on the ground Patchwork++ found (its labels, the reference): within 10 cm of
    # the median height of Patchwork++'s ground points within 1 m.
    scan = np.fromfile(DATA / "000000_every12th.bin", dtype=np.float32).reshape(-1, 4)
    reference = np.load(DATA / "000000_every12th_patchworkpp_ground.npy", allow_pickle=False).astype(bool)
    graph = build_scene_graph(points_map(scan[:, :3])).graph
    assert graph.terrain_classes == ["ground"] and len(graph.places) >= 3 and graph.has_edge_geometry
    position = graph.places.position
    assert np.all((position[:, 2] < -1.5) & (position[:, 2] > -2.2)), position
    ground = scan[reference, :3]
    for x, y, z in position:
        near = np.hypot(ground[:, 0] - x, ground[:, 1] - y) < 1.0
        assert near.sum() >= 5 and abs(z - np.median(ground[near, 2])) < 0.1, (x, y, z)
    assert np.linalg.norm(graph.places.position[:, :2], axis=1).max() < 30.0  # on the densely scanned road


def flat_frame(width: float, depth: float, cell: float = 0.4) -> GridFrame:
    return GridFrame((0.0, 0.0), (int(round(depth / cell)), int(round(width / cell))), cell)


def test_layers_of_a_ten_degree_slope():
    rng = np.random.default_rng(1)
    xy = uniform(rng, [0, 0], [20, 10], 60000)
    points = np.column_stack([xy, TAN10 * xy[:, 0] + rng.normal(0, 0.01, len(xy))])
    layers = ground_layers(points, flat_frame(20, 10))
    inner = (slice(2, -2), slice(2, -2))
    assert layers.observed.all() and len(layers.cells) == 25 * 50
    assert np.nanmedian(layers.as_grid(layers.slope)[inner]) == pytest.approx(10.0, abs=0.2)
    assert np.nanmedian(layers.as_grid(layers.gradient)[inner][..., 0]) == pytest.approx(TAN10, abs=0.005)
    assert np.nanmax(layers.as_grid(layers.step)[inner]) < 0.05  # a slope is no step
    # The noise (1 cm), not the tilt within the cell (0.4 m x tan 10 deg / sqrt(12) = 2 cm).
    assert np.nanmedian(layers.as_grid(layers.roughness)[inner]) == pytest.approx(0.01, abs=0.003)


def test_a_curb_is_a_step_on_both_cells_beside_it():
    rng = np.random.default_rng(2)
    xy = uniform(rng, [0, 0], [20, 10], 60000)
    points = np.column_stack([xy, np.where(xy[:, 1] >= 5.0, 0.15, 0.0)])
    layers = ground_layers(points, flat_frame(20, 10))
    column = layers.as_grid(layers.step)[:, 25]
    # The curb at y = 5.0 runs through row 12 (y 4.8..5.2), whose mean height is 0.075: by hand,
    # row 12 reads |0.15 - 0| - 2 x mean(0, 0) = 0.15; rows 11 and 13 read
    # |0.075 - 0| - 2 x mean(0, 0.075) = 0.
    assert column[12] == pytest.approx(0.15, abs=0.01)
    assert column[11] < 0.01 and column[13] < 0.01
    assert np.all(column[1:11] < 0.01) and np.all(column[14:-1] < 0.01)
    # A curb on a cell boundary (y = 4.8) reads on both cells beside it.
    points[:, 2] = np.where(points[:, 1] >= 4.8, 0.15, 0.0)
    layers = ground_layers(points, flat_frame(20, 10))
    column = layers.as_grid(layers.step)[:, 25]
    assert column[11] == pytest.approx(0.15, abs=0.01) and column[12] == pytest.approx(0.15, abs=0.01)
    assert column[10] < 0.01 and column[13] < 0.01


def test_one_off_centre_point_per_cell_on_a_slope_reads_no_step():
    # A map keeps one point per voxel, anywhere in its cell: the cell's height is moved to its
    # centre along the gradient (else 9 degrees x up to 0.2 m off-centre reads as a 3 cm step).
    rng = np.random.default_rng(4)
    rows, cols = np.mgrid[0:25, 0:50]
    xy = (np.column_stack([cols.ravel(), rows.ravel()]) + rng.uniform(0.0, 1.0, (rows.size, 2))) * CELL
    tan9 = np.tan(np.radians(9.0))
    layers = ground_layers(np.column_stack([xy, tan9 * (xy[:, 0] + 0.5 * xy[:, 1])]), flat_frame(20, 10))
    inner = (slice(3, -3), slice(3, -3))
    assert np.nanmax(layers.as_grid(layers.step)[inner]) < 0.005
    expected = np.degrees(np.arctan(tan9 * np.hypot(1.0, 0.5)))
    assert np.nanmax(np.abs(layers.as_grid(layers.slope)[inner] - expected)) < 0.05
    centres = (np.column_stack([cols.ravel(), rows.ravel()]) + 0.5) * CELL
    truth = tan9 * (centres[:, 0] + 0.5 * centres[:, 1])
    assert np.allclose(layers.as_grid(layers.height).ravel(), truth, atol=1e-3, equal_nan=False)


def test_step_lines_keep_lines_of_steps_above_the_limit():
    step = np.zeros((10, 12), dtype=np.float32)
    step[2, 1:6] = 0.15  # a curb, 5 cells: a line
    step[6, 8] = 0.30  # a stone: one cell
    step[8, 2:4] = 0.12  # two cells: too short
    step[5, 1:7] = 0.06  # a long line of small steps: under the limit
    step[0, 9], step[1, 10], step[2, 11] = 0.1, 0.1, 0.1  # three cells joined diagonally: a line
    unobserved = np.zeros(step.shape, bool)
    unobserved[2, 3] = True  # a hole in the curb's cells: the line's two halves are 2 cells each
    cells = np.flatnonzero(~unobserved.ravel())
    n = len(cells)
    zeros = np.zeros(n, np.float32)
    layers = GroundLayers(
        cells, zeros, np.zeros((n, 2), np.float32), step.ravel()[cells], zeros, step.shape, np.zeros(2), CELL
    )
    expected = np.zeros(step.shape, bool)
    expected[0, 9] = expected[1, 10] = expected[2, 11] = True
    assert np.array_equal(step_lines(layers, 0.08, min_cells=3, close=0), expected)
    with_pairs = expected.copy()
    with_pairs[2, [1, 2, 4, 5]] = with_pairs[8, 2:4] = True
    assert np.array_equal(step_lines(layers, 0.08, min_cells=2, close=0), with_pairs)
    # Closed (the default, one iteration): the curb's hole is filled and it is one line of 5 cells
    # again; the stone and the pair stay apart from everything (3 columns from the diagonal line).
    expected[2, 1:6] = True
    assert np.array_equal(step_lines(layers, 0.08), expected)


def test_an_edge_over_a_line_of_steps_reads_at_least_its_step():
    # Flat ground on a 10 x 10 grid of 0.4 m cells, but row 5 (y 2.0..2.4 m) holds no ground: a
    # curb's LiDAR shadow, where a line of steps was found (GroundLayers.lines).
    shape = (10, 10)
    cells = np.flatnonzero(np.arange(100) // 10 != 5)
    n = len(cells)
    zeros = np.zeros(n, np.float32)
    layers = GroundLayers(cells, zeros, np.zeros((n, 2), np.float32), zeros, zeros, shape, np.zeros(2), CELL)
    position = np.array([[2.0, 1.0, 0.0], [2.0, 3.0, 0.0], [3.5, 1.0, 0.0]])
    edges = np.array([[0, 1], [0, 2]])
    assert np.allclose(edge_geometry(layers, position, edges)[:, 0], 0.0)  # unobserved: nothing read
    layers.lines = np.zeros(shape, bool)
    layers.lines[5] = True
    layers.line_step = 0.08
    assert np.allclose(edge_geometry(layers, position, edges)[:, 0], [0.08, 0.0])  # across / beside


def test_an_edge_from_a_place_without_ground_steps_to_the_first_ground_along_it():
    """A curb's low side in its own LiDAR shadow: on a 10 x 10 grid of 0.4 m cells, columns 0-2 (x
    < 1.2 m) are ground at 0 m, columns 3-4 hold no ground, columns 5-9 (x >= 2.0 m) are the top
    at 0.15 m. A place on column 3 took its height (0 m) from the nearest ground; its edge to the
    top sees only the top, level, and steps by the 0.15 m between them. A place outside the grid
    steps by nothing of its own (edge 3-5); its edge to the top crosses the shadow between the two
    levels, which reads the curb (3-1). A place on column 3 at the top's height is no surer of its
    level: the low side 0.4 m behind it, past its edge's start, says it may stand below (4-2)."""
    shape = (10, 10)
    col = np.arange(100) % 10
    cells = np.flatnonzero((col <= 2) | (col >= 5))
    n = len(cells)
    height = np.where(col[cells] >= 5, 0.15, 0.0).astype(np.float32)
    zeros = np.zeros(n, np.float32)
    layers = GroundLayers(cells, height, np.zeros((n, 2), np.float32), zeros, zeros, shape, np.zeros(2), CELL)
    position = np.array(
        [
            [1.4, 2.0, 0.0],  # 0: column 3, no ground
            [3.0, 2.0, 0.15],  # 1: the top
            [3.8, 2.0, 0.15],  # 2: the top
            [-1.0, 2.0, 0.0],  # 3: outside the grid: nothing known of its cell
            [1.4, 3.0, 0.15],  # 4: column 3 again, at the top's height
            [0.6, 2.0, 0.0],  # 5: the low side
        ]
    )
    edges = np.array([[0, 1], [1, 0], [1, 2], [3, 5], [4, 2], [3, 1]])
    expected = [0.15, 0.15, 0.0, 0.0, 0.15, 0.15]
    np.testing.assert_allclose(edge_geometry(layers, position, edges)[:, 0], expected, atol=1e-6)
    assert np.allclose(edge_geometry(layers, position, edges, unseen_ends=False)[:, 0], 0.0)


def test_an_edge_to_a_place_in_a_hole_reads_the_ground_past_the_place():
    """Sparsely scanned ground: on a 10 x 10 grid of 0.4 m cells, columns 0-3 (x < 1.6 m) are a
    curb's top at 0.15 m, columns 4-6 hold no ground (a hole between scan rings), columns 7-9 (x
    >= 2.8 m) are the road at 0 m. A place on column 5 (x 2.2 m) took its height from the nearest
    ground, the top. Its edge from the top sees only the top and its own place, level; the road
    1 m past the place says the place may stand below the curb: 0.15 m, both ways. With the road
    at the top's height, or no ground within 2 m past the place, nothing is read."""
    shape = (10, 10)
    col = np.arange(100) % 10
    cells = np.flatnonzero((col <= 3) | (col >= 7))
    n = len(cells)
    zeros = np.zeros(n, np.float32)

    def layers(road: float, last: int = 7) -> GroundLayers:
        keep = (col[cells] <= 3) | (col[cells] >= last)
        height = np.where(col[cells] <= 3, 0.15, road).astype(np.float32)
        full = GroundLayers(cells, height, np.zeros((n, 2), np.float32), zeros, zeros, shape, np.zeros(2), CELL)
        return only_cells(full, keep)

    position = np.array([[0.6, 2.0, 0.15], [2.2, 2.0, 0.15]])
    edges = np.array([[0, 1], [1, 0]])
    np.testing.assert_allclose(edge_geometry(layers(0.0), position, edges)[:, 0], 0.15, atol=1e-6)
    np.testing.assert_allclose(edge_geometry(layers(0.15), position, edges)[:, 0], 0.0, atol=1e-6)
    assert layers(0.0, last=10).cells.size == 40  # the road gone from the grid: 2.4 m of hole past the place
    np.testing.assert_allclose(edge_geometry(layers(0.0, last=10), position, edges)[:, 0], 0.0, atol=1e-6)


def test_the_ground_past_a_place_in_a_hole_is_clear_ground():
    """A place in a hole (column 5, x 2.2 m) at the road's height (0) below a curb's top (columns
    0-3, 0.15 m), with an object's foot past it: column 7 holds 'ground' at the top's height but
    lies beside a blocked cell, and columns 8-9 hold none. Read past the place, the object's foot
    made the edge from the top level; it is no clear ground, as along an edge (the step layer and
    the slopes leave such cells out), and with none past the place within 2 m the place's own
    height tells: 0.15 m."""
    shape = (10, 10)
    col = np.arange(100) % 10
    cells = np.flatnonzero((col <= 3) | (col == 7))
    n = len(cells)
    zeros = np.zeros(n, np.float32)
    height, gradient = np.full(n, 0.15, np.float32), np.zeros((n, 2), np.float32)
    layers = GroundLayers(cells, height, gradient, zeros, zeros, shape, np.zeros(2), CELL)
    layers.near_obstacle = col[cells] == 7
    position = np.array([[0.6, 2.0, 0.15], [2.2, 2.0, 0.0]])
    np.testing.assert_allclose(edge_geometry(layers, position, np.array([[0, 1], [1, 0]]))[:, 0], 0.15, atol=1e-6)
    layers.near_obstacle = np.zeros(n, dtype=bool)  # clear ground at the top's height past it: level
    np.testing.assert_allclose(edge_geometry(layers, position, np.array([[0, 1]]))[:, 0], 0.0, atol=1e-6)


def test_an_edge_to_a_place_in_a_hole_on_a_slope_reads_no_step():
    """Ground falling 3 degrees along x (5.2 cm a metre) on a 10 x 10 grid of 0.4 m cells, with no
    ground over columns 4-6 (x 1.6..2.8 m, a hole between scan rings). A place in the hole (x 2.2
    m) took the height of the nearest ground beyond it (x 3.0 m); from the first ground along its
    edge back (x 1.6 m) it lies 7 cm lower, all of it the slope, which the ground on both sides of
    the hole explains: no step. Read from the place's own height, as an edge whose end has no
    ground past it is, the 7 cm were a step a wheelchair refused."""
    shape = (10, 10)
    col = np.arange(100) % 10
    cells = np.flatnonzero((col <= 3) | (col >= 7))
    n = len(cells)
    grade = np.tan(np.radians(3.0))
    height = (-grade * (col[cells] + 0.5) * CELL).astype(np.float32)
    gradient = np.column_stack([np.full(n, -grade), np.zeros(n)]).astype(np.float32)
    zeros = np.zeros(n, np.float32)
    layers = GroundLayers(cells, height, gradient, zeros, zeros, shape, np.zeros(2), CELL)
    position = np.array([[0.6, 2.0, -grade * 0.6], [2.2, 2.0, -grade * 3.0]])
    step = edge_geometry(layers, position, np.array([[0, 1], [1, 0]]))[:, 0]
    np.testing.assert_allclose(step, 0.0, atol=0.01)
    cut = only_cells(layers, col[cells] <= 3)  # nothing past the place: its own height is all there is
    assert edge_geometry(cut, position, np.array([[0, 1]]))[0, 0] > 0.06


def street_beside_a_car(rise: float = 0.15, slope: float = 0.0) -> GroundLayers:
    """A 12 x 4 m grid of 0.4 m cells: a road (y < 2 m) and its raised side (y >= 2 m, `rise`
    metres up), on a ground sloping `slope` metres per metre along y. A car parked at x 4..8 m
    against the curb: its cells and those beside it are near an obstacle, where the step layer
    reads the curb along its length only (grid_layers), so 0; elsewhere the curb's two cells
    read `rise`, the rest 0, and every gradient is the slope's."""
    shape = (10, 30)
    rows, cols = np.divmod(np.arange(300), 30)
    y, x = (rows + 0.5) * CELL, (cols + 0.5) * CELL
    height = (slope * y + np.where(y >= 2.0, rise, 0.0)).astype(np.float32)
    near = (x > 4.0) & (x < 8.0)
    step = np.where((rows == 4) | (rows == 5), rise, 0.0)
    step = np.where(near, 0.0, step).astype(np.float32)
    gradient = np.column_stack([np.zeros(300), np.full(300, slope)]).astype(np.float32)
    layers = GroundLayers(np.arange(300), height, gradient, step, np.zeros(300, np.float32), shape, np.zeros(2), CELL)
    layers.near_obstacle = near
    return layers


def only_cells(layers: GroundLayers, keep: np.ndarray) -> GroundLayers:
    """The layers of the observed cells where `keep` (n,) bool: the others hold no ground."""
    index = np.flatnonzero(keep)
    out = GroundLayers(
        layers.cells[index], layers.height[index], layers.gradient[index], layers.step[index],
        layers.roughness[index], layers.shape, layers.origin, layers.cell_size,
    )  # fmt: skip
    if layers.near_obstacle is not None:
        out.near_obstacle = layers.near_obstacle[index]
    return out


def test_an_edge_past_a_parked_car_reads_the_curb_it_hides():
    """From the road before the car to the raised side after it, the edge crosses the curb beside
    the car, where no cell reads its step: the 0.15 m between the clear ground on both sides of
    the car, which the flat road does not explain, is a step. The same edge on a 5 % slope with
    no curb climbs 0.15 m as well, explained by the slope on both sides: no step."""
    position = np.array([[3.0, 0.6, 0.0], [9.0, 3.4, 0.15]])
    edges = np.array([[0, 1], [1, 0]])
    np.testing.assert_allclose(edge_geometry(street_beside_a_car(), position, edges)[:, 0], 0.15, atol=0.005)
    hill = street_beside_a_car(rise=0.0, slope=0.05)
    position[:, 2] = 0.05 * position[:, 1]
    assert np.all(edge_geometry(hill, position, edges)[:, 0] < 0.005)
    # Along the road past the car (level, clear both sides): nothing hidden.
    along = np.array([[1.0, 0.6, 0.0], [11.0, 0.6, 0.0]])
    assert edge_geometry(street_beside_a_car(), along, np.array([[0, 1]]))[0, 0] < 0.005


def test_a_place_the_car_hid_keeps_its_own_height_across_the_gap():
    """A place on the raised side right behind the car, in a cell without ground (its height
    0.15 m), linked to the road before the car: the place's height is the far side of the gap."""
    layers = street_beside_a_car()
    x, y = layers.centres(np.arange(300)).T
    cut = only_cells(layers, ~((x > 6.0) & (x < 8.0) & (y > 2.0)))
    position = np.array([[2.0, 0.6, 0.0], [7.0, 2.6, 0.15]])
    assert edge_geometry(cut, position, np.array([[0, 1]]))[0, 0] == pytest.approx(0.15, abs=0.005)
    # Without heights on the places (the crossings' straight lines), nothing is read across.
    assert edge_geometry(cut, position, np.array([[0, 1]]), unseen_ends=False)[0, 0] < 0.005


def test_a_gap_without_ground_reads_the_step_its_sides_leave_unexplained():
    """4 m without a point between the road and the raised side (ground the sensor never saw, no
    car's side): the 0.15 m between the level ground on its two sides is a step; on a 5 % slope
    without a curb, the same 0.15 m over 3 m is the slope's."""
    xy = np.array([[3.0, 0.6], [9.0, 3.4]])
    curb = (street_beside_a_car(), np.array([0.0, 0.15]), 0.15)
    slope = (street_beside_a_car(rise=0.0, slope=0.05), 0.05 * xy[:, 1], 0.0)
    for layers, z, step in (curb, slope):
        x = layers.centres(np.arange(300))[:, 0]
        cut = only_cells(layers, (x < 4.0) | (x > 8.0))
        cut.near_obstacle = None
        position = np.column_stack([xy, z])
        assert edge_geometry(cut, position, np.array([[0, 1], [1, 0]]))[:, 0] == pytest.approx(step, abs=0.005)


def test_a_cell_beside_a_pole_whose_neighbours_lie_in_a_line_keeps_its_height():
    """Flat ground (z = 0, one point per cell near its centre) with a pole's footprint and shadow
    emptying the cells above and below cell (12, 25): its 3 x 3 neighbourhood holds three cells,
    their points all 17-18 cm off-centre in y and 1.5 cm apart in height. The plane through them
    climbs 1.5 cm over 1 cm (56 degrees); carried along it the cell would sit 25 cm below its
    neighbours, a step that cuts the ground in two. Fits steeper than 45 degrees keep the mean."""
    rows, cols = np.mgrid[0:25, 0:50]
    keep = ~((np.abs(rows - 12) == 1) & (np.abs(cols - 25) <= 1))
    offset = np.zeros((25, 50, 2))
    offset[12, 24:27, 1] = [0.18, 0.17, 0.18]
    z = np.zeros((25, 50))
    z[12, [24, 26]] = 0.015
    xy = (np.stack([cols, rows], axis=-1) + 0.5) * CELL + offset
    points = np.column_stack([xy[keep], z[keep]])
    layers = ground_layers(points, flat_frame(20, 10))
    assert np.degrees(np.arctan(np.hypot(*layers.as_grid(layers.gradient)[12, 25]))) == pytest.approx(56.3, abs=0.1)
    height = layers.as_grid(layers.height)
    assert height[12, 25] == pytest.approx(0.0, abs=1e-9)  # its mean, not 0 - 1.5 x 0.17
    assert np.nanmax(layers.as_grid(layers.step)[11:14, 23:28]) < 0.03
    # A plane under 45 degrees still carries the mean to the centre (2 cm off-centre, 30 degrees).
    tan30 = np.tan(np.radians(30.0))
    ramp = np.column_stack([xy.reshape(-1, 2) + [0.02, 0.0], tan30 * (xy.reshape(-1, 2)[:, 0] + 0.02)])
    slope = ground_layers(ramp, flat_frame(20, 10))
    centres = (cols + 0.5) * CELL
    assert np.allclose(slope.as_grid(slope.height)[3:-3, 3:-3], tan30 * centres[3:-3, 3:-3], atol=1e-6)


def test_despike_by_hand():
    h = np.zeros((5, 6))
    h[:, 3:] = 0.15  # a curb between columns 2 and 3
    h[1, 1] = 0.1  # a stray point
    h[4, 5] = np.nan  # an unobserved cell
    out = despike(h)
    assert out[1, 1] == 0.0  # 10 cm above all four neighbours: their median
    expected = h.copy()
    expected[1, 1] = 0.0
    np.testing.assert_array_equal(out, expected)  # the curb and everything else unchanged
    h[0, 0] = 0.1  # a corner cell has two neighbours: too few to call it a stray
    assert despike(h)[0, 0] == 0.1


def test_axis_step_by_hand():
    # heights along x: flat, a 0.2 m step, flat; then a constant slope of 0.1 per cell
    h = np.array([[0.0, 0.0, 0.0, 0.2, 0.2, 0.2, 0.3, 0.4, 0.5, 0.6]])
    step = axis_step(h, axis=1)
    # cell 2: |0.2 - 0| - 2 x mean(0, 0) = 0.2; cell 4: |0.3 - 0.2| - 2 x mean(0.2, 0.1) = 0 (floored)
    assert step[0, 2] == pytest.approx(0.2) and step[0, 3] == pytest.approx(0.2)
    assert step[0, 4] == pytest.approx(0.0) and step[0, 7] == pytest.approx(0.0)
    assert np.isnan(step[0, 0]) and np.isnan(step[0, -1])  # one neighbour missing: unknown


def test_a_curb_cut_ramp_reads_no_step_where_it_meets_the_level():
    """A curb cut: 15 cm down a ramp of three 0.4 m cells (5 cm a cell, 7.1 degrees, under the
    wheelchair's 8) between two level walks. Each cell's jump is what the steeper of its two
    sides' slopes explains: no step anywhere (with the mean of the two sides, the ramp's cells at
    5 and 10 cm, each with a level side, read 5 cm, the wheelchair's limit). The same 15 cm as a
    curb: 15 cm."""
    ramp = np.array([[0.0, 0.0, 0.0, 0.0, 0.05, 0.10, 0.15, 0.15, 0.15, 0.15]])
    np.testing.assert_allclose(axis_step(ramp, axis=1)[0, 1:-1], 0.0, atol=1e-12)
    curb = np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 0.15, 0.15, 0.15, 0.15, 0.15]])
    np.testing.assert_allclose(axis_step(curb, axis=1)[0, 4:6], 0.15)


def test_a_step_reads_across_three_cells_of_shadow():
    """Seen from its top, a 15 cm curb hid three cells (1.2 m) of the road beyond it on the
    simulated campus; the cells on both sides of the shadow read the step across it, from the
    nearest heights four cells apart, less the level ground's slope (0). Four cells of shadow
    are more than a step is read across: unknown."""
    h = np.array([[0.15, 0.15, 0.15, 0.15, np.nan, np.nan, np.nan, 0.0, 0.0, 0.0]])
    step = axis_step(h, axis=1, rise=np.zeros_like(h))
    assert step[0, 3] == pytest.approx(0.15) and step[0, 7] == pytest.approx(0.15)
    assert step[0, 1] == pytest.approx(0.0) and step[0, 8] == pytest.approx(0.0)
    wider = np.insert(h, 4, np.nan, axis=1)
    assert np.isnan(axis_step(wider, axis=1, rise=np.zeros_like(wider))[0, 3])


def test_a_step_read_across_a_gap_stays_on_the_cell_that_holds_it():
    """A curb whose face runs through a cell (its points of both levels: 0.40 m between the walk's
    0.51 and the road's 0.36), with a cell without ground on each side of it: that cell reads the
    curb across both gaps (0.15 m); the walk's cell and the road's cell beyond the gaps are level
    with their own neighbours and read no step, since the cell between them stands on it. Before,
    each read the step across its gap (0.11 and 0.04 m), 80 cm from the curb on the simulated
    LiDAR-only tiny world."""
    n = np.nan
    h = np.array([[0.51, 0.51, 0.51, 0.51, n, 0.40, n, 0.36, 0.36, 0.36]])
    step = axis_step(h, axis=1, rise=np.zeros_like(h))
    assert step[0, 5] == pytest.approx(0.15)
    assert step[0, 3] == pytest.approx(0.0) and step[0, 7] == pytest.approx(0.0)
    # A height within 2 cm of one side is that side's ground, not the step's face: read as before.
    near_road = np.array([[0.51, 0.51, 0.51, 0.51, n, 0.37, n, 0.36, 0.36, 0.36]])
    assert axis_step(near_road, axis=1, rise=np.zeros_like(h))[0, 3] == pytest.approx(0.14)


def curb_over_its_shadow(car: bool = False, bench: bool = False) -> GroundLayers:
    """grid_layers on 0.4 m cells (12 x 30) of a curb seen from its top: its top 0.15 m up for y
    >= 2.8 m (rows 7-11), the road at 0 for y < 1.6 m (rows 0-3), and no point between (rows 4-6,
    the curb's LiDAR shadow; the curb runs at y = 2.8 m). With `car`, a car (blocked cells, no
    ground) stands on the top at rows 9-10, x 4..8 m (columns 10-19); with `bench`, a bench on the
    road at rows 0-1, x 4..5.2 m (columns 10-12), two rows from the road's edge."""
    from terra.graph.grid import TerrainGrid

    rng = np.random.default_rng(11)
    xy = uniform(rng, [0, 0], [12, 4.8], 40000)
    xy = xy[(xy[:, 1] < 1.6) | (xy[:, 1] >= 2.8)]
    shape = (12, 30)
    blocked = np.zeros(shape, dtype=bool)
    if car:
        blocked[9:11, 10:20] = True
    if bench:
        blocked[0:2, 10:13] = True
    if car or bench:
        rows, cols = (xy[:, 1] // CELL).astype(int), (xy[:, 0] // CELL).astype(int)
        xy = xy[~blocked[rows, cols]]
    z = np.where(xy[:, 1] >= 2.8, 0.15, 0.0)
    grid = TerrainGrid(np.zeros(shape, np.int16), np.zeros(shape, np.float32), blocked, np.zeros(2), CELL)
    return grid_layers(np.column_stack([xy, z]), np.ones(len(xy), dtype=bool), grid)


def test_a_step_across_a_shadow_is_held_by_its_high_edge():
    """A curb over its shadow (`curb_over_its_shadow`): the top's edge (row 7) reads the curb
    across the shadow, 0.15 m; the road's edge (row 3), 1.2 m from the curb, reads only its own
    side, 0: before, it read the curb too, and closed the level routes past road places there.
    The lines of steps keep both edges (the GVD keeps out of the shadow), and an edge from the road
    up to the top still reads the curb; an edge along the road's edge reads none."""
    layers = curb_over_its_shadow()
    step = layers.as_grid(layers.step)
    np.testing.assert_allclose(step[7, 2:-2], 0.15, atol=0.01)
    np.testing.assert_allclose(step[3, 2:-2], 0.0, atol=0.01)
    assert layers.held_cells is not None and layers.held_step is not None
    before = np.full(len(layers.cells), np.nan)
    before[layers.held_cells] = layers.held_step
    np.testing.assert_allclose(layers.as_grid(before)[3, 2:-2], 0.15, atol=0.01)  # what it read
    lines = step_lines(layers, 0.05)
    assert lines[3, 2:-2].all() and lines[7, 2:-2].all() and not lines[[0, 1, 10, 11]].any()
    position = np.array([[6.2, 0.6, 0.0], [6.2, 4.2, 0.15], [1.0, 1.4, 0.0], [11.0, 1.4, 0.0]])
    geometry = edge_geometry(layers, position, np.array([[0, 1], [2, 3]]))
    assert geometry[0, 0] == pytest.approx(0.15, abs=0.01) and geometry[1, 0] == pytest.approx(0.0, abs=0.01)


def test_a_step_across_a_shadow_stays_on_the_low_edge_where_the_high_edge_does_not_hold_it():
    """The same curb with a car on its top two rows up from the top's edge: there the top's edge
    reads the curb only along its length (clear of the car), 0, and the road's edge, across the
    shadow, keeps the whole curb (0.15 m); away from the car, the top's edge holds it."""
    layers = curb_over_its_shadow(car=True)
    step = layers.as_grid(layers.step)
    np.testing.assert_allclose(step[7, 11:19], 0.0, atol=0.01)
    np.testing.assert_allclose(step[3, 11:19], 0.15, atol=0.01)
    np.testing.assert_allclose(step[3, 2:6], 0.0, atol=0.01)
    np.testing.assert_allclose(step[7, 2:6], 0.15, atol=0.01)


def test_a_step_across_a_shadow_beside_an_obstacle_is_held_by_clear_ground():
    """The curb over its shadow with a bench on the road two rows from the road's edge: the road's
    edge beside it (row 3, columns 8-14, within BESIDE cells of the bench) reads the curb across the
    shadow as the rest of the edge does, and the top's edge, clear of obstacles, holds it there too
    (on the simulated LiDAR-only campus a road place 1 m from a curb, beside an object, read the
    curb and was cut off). With the car on the top two rows up as well, the top's edge above the
    car's columns is beside an obstacle itself, and the road's edge keeps its read there."""
    layers = curb_over_its_shadow(bench=True)
    assert layers.near_obstacle is not None and layers.as_grid(layers.near_obstacle)[3, 8:15].all()
    step = layers.as_grid(layers.step)
    np.testing.assert_allclose(step[3, 2:-2], 0.0, atol=0.01)
    np.testing.assert_allclose(step[7, 2:-2], 0.15, atol=0.01)
    both = curb_over_its_shadow(car=True, bench=True)  # columns 10-12 read along the road alone
    np.testing.assert_allclose(both.as_grid(both.step)[3, [8, 9, 13, 14]], 0.15, atol=0.01)


def test_a_place_in_a_curbs_shadow_stands_at_the_road():
    """On the curb over its shadow (rows 4-6 without ground, the top 0.15 m up from row 7, the road
    at 0 to row 3), a place in row 6 beside the top (nearest ground: the top, one cell up; the road
    three cells down) stands at the road's height, the shadow's low level; a place on observed
    ground keeps its height, and one with no ground within four cells along any axis keeps the
    height it had."""
    layers = curb_over_its_shadow()
    xy = np.array([[6.2, 2.6], [6.2, 4.2], [6.2, 0.6]])  # row 6 (the shadow), row 10 (top), row 1 (road)
    np.testing.assert_allclose(heights_in_gaps(layers, xy, np.array([0.15, 0.2, 0.3])), [0.0, 0.2, 0.3], atol=0.01)
    bare = only_cells(layers, layers.cells // 30 <= 3)  # only the road: nothing within reach of row 10
    np.testing.assert_allclose(heights_in_gaps(bare, xy[1:2], np.array([0.15])), [0.15])


def level_ground_before(
    blocked_rows: slice,
    blocked_height: float,
    face: float | None = None,
    car_cols: slice | None = None,
    gap: tuple[float, float] = (1.6, 2.8),
) -> np.ndarray:
    """(16, 30) metres: the step layer of grid_layers on 0.4 m cells of ground with no point over
    y in `gap` (metres; rows 4-6 by default), level at 0 elsewhere, except that the cells of
    `blocked_rows` (in the columns `car_cols`, all by default) are blocked and their ground points
    stand at `blocked_height` (an object's lowest returns), and with `face`, rows 7-15 stand 0.15 m
    up and row 3's points are of both levels, `face` the share of them at the top (a curb's face)."""
    from terra.graph.grid import TerrainGrid

    rng = np.random.default_rng(5)
    xy = uniform(rng, [0, 0], [12, 6.4], 50000)
    xy = xy[(xy[:, 1] < gap[0]) | (xy[:, 1] >= gap[1])]
    shape = (16, 30)
    blocked = np.zeros(shape, dtype=bool)
    blocked[blocked_rows, car_cols if car_cols is not None else slice(None)] = True
    rows, cols = (xy[:, 1] // CELL).astype(int), (xy[:, 0] // CELL).astype(int)
    z = np.where(blocked[rows, cols], blocked_height, 0.0)
    if face is not None:
        z = np.where(rows >= 7, 0.15, z)
        on_face = (rows == 3) & (rng.uniform(size=len(xy)) < face)
        z = np.where(on_face, 0.15, z)
    grid = TerrainGrid(np.zeros(shape, np.int16), np.zeros(shape, np.float32), blocked, np.zeros(2), CELL)
    layers = grid_layers(np.column_stack([xy, z]), np.ones(len(xy), dtype=bool), grid)
    return layers.as_grid(layers.step)


def test_a_step_across_a_gap_is_not_read_up_to_a_blocked_cell():
    """Level ground, no point in rows 8-9, and a wall in rows 10-11 whose lowest returns, 0.17 m
    up, pass for ground: row 7, three rows from the wall (beyond BESIDE), read the wall's foot
    across the gap as a 0.17 m step (a simulated place 1.2 m from a wall was cut off). It reads
    none, nor does the ground past the wall."""
    assert BESIDE < 3
    step = level_ground_before(slice(10, 12), 0.17, gap=(3.2, 4.0))
    np.testing.assert_allclose(step[7, 2:-2], 0.0, atol=0.01)
    np.testing.assert_allclose(step[[0, 1, 14, 15], 2:-2], 0.0, atol=0.01)


def test_a_blocked_cell_still_tells_that_the_cell_before_it_holds_a_step():
    """A curb's top (rows 7-15, 0.15 m) over a shadow (rows 4-6), its face in row 3 (half of its
    points at each level), the road (rows 0-2) at 0 and a car on the road in row 2 (columns 10-19)
    whose lowest returns read the road: the top's edge (row 7), 1.6 m from the curb, reads no step
    beside the car either (the face stands on the step: the car's cell beyond it is lower; read
    without it, 7 cm), and away from the car the face reads the whole curb."""
    step = level_ground_before(slice(2, 3), 0.0, face=0.5, car_cols=slice(10, 20))
    np.testing.assert_allclose(step[7, 2:-2], 0.0, atol=0.01)
    np.testing.assert_allclose(step[3, 2:6], 0.15, atol=0.015)


def test_a_place_in_a_hole_on_a_curbs_top_stands_on_the_top():
    """A curb's top (rows 7-11, 0.15 m up) over its shadow (rows 4-6) with one cell of the top's
    edge (row 7, column 15) without ground: its neighbours along the row both hold the top, so it is
    a hole in the top, not shadow, and a place there stands on the top (the lowest ground within
    reach, the road four rows down, put it at 0; on the simulated LiDAR-only small site such a
    place beside an obstacle, no ground past it, had an edge down to the road over no ground that
    read no step); a place in the shadow stands at the road, as before, and the edge down from the
    hole reads the curb."""
    layers = curb_over_its_shadow()
    keep = layers.cells != 7 * 30 + 15
    holed = only_cells(layers, keep)
    xy = np.array([[6.2, 2.6], [6.2, 3.0]])  # (row 6: the shadow), (row 7, column 15: the hole)
    z = heights_in_gaps(holed, xy, np.array([0.3, 0.3]))
    np.testing.assert_allclose(z, [0.0, 0.15], atol=0.01)
    position = np.array([[6.2, 3.0, z[1]], [6.2, 1.8, 0.0]])  # down to row 4: no ground between
    assert edge_geometry(holed, position, np.array([[0, 1]]))[0, 0] >= 0.1


def curb_before_a_wall(rise: float, slope: float = 0.0) -> np.ndarray:
    """(12, 30) metres: the step layer of grid_layers on 0.4 m cells, of a road whose curb (`rise`
    metres) runs along x at y = 2.2 m, halfway across row 5 (whose points are of both levels), on
    ground sloping `slope` m/m along y, before a wall in row 7 (blocked, no ground): NaN where
    unknown."""
    from terra.graph.grid import TerrainGrid

    rng = np.random.default_rng(7)
    xy = uniform(rng, [0, 0], [12, 4.8], 40000)
    xy = xy[(xy[:, 1] < 2.8) | (xy[:, 1] >= 3.2)]
    z = slope * xy[:, 1] + np.where(xy[:, 1] >= 2.2, rise, 0.0)
    shape = (12, 30)
    blocked = np.zeros(shape, dtype=bool)
    blocked[7] = True
    grid = TerrainGrid(np.zeros(shape, np.int16), np.zeros(shape, np.float32), blocked, np.zeros(2), CELL)
    layers = grid_layers(np.column_stack([xy, z]), np.ones(len(xy), dtype=bool), grid)
    out = np.full(shape[0] * shape[1], np.nan)
    out[layers.cells] = layers.step
    return out.reshape(shape)


def test_a_curb_through_a_cell_before_a_wall_reads_its_whole_step():
    """Row 5 holds both of the curb's levels and the wall lies two rows up: across the row, rows 4
    and 6 differ by the whole curb, and the road's side (rows 3 and 4) tells the slope, which the
    wall hides on the other side. Read as the cell and its two neighbours alone, the two halves of
    the curb cancelled (0 where the curb is 15 cm). On a 5 % slope without a curb: no step."""
    curb = curb_before_a_wall(0.15)
    np.testing.assert_allclose(curb[5, 2:-2], 0.15, atol=0.015)
    assert np.all(curb[[0, 1, 2, 9, 10, 11], 2:-2] < 0.01)
    slope = curb_before_a_wall(0.0, slope=0.05)
    assert np.all(slope[5, 2:-2] < 0.01)


def test_edge_geometry_of_a_slope_and_a_curb():
    rng = np.random.default_rng(3)
    xy = uniform(rng, [0, 0], [20, 10], 60000)
    slope = ground_layers(np.column_stack([xy, TAN10 * xy[:, 0]]), flat_frame(20, 10))
    position = np.array([[2.0, 2.0, 0.0], [18.0, 2.0, 0.0], [10.0, 1.0, 0.0], [10.0, 9.0, 0.0]])
    geometry = edge_geometry(slope, position, np.array([[0, 1], [1, 0], [2, 3]]))
    assert geometry[0, 1] == pytest.approx(10.0, abs=0.5) and geometry[0, 2] == pytest.approx(0.0, abs=0.5)
    assert geometry[1, 1] == pytest.approx(0.0, abs=0.5) and geometry[1, 2] == pytest.approx(10.0, abs=0.5)
    assert geometry[2, 1] < 0.5 and geometry[2, 2] < 0.5  # across the slope: level
    # The slope across: 10 degrees on the contour (2, 3), none straight up or down.
    assert geometry[2, 4] == pytest.approx(10.0, abs=0.5) and np.all(geometry[:2, 4] < 0.5)
    # At 45 degrees to the slope: tan a = tan 10 x cos 45 along it and as much across.
    diagonal = edge_geometry(slope, np.array([[4.0, 1.0, 0.0], [12.0, 9.0, 0.0]]), np.array([[0, 1]]))[0]
    expected = np.degrees(np.arctan(TAN10 * np.cos(np.radians(45.0))))
    assert diagonal[1] == pytest.approx(expected, abs=0.5) and diagonal[4] == pytest.approx(expected, abs=0.5)
    curb = ground_layers(np.column_stack([xy, np.where(xy[:, 1] >= 5.0, 0.15, 0.0)]), flat_frame(20, 10))
    geometry = edge_geometry(curb, position, np.array([[2, 3], [0, 1]]))
    assert geometry[0, 0] == pytest.approx(0.15, abs=0.02)  # crosses the curb
    assert geometry[1, 0] < 0.02  # runs beside it, 3 m away
    assert np.all(geometry[:, 4] < 0.5)  # a curb is a step, not a slope across the edge (nor along the road)
    # Along the curb on its top, on the cells beside it whose planes take in the curb: no slope
    # steeper than a wheelchair's 8 degrees (the curb's own cells are the step column's business).
    for y in (4.7, 5.1, 5.3):
        beside = edge_geometry(curb, np.array([[2.0, y, 0.0], [18.0, y, 0.0]]), np.array([[0, 1]]))[0]
        assert beside[4] < 8.0, y


def test_a_plane_through_cells_nearly_in_a_line_reads_no_slope_across():
    """Level ground seen as one row of cells (a far ring: points near the row's top, y 2.35..2.4 m)
    and one cell above it, 1 cm higher, seen at its bottom (y 2.4..2.45): the planes of the row's
    cells beside it, through four cells whose centroids nearly line up, climb 11 degrees across the
    row (read, the edge along the row would read so). Too few cells (4 of 9) to tell a slope
    across an edge along the row: it reads none."""
    rng = np.random.default_rng(5)
    row = np.column_stack([uniform(rng, [2.0, 2.35], [8.0, 2.4], 3000), np.zeros(3000)])
    above = np.column_stack([uniform(rng, [4.0, 2.4], [4.4, 2.45], 200), np.full(200, 0.01)])
    layers = ground_layers(np.vstack([row, above]), flat_frame(10, 5))
    assert np.all(layers.as_grid(layers.slope)[5, 9:12] > 10.0)  # the row's cells below the higher one
    position = np.array([[2.5, 2.38, 0.0], [7.5, 2.38, 0.0]])
    assert edge_geometry(layers, position, np.array([[0, 1]]))[0, 4] < 0.5


def test_edge_geometry_measures_the_stretch_over_unobserved_ground():
    """Flat ground 20 x 10 m whose points leave out x in [8, 14) (the cells 20 to 34 at 0.4 m): an
    edge across it runs 6 m over unobserved ground, sampled every 0.2 m; one that ends in it counts
    the part it crosses; ground beyond the grid is not the map's to observe and counts as nothing."""
    rng = np.random.default_rng(6)
    xy = uniform(rng, [0, 0], [20, 10], 60000)
    xy = xy[(xy[:, 0] < 8.0) | (xy[:, 0] >= 14.0)]
    layers = ground_layers(np.column_stack([xy, np.zeros(len(xy))]), flat_frame(20, 10))
    position = np.array([[2.0, 5.0, 0.0], [18.0, 5.0, 0.0], [7.0, 5.0, 0.0], [10.0, 5.0, 0.0], [25.0, 5.0, 0.0]])
    edges = np.array([[0, 1], [1, 0], [0, 2], [3, 1], [1, 4]])
    unobserved = edge_geometry(layers, position, edges)[:, 3]
    np.testing.assert_allclose(unobserved, [6.0, 6.0, 0.0, 4.0, 0.0], atol=0.21)
    assert np.all(edge_geometry(layers, position, edges)[:, 0] < 0.01)  # and the gap makes no step


def test_an_edge_slope_leaves_out_the_cells_beside_an_obstacle():
    """A 5 % lawn with a bench's feet: the points under the bench, 8 cm up over 1 m, pass for ground. An
    edge along the bench reads the lawn's 2.9 degrees once the cells beside it are known to be near an
    obstacle, and the bump's 7 degrees and more without that."""
    rng = np.random.default_rng(4)
    xy = uniform(rng, [0, 0], [20, 10], 60000)
    z = 0.05 * xy[:, 0] + np.where((xy[:, 0] > 9.0) & (xy[:, 0] < 10.0) & (np.abs(xy[:, 1] - 5.0) < 1.0), 0.08, 0.0)
    layers = ground_layers(np.column_stack([xy, z]), flat_frame(20, 10))
    position = np.array([[4.0, 5.0, 0.0], [16.0, 5.0, 0.0]])
    bumpy = edge_geometry(layers, position, np.array([[0, 1]]))
    assert bumpy[0, 1] > 6.0  # the bump read as the lawn's slope
    centres = layers.centres(np.arange(len(layers.cells)))
    layers.near_obstacle = (np.abs(centres[:, 0] - 9.5) < 1.5) & (np.abs(centres[:, 1] - 5.0) < 1.5)
    clear = edge_geometry(layers, position, np.array([[0, 1]]))
    assert clear[0, 1] == pytest.approx(np.degrees(np.arctan(0.05)), abs=0.3) and clear[0, 2] < 0.3
    assert clear[0, 4] < 0.3  # level across, with or without the bump
    layers.near_obstacle = np.ones(len(layers.cells), dtype=bool)  # all of it beside an obstacle: all read
    np.testing.assert_array_equal(edge_geometry(layers, position, np.array([[0, 1]]))[:, :4], bumpy[:, :4])
    # ... but for the slope across, read only on planes clear of obstacles: none here.
    assert edge_geometry(layers, position, np.array([[0, 1]]))[0, 4] == 0.0


def test_a_gap_before_ground_beside_an_obstacle_all_along_reads_its_step():
    """A road (0 m) up to x = 4.4, no ground to x = 5.6 (the curb's shadow), the curb's top (15
    cm) beyond, every cell of it beside an obstacle and reading no step (beside an obstacle a cell
    reads its step along an axis clear of blocked cells: along the curb, grid_layers). An edge from
    a place in the gap on the road's level to the top has no clear sample at all: the step across
    the gap is read on the ground beside the obstacle rather than not at all (the simulated
    LiDAR-only small site, seed 1: a 15 cm curb read 0.5 cm)."""
    rng = np.random.default_rng(7)
    xy = uniform(rng, [0, 0], [12, 10], 40000)
    xy = xy[(xy[:, 0] < 4.4) | (xy[:, 0] >= 5.6)]
    layers = ground_layers(np.column_stack([xy, np.where(xy[:, 0] < 5.0, 0.0, 0.15)]), flat_frame(12, 10))
    centres = layers.centres(np.arange(len(layers.cells)))
    layers.near_obstacle = centres[:, 0] > 5.0
    layers.step[layers.near_obstacle] = 0.0
    position = np.array([[5.0, 5.0, 0.0], [8.0, 5.0, 0.15]])
    assert edge_geometry(layers, position, np.array([[0, 1]]))[0, 0] == pytest.approx(0.15, abs=0.01)


def test_an_edge_clear_of_obstacles_at_one_end_only_reads_its_slope_beside_them():
    """A curb 14 cm high at x = 10 (level ground on each side) with a planter along its foot: every
    cell from x = 5 on lies beside an obstacle. An edge from x = 3 on the top to x = 14 below has
    clear samples over its first 2 m only; read on those alone it was level (0.2 degrees in the
    simulated case), read on all it falls by the curb. The same edge with clear ground at both
    ends still leaves the cells beside the planter out."""
    rng = np.random.default_rng(6)
    xy = uniform(rng, [0, 0], [20, 10], 60000)
    z = np.where(xy[:, 0] < 10.0, 0.14, 0.0)
    layers = ground_layers(np.column_stack([xy, z]), flat_frame(20, 10))
    centres = layers.centres(np.arange(len(layers.cells)))
    layers.near_obstacle = centres[:, 0] > 5.0
    position = np.array([[3.0, 5.0, 0.14], [14.0, 5.0, 0.0]])
    down = edge_geometry(layers, position, np.array([[0, 1]]), unseen_ends=False)
    # 14 cm over the 1 m baseline: 8 degrees of fall, more on the planes fitted across the curb
    assert down[0, 2] > np.degrees(np.arctan(0.14)) - 0.5 and down[0, 1] < 0.5
    layers.near_obstacle = (centres[:, 0] > 5.0) & (centres[:, 0] < 12.0)  # clear again past x = 12
    both = edge_geometry(layers, position, np.array([[0, 1]]), unseen_ends=False)
    # Read on the clear ends (14 cm over the 7 m between them: 1.1 degrees); the gap reads the step.
    assert both[0, 2] < 1.5
    assert both[0, 0] == pytest.approx(0.14, abs=0.02)


def test_a_curb_read_as_a_ramp_at_an_edges_end_reads_its_cells_slope():
    """Layers as read at a 13 cm curb on the simulated campus: level ground, then two cells 6.5 and
    13 cm up whose planes (fitted across the curb) climb 11.3 degrees along x, no step. An edge
    ending on the top climbs 13 cm over its last metre, 7.4 degrees, under a wheelchair's 8; the
    cells' own planes climb 11.3 along it, and that is its rise (its fall the other way)."""
    W = 30
    cells = np.arange(5 * W)
    col = cells % W
    height = np.select([col == 25, col >= 26], [0.065, 0.13], 0.0).astype(np.float32)
    gradient = np.zeros((len(cells), 2), np.float32)
    gradient[(col == 25) | (col == 26), 0] = 0.2
    layers = GroundLayers(
        cells,
        height,
        gradient,
        np.zeros(len(cells), np.float32),
        np.zeros(len(cells), np.float32),
        (5, W),
        np.zeros(2),
        CELL,
    )
    position = np.array([[4.0, 1.0, 0.0], [10.6, 1.0, 0.13]])
    geometry = edge_geometry(layers, position, np.array([[0, 1], [1, 0]]), unseen_ends=False)
    planes = np.degrees(np.arctan(0.2))
    assert geometry[0, 1] == pytest.approx(planes, abs=0.01) and geometry[0, 2] == 0.0
    assert geometry[1, 2] == pytest.approx(planes, abs=0.01) and geometry[1, 1] == 0.0


def level_cells(W: int = 30, rows: int = 5) -> GroundLayers:
    """Hand-made layers: `rows` x W observed cells of level ground at z = 0, no step."""
    cells = np.arange(rows * W)
    zeros = np.zeros(len(cells), np.float32)
    return GroundLayers(
        cells, zeros.copy(), np.zeros((len(cells), 2), np.float32), zeros, zeros, (rows, W), np.zeros(2), CELL
    )


def test_a_plane_steeper_than_a_fit_holds_is_no_slope_of_an_edge():
    """Level ground whose cell (2, 15) fitted a plane 80 degrees steep (beside a bench on the
    simulated LiDAR-only campus: cells nearly in a line), its height the mean (ground_layers keeps
    it). An edge over it read a 70 degree rise and cut a place off; such a plane is no slope
    (`fitted_gradient`), and the edge reads level, nor is a point's height carried along it. A plane
    of 42 degrees, under STEEPEST_FIT, is still the ground's slope along the edge."""
    layers = level_cells()
    layers.gradient[2 * 30 + 15] = [5.4, 1.5]
    position = np.array([[4.0, 1.0, 0.0], [10.0, 1.0, 0.0]])
    edges = np.array([[0, 1], [1, 0]])
    geometry = edge_geometry(layers, position, edges)
    assert np.all(geometry[:, :3] == 0.0)
    assert np.isnan(layers.fitted_gradient(np.array([2 * 30 + 15]))).all()
    assert layers.height_at(np.array([2 * 30 + 15]), np.array([[6.3, 1.1]]))[0] == 0.0
    layers.gradient[2 * 30 + 15] = [0.9, 0.0]
    steep = edge_geometry(layers, position, edges)
    assert steep[0, 1] == pytest.approx(np.degrees(np.arctan(0.9)), abs=0.01) and steep[1, 2] == steep[0, 1]


def test_a_map_of_bare_points_builds_places_on_the_ground():
    points, truth = street()
    build = build_scene_graph(points_map(points))
    graph = build.graph
    assert graph.terrain_classes == ["ground"]
    assert len(graph.places) >= 3 and graph.has_edge_geometry
    # Places stand on the ground (road or sidewalk height under them), none on the car or wall.
    x, y, z = graph.places.position.T
    expected = 0.02 * x + np.where(y >= 6.0, 0.15, 0.0)
    assert np.all(np.abs(z - expected) < 0.1)
    assert not np.any((x > 10) & (x < 14.5) & (y > 1) & (y < 2.8))
    assert build.ground is not None and build.ground.observed.any()
    # Band by band (three rows at a time) gives the same layers as in one piece.
    frame = GridFrame(tuple(build.ground.origin), build.ground.shape, build.ground.cell_size, build.ground.offset)
    ground = segment_ground(points)
    whole, bands = (
        ground_layers(points[ground], frame),
        ground_layers(points[ground], frame, band_cells=3 * frame.shape[1]),
    )
    assert np.array_equal(whole.cells, bands.cells)
    for name in ("height", "gradient", "step", "roughness"):
        np.testing.assert_array_equal(getattr(whole, name), getattr(bands, name), err_msg=name)


def test_a_lidar_only_maps_layers_beside_its_grid_equal_those_after_it(monkeypatch):
    """A LiDAR-only map segments its ground first (its grid is built on it); its layers, computed
    on a second thread while that grid is built, are those computed after it, to the last bit."""
    monkeypatch.setattr(pipeline, "usable_cores", lambda: 2)
    points, _ = street()
    beside = build_scene_graph(points_map(points)).ground
    after = build_scene_graph(points_map(points), BuildConfig.model_validate({"ground": {"beside_grid_points": 0}}))
    assert beside is not None and after.ground is not None and beside.near_obstacle is not None
    for name in ("cells", "height", "gradient", "step", "roughness", "near_obstacle"):
        np.testing.assert_array_equal(getattr(beside, name), getattr(after.ground, name), err_msg=name)


def test_layers_do_not_depend_on_the_empty_cells_around_the_points():
    """Each band is computed only over the columns near its points, and steps only at its observed
    cells: the same points on a frame with wide empty margins, cut into bands of a few rows, give
    the same layers to the last bit as on a tight frame in one piece (holes in the ground make
    steps read across gaps)."""
    points, truth = street()
    ground = points[truth]
    holes = (np.abs(ground[:, 0] % 3.0 - 1.5) < 0.3) & (ground[:, 1] > 5.0)  # curb-side shadows
    ground = ground[~holes]
    tight = flat_frame(30, 10)
    wide = GridFrame((0.0, 0.0), (tight.shape[0] + 40, tight.shape[1] + 60), CELL, (-20, -30))
    a = ground_layers(ground, tight)
    b = ground_layers(ground, wide, band_cells=4 * wide.shape[1])
    rows, cols = np.divmod(a.cells, tight.shape[1])
    np.testing.assert_array_equal(b.cells, (rows + 20) * wide.shape[1] + cols + 30)
    assert np.isfinite(a.step).sum() > 0.9 * len(a.step)
    for name in ("height", "gradient", "step", "roughness"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_a_map_whose_classes_got_no_votes_builds_on_the_ground():
    # A SemanticKITTI folder without label files: the legend names terrain classes, no point votes.
    points, _ = street()
    msm = points_map(points)
    msm.terrain_classes = ["road", "sidewalk"]
    msm.terrain_votes = np.zeros((len(points), 2), dtype=np.uint16)
    msm.terrain_embeddings = np.eye(2, 8, dtype=np.float32)
    graph = build_scene_graph(msm).graph
    assert graph.terrain_classes == ["ground"] and len(graph.places) >= 3


def test_a_lidar_only_bag_maps_builds_and_plans(lidar_only_bundle, capsys):
    bundle = Bundle(lidar_only_bundle)
    assert bundle.model.terrain_classes == []  # the map itself is unchanged: no classes, no embeddings
    graph = load_scene_graph(bundle)
    assert graph.terrain_classes == ["ground"] and len(graph.places) >= 10
    assert graph.has_edge_geometry
    info = bundle.model.components.graph
    assert info is not None and info.ground is not None
    ground = info.ground
    assert ground.units["height"] == "m, map frame" and ground.observed_cells > 1000
    cells = bundle.array("graph/ground_cells")
    assert cells.shape == (ground.observed_cells,) and cells.max() < np.prod(ground.shape)
    assert bundle.array("graph/ground_gradient").shape == (len(cells), 2)
    capsys.readouterr()
    last = len(graph.places) - 1
    assert run(["plan", str(lidar_only_bundle), "--from-node", "0", "--to-node", str(last), "--json"]) == 0
    assert '"goal_place": ' + str(last) in capsys.readouterr().out


def test_an_edit_of_the_graph_keeps_the_ground_layers(lidar_only_bundle, tmp_path):
    # `terra find --save` rewrites the scene graph: the layers of the build stay, with their entry.
    from terra.bundle import BundleWriter
    from terra.graph.storage import write_scene_graph
    from tests.graph.fixtures import copy_bundle

    path = copy_bundle(lidar_only_bundle, tmp_path / "copy.terra")
    before = Bundle(path)
    graph = load_scene_graph(before)
    with BundleWriter(path, base=before) as writer:
        write_scene_graph(writer, graph)
    after = Bundle(path)
    names = [n for n in before.files if n.startswith("graph/ground_")]
    assert len(names) == 5 and all(after.files[n] == before.files[n] for n in names)
    kept, built = after.model.components.graph, before.model.components.graph
    assert kept is not None and built is not None and kept.ground is not None
    assert kept.ground == built.ground
    np.testing.assert_array_equal(load_scene_graph(after).place_edge_geometry, graph.place_edge_geometry)


@pytest.mark.parametrize("recorded", [3, 4])
def test_edge_geometry_of_an_older_bundle_reads_what_it_lacks_as_unknown(lidar_only_bundle, tmp_path, capsys, recorded):
    """A bundle written before the stretch over unobserved ground (three columns) or the cross slope
    (four) was recorded: the missing columns read as NaN (unknown; no robot refuses on them, a plan
    reports none), a plan still runs, and the graph written again reads back with the columns it
    knows; six columns are one line naming the file, exit 2."""
    from terra.bundle import BundleWriter
    from terra.graph.storage import write_scene_graph
    from tests.graph.fixtures import copy_bundle

    path = copy_bundle(lidar_only_bundle, tmp_path / "old.terra")
    graph = load_scene_graph(Bundle(path))
    assert np.isfinite(graph.place_edge_geometry).all() and graph.place_edge_geometry.shape[1] == 5
    with BundleWriter(path, base=Bundle(path)) as writer:
        writer.put_array("graph/place_edge_geometry", graph.place_edge_geometry[:, :recorded].copy())
    old = load_scene_graph(Bundle(path))
    np.testing.assert_array_equal(old.place_edge_geometry[:, :recorded], graph.place_edge_geometry[:, :recorded])
    assert np.isnan(old.place_edge_geometry[:, recorded:]).all() and old.has_edge_geometry
    capsys.readouterr()
    last = str(len(graph.places) - 1)
    assert run(["plan", str(path), "--from-node", "0", "--to-node", last, "--json"]) == 0
    out = capsys.readouterr().out
    assert '"max_cross_slope_deg": null' in out and ('"max_unobserved_m": null' in out) == (recorded == 3)
    with BundleWriter(path, base=Bundle(path)) as writer:
        write_scene_graph(writer, old)
    again = load_scene_graph(Bundle(path)).place_edge_geometry
    np.testing.assert_array_equal(again[:, :recorded], graph.place_edge_geometry[:, :recorded])
    assert np.isnan(again[:, recorded:]).all()
    with BundleWriter(path, base=Bundle(path)) as writer:
        writer.put_array("graph/place_edge_geometry", np.zeros((len(graph.place_edges), 6), np.float32))
    assert run(["plan", str(path), "--from-node", "0", "--to-node", last, "--json"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "place_edge_geometry.npy" in err and "3 to 5 columns" in err


@pytest.mark.parametrize("argv", [["find", "bench"], ["monitor", "parking lot"], ["plan", "--to", "the bench"]])
def test_text_queries_on_a_lidar_only_map_are_refused(lidar_only_bundle, capsys, argv):
    capsys.readouterr()
    assert run([argv[0], str(lidar_only_bundle), *argv[1:]]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "the map has no image embeddings" in err


def lattice(x: float, y: float, nx: int, ny: int) -> np.ndarray:
    """(nx ny, 2) the corners (metres) of nx x ny cells of CELL from (x, y)."""
    return np.stack(np.meshgrid(x + CELL * np.arange(nx), y + CELL * np.arange(ny)), axis=-1).reshape(-1, 2)


def table_on_a_walk(seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (N, 3) of a level walk (x 0..8, y 0..6 m, at 0) with a picnic table's top (x 3.2..5.2,
    y 2..3.6 m, 0.75 m up, two points a 0.4 m cell) and a tree's crown (x 6..8, y 4..6 m: points
    1.9, 1.97 and 3.0 m up, one each a cell); their terrain (N,) (the walk, 0, also on the table's top:
    the camera's mask bleeds onto it; the crown none, -1) and which are ground (N,) bool."""
    rng = np.random.default_rng(seed)
    walk = np.column_stack([uniform(rng, [0, 0], [8, 6], 12000), np.zeros(12000)])
    cells = lattice(3.2, 2.0, 5, 4)
    top = np.column_stack(
        [np.repeat(cells, 2, axis=0) + rng.uniform(0.05, 0.35, (2 * len(cells), 2)), np.full(2 * len(cells), 0.75)]
    )
    crown_cells = lattice(6.0, 4.0, 5, 5) + CELL / 2
    crown = np.vstack([np.column_stack([crown_cells, np.full(len(crown_cells), h)]) for h in (1.9, 1.97, 3.0)])
    points = np.vstack([walk, top, crown])
    terrain = np.concatenate([np.zeros(len(walk) + len(top), np.int16), np.full(len(crown), -1, np.int16)])
    ground = np.arange(len(points)) < len(walk)
    return points, terrain, ground


def test_a_table_its_terrain_mask_bleeds_onto_is_blocked_over_the_segmented_ground():
    """The table's top points carry the walk's terrain, so the grid's own rule (points without a
    terrain class above the terrain points' height) blocks none of its cells, only the crown's;
    measured above the segmented ground (0), the top stands 0.75 m up, two points a cell: its
    4 x 5 cells are blocked too and lose their label. The crown's cells (two points in the band,
    its lowest leaves, and one above) are none of the segmented ground's rule's, nor is any cell
    of the walk."""
    from terra.graph.pipeline import terrain_grid

    points, terrain, ground = table_on_a_walk()
    grid = terrain_grid(points, terrain, BuildConfig())
    rows, cols, _ = grid.cell_of(points[points[:, 2] == 0.75])  # the cells of the table's top
    table = np.zeros(grid.shape, dtype=bool)
    table[rows, cols] = True
    rows, cols, _ = grid.cell_of(points[points[:, 2] == 3.0])
    crown = np.zeros(grid.shape, dtype=bool)
    crown[rows, cols] = True
    assert table.sum() == 20 and crown.sum() == 25
    np.testing.assert_array_equal(grid.blocked, crown)
    layers = grid_layers(points, ground, grid)
    np.testing.assert_array_equal(grid.blocked, crown | table)
    assert (grid.label[table] == -1).all() and (grid.label[~table & ~crown & (grid.label >= 0)] == 0).all()
    assert layers.near_obstacle is not None and layers.as_grid(layers.near_obstacle)[table].all()
    fresh = terrain_grid(points, terrain, BuildConfig())
    fresh.blocked[:] = False
    assert block_above_ground(fresh, points, layers) == 20
    np.testing.assert_array_equal(fresh.blocked, table)
    # Two points a cell are needed (min_points 3: none), and a band of None blocks nothing.
    again = terrain_grid(points, terrain, BuildConfig())
    assert block_above_ground(again, points, layers, min_points=3) == 0
    assert block_above_ground(again, points, layers, band=None) == 0
