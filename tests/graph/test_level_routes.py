"""Level routes (terra.graph.level_routes): pieces of the places graph joined along level ground,
checked against the hand-made street's own surface, on hand-made layers, and end to end."""

from __future__ import annotations

import numpy as np
import pytest

from terra.errors import NoPathError
from terra.graph.config import BuildConfig
from terra.graph.grid import TerrainGrid
from terra.graph.ground import GroundLayers, grid_layers
from terra.graph.level_routes import (
    HOLE,
    Route,
    RouteBlocks,
    RouteRule,
    _lines_open,
    _refined,
    level_along,
    level_routes,
)
from terra.graph.pipeline import build_scene_graph, terrain_grid
from terra.graph.room import ROOM_REACH
from terra.graph.scene_graph import EDGE_LEVEL_ROUTE
from terra.graph.storage import scene_graph_to_spark_json
from terra.schemas import EdgeTerra
from terra.tasks.planning import plan_path
from terra.tasks.robot import ROBOTS
from tests.graph.test_graph_crossings import ASPHALT, SIDEWALK, nearest, street_map

RULE = RouteRule(max_step=0.05, max_slope=8.0, max_unobserved=5.0, clearance=0.45, max_length=40.0)
CUT = (12.0, 15.0)  # metres: the curb cut's x extent
NO_GAP_PLACES = {"linking": {"curb_gap_max_step": None}}


def street_height(x: np.ndarray, y: np.ndarray, cut: bool = True) -> np.ndarray:
    """The street's surface (metres): a road at 0 for y < 5, a sidewalk at 0.15 beyond a curb at
    y = 5, and (with `cut`) a 3 m curb cut at x 12..15 ramping at 1:12 over y 5..6.8."""
    z = np.where(y >= 5.0, 0.15, 0.0)
    if cut:
        ramp = (x >= CUT[0]) & (x <= CUT[1]) & (y >= 5.0) & (y < 6.8)
        z = np.where(ramp, 0.15 * (y - 5.0) / 1.8, z)
    return z


def street(cut: bool = True, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) on `street_height` (x 0..30, y 0..12 m, 5 mm noise) and their terrain (N,)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([0.0, 0.0], [30.0, 12.0], (90000, 2))
    z = street_height(xy[:, 0], xy[:, 1], cut) + rng.normal(0.0, 0.005, len(xy))
    return np.column_stack([xy, z]), np.where(xy[:, 1] >= 5.0, SIDEWALK, ASPHALT)


def street_ground(cut: bool = True) -> tuple[TerrainGrid, GroundLayers]:
    """The street's terrain grid and ground layers."""
    points, terrain = street(cut)
    grid = terrain_grid(points, terrain.astype(np.int16), BuildConfig())
    return grid, grid_layers(points, np.ones(len(points), dtype=bool), grid)


def largest_true_step(waypoints: np.ndarray, cut: bool = True, spacing: float = 0.05) -> float:
    """The largest jump of the street's own surface between samples `spacing` metres apart along
    a polyline of waypoints (n, 2+) (a ramp of 1:12 rises 4 mm a sample; the curb 15 cm)."""
    jumps = [0.0]
    for a, b in zip(waypoints[:-1, :2], waypoints[1:, :2], strict=True):
        t = np.linspace(0.0, 1.0, max(int(np.linalg.norm(b - a) / spacing), 1) + 1)[:, None]
        xy = a + t * (b - a)
        jumps.append(float(np.abs(np.diff(street_height(xy[:, 0], xy[:, 1], cut))).max(initial=0.0)))
    return max(jumps)


def curb_crossings(waypoints: np.ndarray) -> np.ndarray:
    """x (metres) where each segment of a polyline (n, 2+) crosses the curb's line y = 5."""
    a, b = waypoints[:-1], waypoints[1:]
    across = (a[:, 1] - 5.0) * (b[:, 1] - 5.0) < 0
    t = (5.0 - a[across, 1]) / (b[across, 1] - a[across, 1])
    return a[across, 0] + t * (b[across, 0] - a[across, 0])


def test_a_route_joins_the_road_to_the_walk_through_the_cut_and_bends_there():
    grid, layers = street_ground()
    # Two places with no edge between them: one on the road far west, one on the walk far east.
    position = np.array([[3.0, 2.5, 0.0], [27.0, 9.0, 0.15]])
    edges, geometry = np.zeros((0, 2), np.int64), np.zeros((0, 5), np.float32)
    routes = level_routes(
        position, np.array([ASPHALT, SIDEWALK]), np.array([2.0, 2.0]), edges, geometry, grid, layers, RULE
    )
    assert len(routes.position) >= 1  # the straight line crosses the curb: the route bends
    chain = np.vstack([position, routes.position])
    path = [0, *range(2, 2 + len(routes.position)), 1]
    assert [tuple(e) for e in routes.edges] == [tuple(sorted(p)) for p in zip(path[:-1], path[1:], strict=True)]
    waypoints = chain[path]
    crossings = curb_crossings(waypoints)
    assert len(crossings) == 1 and CUT[0] <= crossings[0] <= CUT[1]
    assert largest_true_step(waypoints) <= 0.05
    assert np.all(routes.geometry[:, 0] <= RULE.max_step)
    assert np.all(routes.geometry[:, 1:3] <= RULE.max_slope)
    assert np.all(routes.clearance >= RULE.clearance)
    # Each new place stands on the surface, with the terrain of its cell.
    assert np.allclose(routes.position[:, 2], street_height(routes.position[:, 0], routes.position[:, 1]), atol=0.03)
    assert np.array_equal(routes.terrain, np.where(routes.position[:, 1] >= 5.0, SIDEWALK, ASPHALT))
    # The length is the polyline's, at least the straight line's.
    assert np.isclose(routes.length.sum(), np.linalg.norm(np.diff(waypoints, axis=0), axis=1).sum())
    assert routes.length.sum() >= np.linalg.norm(position[1] - position[0])


def test_no_route_over_a_curb_without_a_cut():
    grid, layers = street_ground(cut=False)
    position = np.array([[3.0, 2.5, 0.0], [27.0, 9.0, 0.15]])
    edges, geometry = np.zeros((0, 2), np.int64), np.zeros((0, 5), np.float32)
    routes = level_routes(
        position, np.array([ASPHALT, SIDEWALK]), np.array([2.0, 2.0]), edges, geometry, grid, layers, RULE
    )
    assert len(routes.edges) == 0 and len(routes.position) == 0


def gutter_ground(gap: tuple[float, float]) -> tuple[TerrainGrid, GroundLayers]:
    """Level ground (x 0..20, y 0..12 m) rising at 4 degrees over y 3..4.4 to a 15 cm curb at
    y = 5.2 beyond it, and no points over y in `gap` (a curb's LiDAR shadow)."""
    rng = np.random.default_rng(1)
    xy = rng.uniform([0.0, 0.0], [20.0, 12.0], (70000, 2))
    xy = xy[(xy[:, 1] < gap[0]) | (xy[:, 1] >= gap[1])]
    y = xy[:, 1]
    rise = np.tan(np.radians(4.0)) * np.clip(y - 3.0, 0.0, 1.4)
    z = rise + np.where(y >= 5.2, 0.15, 0.0) + rng.normal(0.0, 0.003, len(y))
    points = np.column_stack([xy, z])
    grid = terrain_grid(points, np.zeros(len(points), np.int16), BuildConfig())
    return grid, grid_layers(points, np.ones(len(points), dtype=bool), grid)


@pytest.mark.parametrize(("gap", "joined"), [((4.4, 6.0), False), ((4.4, 5.2), False), ((8.0, 8.8), True)])
def test_a_route_crosses_ground_without_points_only_where_a_step_would_read(gap, joined):
    # A curb in a 1.6 m stretch the sensor never saw (four cells): the step layer reads across
    # three cells at most, and the slope before the stretch explains most of the curb away, so
    # no route crosses it; nor a 0.8 m one, where the step reads. A 0.8 m stretch of the level
    # top (ground scanned in rings) is crossed.
    grid, layers = gutter_ground(gap)
    position = np.array([[10.0, 1.5, 0.0], [10.0, 10.0, 0.25]])
    edges, geometry = np.zeros((0, 2), np.int64), np.zeros((0, 5), np.float32)
    if joined:
        position = np.array([[10.0, 7.0, 0.25], [10.0, 10.0, 0.25]])
    routes = level_routes(position, np.zeros(2, np.int64), np.array([2.0, 2.0]), edges, geometry, grid, layers, RULE)
    assert (len(routes.edges) > 0) == joined


def test_routes_join_each_piece_once_cheapest_first():
    # Three places in a row on level ground, no edges: pieces {0}, {1}, {2}. Routes 0-1 and 1-2
    # (10 m each) join them; 0-2 (20 m) would join nothing new. Straight lines: no new places.
    grid, layers = street_ground()
    position = np.array([[5.0, 9.5, 0.15], [15.0, 9.5, 0.15], [25.0, 9.5, 0.15]])
    edges, geometry = np.zeros((0, 2), np.int64), np.zeros((0, 5), np.float32)
    routes = level_routes(position, np.full(3, SIDEWALK), np.full(3, 2.0), edges, geometry, grid, layers, RULE)
    assert len(routes.position) == 0
    assert sorted(map(tuple, routes.edges.tolist())) == [(0, 1), (1, 2)]
    assert np.allclose(routes.length, 10.0, atol=0.01)
    # Places already joined by a level edge make one piece: nothing to route.
    level = np.zeros((2, 5), np.float32)
    joined = level_routes(
        position, np.full(3, SIDEWALK), np.full(3, 2.0), np.array([[0, 1], [1, 2]]), level, grid, layers, RULE
    )
    assert len(joined.edges) == 0
    # Two places of different pieces in one block: a straight edge joins them.
    close = np.array([[5.0, 9.5, 0.15], [5.3, 9.3, 0.15], [15.0, 9.5, 0.15]])
    both = level_routes(close, np.full(3, SIDEWALK), np.full(3, 2.0), edges, geometry, grid, layers, RULE)
    assert sorted(map(tuple, both.edges.tolist())) == [(0, 1), (0, 2)]
    # An edge over the curb is no level edge: its places stay apart.
    steep = np.array([[0.15, 0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0, 0.0]], np.float32)
    apart = level_routes(
        position, np.full(3, SIDEWALK), np.full(3, 2.0), np.array([[0, 1], [1, 2]]), steep, grid, layers, RULE
    )
    assert sorted(map(tuple, apart.edges.tolist())) == [(0, 1)]


def flat_layers(shape: tuple[int, int], observed: np.ndarray, bad: np.ndarray) -> tuple[TerrainGrid, GroundLayers]:
    """A level grid of 0.4 m cells: ground on the `observed` (H, W) cells, a 15 cm step on `bad` ones."""
    H, W = shape
    cells = np.flatnonzero(observed.ravel())
    step = np.where(bad.ravel()[cells], 0.15, 0.0).astype(np.float32)
    n = len(cells)
    origin = np.zeros(2)
    layers = GroundLayers(
        cells, np.zeros(n, np.float32), np.zeros((n, 2), np.float32), step, np.zeros(n, np.float32), (H, W), origin, 0.4
    )
    grid = TerrainGrid(np.zeros(shape, np.int16), np.zeros(shape, np.float32), np.zeros(shape, bool), origin, 0.4)
    return grid, layers


def test_blocks_keep_clear_of_steps_and_cross_short_holes_only():
    H, W = 20, 40
    observed, bad = np.ones((H, W), bool), np.zeros((H, W), bool)
    bad[10, 10] = True  # one cell of a step
    observed[:, 20:22] = False  # a hole one block (0.8 m) wide: ground scanned in rings
    observed[:, 28:38] = False  # a stretch five blocks (4 m) wide the sensor never saw
    grid, layers = flat_layers((H, W), observed, bad)
    blocks = RouteBlocks.of(grid, layers, RULE).open
    # The step's block and the blocks within one cell of it (0.45 m of clearance) are closed.
    assert not blocks[5, 5] and not blocks[4, 4] and not blocks[5, 4]
    assert blocks[3, 3] and blocks[7, 7] and blocks[5, 7]
    assert blocks[:, 10].all()  # the one-block hole, between level blocks
    assert not blocks[2:-2, 14:19].any()  # the wide stretch, away from the grid's edges
    # A route crosses the short hole and not the wide stretch; it bends around the step's cell,
    # which the straight line from place 0 to place 1 (along y = 4.2) crosses.
    position = np.array([[2.0, 4.2, 0.0], [11.0, 4.2, 0.0], [15.8, 4.2, 0.0]])
    edges, geometry = np.zeros((0, 2), np.int64), np.zeros((0, 5), np.float32)
    routes = level_routes(position, np.zeros(3, np.int64), np.full(3, 2.0), edges, geometry, grid, layers, RULE)
    assert len(routes.position) >= 1 and not (routes.edges == 2).any()
    chain = np.vstack([position, routes.position])
    ends = np.bincount(routes.edges.ravel(), minlength=len(chain))
    assert ends[0] == 1 and ends[1] == 1 and np.all(ends[3:] == 2)  # one chain from 0 to 1
    step_cell = np.array([4.2, 4.2])
    for a, b in chain[routes.edges][:, :, :2]:  # no leg passes within 0.45 m of the step's cell centre
        t = np.clip(np.dot(step_cell - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
        assert np.linalg.norm(a + t * (b - a) - step_cell) > 0.45


def test_blocks_cross_holes_up_to_twice_hole_blocks_wide():
    """A run of 2 HOLE blocks without ground between level blocks (3.2 m: far rings) is open; one
    block more is not."""
    H, W = 12, 48
    observed = np.ones((H, W), bool)
    observed[:, 4 : 4 + 4 * HOLE] = False  # 2 HOLE blocks
    observed[:, 24 : 26 + 4 * HOLE] = False  # 2 HOLE + 1 blocks
    grid, layers = flat_layers((H, W), observed, np.zeros((H, W), bool))
    blocks = RouteBlocks.of(grid, layers, RULE).open
    assert blocks[:, 2 : 2 + 2 * HOLE].all()
    assert not blocks[HOLE:-HOLE, 12 : 13 + 2 * HOLE].any()


def test_cells_of_unknown_slope_neither_open_nor_close_blocks_unless_their_step_is_known():
    """Far ground seen in single cells: a band (columns 16..23) whose every fourth cell holds
    ground without neighbours for a plane (slope unknown, NaN), between level ground. Such a cell
    is no evidence of a slope: the band's blocks open as a run without ground would (2 HOLE blocks
    wide at most), where an unknown slope read as bad closed them and the blocks around them. One
    of them whose step is known, 15 cm, stays bad."""
    H, W = 16, 40
    observed = np.ones((H, W), bool)
    observed[:, 16:24] = False
    rows, cols = np.indices((H, W))
    lone = (cols >= 16) & (cols < 24) & (rows % 4 == 1) & (cols % 4 == 1)
    grid, layers = flat_layers((H, W), observed | lone, np.zeros((H, W), bool))
    unknown = lone.ravel()[layers.cells]
    layers.gradient[unknown] = np.nan
    layers.step[unknown] = np.nan
    assert np.isnan(layers.slope[unknown]).all()
    blocks = RouteBlocks.of(grid, layers, RULE)
    assert blocks.open[:, 8:12].all() and not blocks.bad[:, 16:24].any()
    at = np.flatnonzero(layers.cells == 9 * W + 21)
    layers.step[at] = 0.15
    blocks = RouteBlocks.of(grid, layers, RULE)
    assert blocks.bad[9, 21] and not blocks.open[4, 10]


@pytest.mark.parametrize(
    ("hole", "far", "level"),
    [((4.0, 8.0), 0.0, True), ((4.0, 8.0), 0.15, False), ((4.0, 8.0), 0.04, True), ((2.0, 8.0), 0.0, False)],
)
def test_a_route_is_judged_across_a_stretch_without_ground_that_spans_its_bends(hole, far, level):
    """Level ground along y (0.4 m cells) with no ground over x in `hole` and the ground beyond it
    at `far` metres; a route from x = 1 to x = 11 bends twice inside the stretch, so its middle leg
    holds no ground at all. Judged along the whole route, the stretch (4 m) is level when the
    heights on its two sides are within the 5 cm step; a 15 cm curb in it is not, nor a 6 m
    stretch (more than the profile's 5 m of unobserved ground), level as its sides are."""
    H, W = 10, 30
    x = (np.arange(W) + 0.5) * 0.4
    observed = np.broadcast_to((x < hole[0]) | (x > hole[1]), (H, W)).copy()
    grid, layers = flat_layers((H, W), observed, np.zeros((H, W), bool))
    layers.height[:] = np.where(layers.cells % W >= int(hole[1] / 0.4), far, 0.0)
    chain = np.array([[1.0, 2.0], [5.0, 2.0], [7.0, 2.4], [11.0, 2.0]])
    assert level_along(layers, chain, RULE) == level
    assert not level_along(layers, chain[1:3], RULE)  # the middle leg alone holds no ground


def ring_layers(curb: bool) -> tuple[TerrainGrid, GroundLayers]:
    """Level ground (x 0..24, y 0..8 m, 0.4 m cells) seen only in diagonal rings two cells wide,
    six cells apart (far from the sensor): no cell has ground within four cells along x or y on
    both sides, so every step reads unknown (NaN), while each ring's own cells fix the slope (0).
    With `curb`, the ground beyond x = 12 m stands 15 cm higher."""
    H, W = 20, 60
    rows, cols = np.indices((H, W))
    observed = ((rows + cols) % 6 < 2).ravel()
    cells = np.flatnonzero(observed)
    n = len(cells)
    height = np.where(curb & (cells % W >= 30), 0.15, 0.0).astype(np.float32)
    step = np.full(n, np.nan, np.float32)
    layers = GroundLayers(
        cells, height, np.zeros((n, 2), np.float32), step, np.zeros(n, np.float32), (H, W), np.zeros(2), 0.4
    )
    grid = TerrainGrid(
        np.zeros((H, W), np.int16), np.zeros((H, W), np.float32), np.zeros((H, W), bool), np.zeros(2), 0.4
    )
    return grid, layers


@pytest.mark.parametrize("curb", [False, True])
def test_a_route_crosses_ground_seen_in_sparse_rings_unless_the_rings_differ_by_a_step(curb):
    # The rings' unknown steps are no steps: their blocks open, and each leg is judged on the
    # heights across the gaps between rings, where a curb between two rings reads 15 cm.
    grid, layers = ring_layers(curb)
    position = np.array([[2.0, 4.0, 0.0], [22.0, 4.0, 0.15 if curb else 0.0]])
    edges, geometry = np.zeros((0, 2), np.int64), np.zeros((0, 5), np.float32)
    routes = level_routes(position, np.zeros(2, np.int64), np.full(2, 2.0), edges, geometry, grid, layers, RULE)
    assert (len(routes.edges) > 0) != curb
    if not curb:
        assert np.all(routes.geometry[:, 0] <= RULE.max_step) and np.all(routes.geometry[:, 3] <= RULE.max_unobserved)


def test_a_built_street_without_gap_places_is_crossed_by_a_route():
    msm = street_map(*street())
    build = build_scene_graph(msm, BuildConfig.model_validate(NO_GAP_PLACES))
    graph = build.graph
    route = graph.place_edge_kind == EDGE_LEVEL_ROUTE
    assert route.any() and build.stats.edges.level_route == int(route.sum())
    start, goal = nearest(graph, 3.0, 2.5, ASPHALT), nearest(graph, 27.0, 9.0, SIDEWALK)
    chair = plan_path(graph, start, goal, robot=ROBOTS["wheelchair"])
    crossings = curb_crossings(chair.waypoints)
    assert len(crossings) == 1 and CUT[0] <= crossings[0] <= CUT[1]
    assert largest_true_step(chair.waypoints) <= 0.05
    assert chair.ground is not None and chair.ground.max_step_m <= 0.05
    # The places of a route count with their terrain; the stored edges name their kind.
    assert sum(build.stats.places_per_terrain.values()) == len(graph.places)
    # The room, read before the routes, is extended to their places: nothing stands on the street.
    room = graph.places.room
    assert room is not None and len(room) == len(graph.places) and np.all(room == ROOM_REACH)
    stored = scene_graph_to_spark_json(graph)["edges"]
    kinds = {e["info"]["metadata"]["terra"]["kind"] for e in stored if e["info"]["metadata"]}
    assert "level_route" in kinds and EdgeTerra.model_validate({"kind": "level_route"}).kind == "level_route"
    # Without routes as well, the road and the walk meet only over the curb.
    config = BuildConfig.model_validate({"linking": {"curb_gap_max_step": None, "level_route_length": None}})
    without = build_scene_graph(msm, config).graph
    assert not (without.place_edge_kind == EDGE_LEVEL_ROUTE).any()
    start, goal = nearest(without, 3.0, 2.5, ASPHALT), nearest(without, 27.0, 9.0, SIDEWALK)
    with pytest.raises(NoPathError):
        plan_path(without, start, goal, robot=ROBOTS["wheelchair"])


def test_a_street_without_a_cut_gets_no_route_and_no_wheelchair_path():
    graph = build_scene_graph(street_map(*street(cut=False)), BuildConfig.model_validate(NO_GAP_PLACES)).graph
    assert not (graph.place_edge_kind == EDGE_LEVEL_ROUTE).any()
    start, goal = nearest(graph, 3.0, 2.5, ASPHALT), nearest(graph, 27.0, 9.0, SIDEWALK)
    with pytest.raises(NoPathError):
        plan_path(graph, start, goal, robot=ROBOTS["wheelchair"])
    legged = plan_path(graph, start, goal, robot=ROBOTS["legged"])  # 20 cm: the curb is a step it takes
    assert legged.ground is not None and legged.ground.max_step_m > 0.05


@pytest.mark.parametrize(
    ("curb", "before_only", "level"), [(0.0, False, True), (0.15, False, False), (0.0, True, False)]
)
def test_a_stretch_without_ground_on_a_slope_both_sides_share_is_level(curb, before_only, level):
    """Ground falling 1 degree along x (1.75 cm a metre) with no ground over x 4..8 m: its two
    sides differ by 7 cm across the stretch, all of it the slope both share, so a route along it
    is level; a 15 cm curb in the stretch is not. Where only the ground before the stretch slopes
    and the ground beyond is level, 8 cm lower (a ramp meeting a curb hidden in the stretch looks
    so), no slope is shared and it explains nothing: refused."""
    H, W = 10, 30
    grade = np.tan(np.radians(1.0))
    x = (np.arange(W) + 0.5) * 0.4
    observed = np.broadcast_to((x < 4.0) | (x > 8.0), (H, W)).copy()
    grid, layers = flat_layers((H, W), observed, np.zeros((H, W), bool))
    cx = x[layers.cells % W]
    beyond = cx > 8.0
    layers.height[:] = -grade * cx - np.where(beyond, curb, 0.0)
    layers.gradient[:, 0] = -grade
    if before_only:
        layers.height[beyond] = -grade * 8.4
        layers.gradient[beyond, 0] = 0.0
    chain = np.array([[1.0, 2.0], [11.0, 2.0]])
    assert level_along(layers, chain, RULE) == level


def test_a_stretch_without_ground_around_a_bend_is_judged_on_the_ground_it_crosses():
    """Ground falling 1.5 degrees along x, with no ground over x 4..7.2 m for y < 3.2 m; a route
    east along y = 2 m to x = 6.4 m, then north: its stretch without ground runs 2.4 m east and
    1.2 m north, and falls 6.3 cm, all of it the slope both its sides' planes share. Its sides'
    slopes along the route (east before it, north after) would not agree on any of it."""
    H, W = 20, 30
    grade = np.tan(np.radians(1.5))
    rows, cols = np.indices((H, W))
    x, y = (cols + 0.5) * 0.4, (rows + 0.5) * 0.4
    observed = ~((x > 4.0) & (x < 7.2) & (y < 3.2))
    grid, layers = flat_layers((H, W), observed, np.zeros((H, W), bool))
    layers.height[:] = -grade * x.ravel()[layers.cells]
    layers.gradient[:, 0] = -grade
    chain = np.array([[1.0, 2.0], [6.4, 2.0], [6.4, 6.0]])
    assert level_along(layers, chain, RULE)
    layers.height[y.ravel()[layers.cells] > 3.2] -= 0.15  # a curb along y = 3.2 m, where the stretch ends
    assert not level_along(layers, chain, RULE)


def test_a_leg_that_is_not_level_is_split_over_its_own_blocks():
    """A route's polyline over open blocks (all of a level grid but one bad cell) judged with legs
    that are not level: each is replaced by legs over the same path points spanning at most half
    as many (9 points: 0-8 becomes 0-4-8), each straight and open (the bad cell's blocks are
    closed: no leg runs across them); level legs, and legs between neighbouring points, stay."""
    H, W = 12, 40
    bad = np.zeros((H, W), bool)
    bad[8, 20] = True  # at x 8.0..8.4, y 3.2..3.6: its block and the ring around it closed
    grid, layers = flat_layers((H, W), np.ones((H, W), bool), bad)
    blocks = RouteBlocks.of(grid, layers, RULE)
    path = np.column_stack([0.4 + 0.8 * np.arange(9), np.full(9, 1.2)])  # block centres along y = 1.2 m
    flat, steep = np.zeros(5, np.float32), np.array([0.08, 0, 0, 0, 0], np.float32)
    one_leg = Route((0, 1), np.zeros((0, 3)), np.zeros(0, np.int64), 9, np.array([steep]), path)
    split = _refined(blocks, layers, one_leg, RULE)
    assert split is not None and split.index.tolist() == [4]
    np.testing.assert_allclose(split.xyz, [[path[4, 0], path[4, 1], 0.0]])
    second = Route((0, 1), split.xyz, split.index, 9, np.array([flat, steep]), path)
    finer = _refined(blocks, layers, second, RULE)
    assert finer is not None and finer.index.tolist() == [4, 6]
    assert (
        _refined(blocks, layers, Route((0, 1), split.xyz, split.index, 9, np.array([flat, flat]), path), RULE) is None
    )
    neighbours = Route((0, 1), np.zeros((0, 3)), np.zeros(0, np.int64), 2, np.array([steep]), path[:2])
    assert _refined(blocks, layers, neighbours, RULE) is None
    # A path bending north past the bad cell's closed blocks: no new leg crosses them.
    bend = np.array([[6.0, 1.2], [6.8, 1.2], [7.6, 1.2], [8.4, 1.2], [9.2, 1.2], [9.2, 2.0], [9.2, 2.8], [9.2, 4.4]])
    around = Route((0, 1), np.zeros((0, 3)), np.zeros(0, np.int64), len(bend), np.array([steep]), bend)
    finer = _refined(blocks, layers, around, RULE)
    assert finer is not None
    vertices = bend[[0, *finer.index.tolist(), len(bend) - 1]]
    assert np.all(np.diff([0, *finer.index.tolist(), len(bend) - 1]) <= 4)
    for a, b in zip(vertices[:-1], vertices[1:], strict=True):
        assert _lines_open(blocks, a, b[None])[0]
