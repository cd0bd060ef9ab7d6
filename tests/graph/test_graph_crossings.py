"""Places at the gaps of a curb (terra.graph.crossings): gaps found on hand-made grids, and a
street with a curb cut built end to end, where a wheelchair must cross at the cut."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from terra.errors import NoPathError
from terra.graph.config import BuildConfig
from terra.graph.crossings import curb_gaps
from terra.graph.pipeline import build_scene_graph
from terra.graph.results import BuildStats
from terra.tasks.planning import plan_path
from terra.tasks.robot import ROBOTS
from tests.graph.fixtures_ground import points_map

CELL = 0.4
SIDEWALK, GRASS, ASPHALT = 0, 1, 2


def street_grid(gap_cols: range, step: float = 0.15) -> tuple[np.ndarray, np.ndarray]:
    """Labels (30, 60): asphalt rows 0-14, sidewalk rows 15-29; steps (30, 60) metres: `step` on
    the two rows beside the curb (14 and 15), 0.01 in the columns `gap_cols` and elsewhere."""
    label = np.full((30, 60), SIDEWALK, dtype=np.int16)
    label[:15] = ASPHALT
    steps = np.full(label.shape, 0.01)
    steps[14:16] = step
    steps[14:16, gap_cols.start : gap_cols.stop] = 0.01
    return label, steps


def test_a_gap_in_a_curb_gets_one_place_at_its_middle():
    label, steps = street_grid(range(20, 28))  # 8 cells: a 3.2 m curb cut
    gaps = curb_gaps(label, steps, CELL, max_step=0.04, min_width=1.0, max_width=12.0, terrains=3)
    assert len(gaps.cell) == 1
    # By hand: level cells keep one cell from the curb's steps, so the run is rows 14-15, columns
    # 21-26: its cell nearest the centroid (14.5, 23.5) is on row 14 or 15, column 23 or 24; its
    # width is the run's diagonal, hypot(1, 5) + 1 = 6.1 cells, plus the cell it keeps on each
    # side: 8.1 cells, 3.24 m.
    row, col = gaps.cell[0]
    assert row in (14, 15) and col in (23, 24)
    assert gaps.width[0] == pytest.approx((np.hypot(1, 5) + 1 + 2) * CELL)
    assert gaps.terrain[0] == label[row, col]
    assert set(np.flatnonzero(gaps.touches[0])) == {SIDEWALK, ASPHALT}


@pytest.mark.parametrize(
    ("gap", "step", "why"),
    [
        (range(20, 22), 0.15, "two cells: no cell of it keeps clear of the steps"),
        (range(0, 60), 0.15, "no curb: the whole boundary is level"),
        (range(20, 28), 0.01, "no curb: a boundary without steps is no curb"),
        (range(5, 45), 0.15, "16 m: wider than 12 m, a level stretch between two curbs, no gap"),
    ],
)
def test_no_gap(gap: range, step: float, why: str):
    label, steps = street_grid(gap, step)
    gaps = curb_gaps(label, steps, CELL, max_step=0.04, min_width=1.0, max_width=12.0, terrains=3)
    assert len(gaps.cell) == 0, why


def test_unknown_steps_make_no_gap():
    label, steps = street_grid(range(20, 28))
    steps[14:16, 20:28] = np.nan  # the cut unobserved: nothing says it is level
    assert len(curb_gaps(label, steps, CELL, 0.04, 1.0, 12.0, terrains=3).cell) == 0


def curb_street(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A road (y < 5, z = 0) and a sidewalk 15 cm up beyond a curb at y = 5 (x 0..30, y 0..12,
    metres), with a 3 m curb cut at x 12..15 ramping at 1:12 from the road to the sidewalk over
    y 5..6.8. Points (N, 3) and their terrain (N,) (SIDEWALK or ASPHALT)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([0.0, 0.0], [30.0, 12.0], (90000, 2))
    x, y = xy.T
    z = np.where(y >= 5.0, 0.15, 0.0)
    cut = (x >= 12.0) & (x <= 15.0) & (y >= 5.0) & (y < 6.8)
    z = np.where(cut, 0.15 * (y - 5.0) / 1.8, z)
    terrain = np.where(y >= 5.0, SIDEWALK, ASPHALT)
    return np.column_stack([xy, z + rng.normal(0.0, 0.005, len(z))]), terrain


def street_map(points: np.ndarray, terrain: np.ndarray):
    """A map of the points with terrain votes for sidewalk, grass and asphalt (one vote per point)."""
    msm = points_map(points)
    votes = np.zeros((len(points), 3), dtype=np.uint16)
    votes[np.arange(len(points)), terrain] = 1
    embeddings = np.eye(3, msm.dim, dtype=np.float32)
    return replace(
        msm, terrain_classes=["sidewalk", "grass", "asphalt"], terrain_votes=votes, terrain_embeddings=embeddings
    )


def nearest(graph, x: float, y: float, terrain: int) -> int:
    position, on = graph.places.position, graph.places.terrain == terrain
    d = np.hypot(position[:, 0] - x, position[:, 1] - y)
    return int(np.argmin(np.where(on, d, np.inf)))


def test_a_wheelchair_crosses_a_built_street_at_its_curb_cut():
    msm = street_map(*curb_street())
    graph = build_scene_graph(msm).graph
    position = graph.places.position
    at_cut = np.flatnonzero((np.abs(position[:, 0] - 13.5) < 1.5) & (np.abs(position[:, 1] - 5.0) < 1.0))
    assert len(at_cut) == 1  # the gap's place, on the curb line
    start, goal = nearest(graph, 3.0, 2.5, ASPHALT), nearest(graph, 27.0, 9.0, SIDEWALK)
    chair = plan_path(graph, start, goal, robot=ROBOTS["wheelchair"])
    assert at_cut[0] in chair.places
    assert chair.ground is not None and chair.ground.max_step_m <= 0.05
    # Without places at gaps (and without level routes, which find the cut on their own:
    # tests/graph/test_level_routes.py) the road and the sidewalk meet only over the curb.
    config = BuildConfig.model_validate({"linking": {"curb_gap_max_step": None, "level_route_length": None}})
    without = build_scene_graph(msm, config).graph
    assert len(without.places) == len(graph.places) - 1
    start, goal = nearest(without, 3.0, 2.5, ASPHALT), nearest(without, 27.0, 9.0, SIDEWALK)
    with pytest.raises(NoPathError):
        plan_path(without, start, goal, robot=ROBOTS["wheelchair"])


def test_a_lidar_only_street_keeps_places_to_each_level_and_a_wheelchair_crosses_at_the_cut():
    # The same street without terrain classes (a LiDAR-only log): one terrain, `ground`, whose
    # GVD is split at the curb's line of steps (build.ground.barrier_step), so places stand on the
    # road and on the sidewalk, and the GVD passes between them only through the curb cut.
    points, _ = curb_street()
    build = build_scene_graph(points_map(points))
    graph = build.graph
    # The curb's line as the build reports it: 27 m of curb (30 m less the 3 m cut) in one or two
    # rows of 0.4 m cells, about 68 to 135 cells (its ends a cell short or long).
    assert build.stats.step_line_cells is not None and 60 <= build.stats.step_line_cells <= 140
    assert BuildStats.from_json(build.stats.to_json()) == build.stats
    position = graph.places.position
    road, walk = position[:, 1] < 4.5, position[:, 1] > 5.5
    assert road.any() and walk.any()
    assert np.all(np.abs(position[road, 2]) < 0.03) and np.all(np.abs(position[walk, 2] - 0.15) < 0.03)
    start, goal = nearest_of(position, 3.0, 2.5), nearest_of(position, 27.0, 9.0)
    chair = plan_path(graph, start, goal, robot=ROBOTS["wheelchair"])
    assert chair.ground is not None and chair.ground.max_step_m <= 0.05
    a, b = chair.waypoints[:-1], chair.waypoints[1:]
    crosses = (a[:, 1] - 5.0) * (b[:, 1] - 5.0) < 0
    assert crosses.sum() == 1  # one segment over the curb line, where the ground is level: the cut
    ((a, b),) = zip(a[crosses], b[crosses])
    x = a[0] + (5.0 - a[1]) * (b[0] - a[0]) / (b[1] - a[1])
    assert 12.0 <= x <= 15.0
    # Places also link straight across the curb (build.linking.step_link_distance), each such edge
    # reading at least the barrier's 8 cm: a legged robot (20 cm) takes the curb where it stands,
    # the wheelchair does not.
    ends = position[graph.place_edges]
    over = (ends[:, 0, 1] - 5.0) * (ends[:, 1, 1] - 5.0) < 0
    west, east = ends[:, :, 0].min(axis=1), ends[:, :, 0].max(axis=1)
    beside_cut = over & ((west > 15.5) | (east < 11.5))  # both ends clear of the cut (x 12..15) by 0.5 m
    assert beside_cut.any() and np.all(graph.place_edge_geometry[beside_cut, 0] >= 0.08)
    start, goal = nearest_of(position, 3.0, 2.5), nearest_of(position, 3.0, 9.0)
    legged = plan_path(graph, start, goal, robot=ROBOTS["legged"])
    chair = plan_path(graph, start, goal, robot=ROBOTS["wheelchair"])
    assert legged.waypoints[:, 0].max() < 11.5 < 12.0 < chair.waypoints[:, 0].max()  # the chair goes by the cut
    assert legged.ground is not None and 0.1 < legged.ground.max_step_m <= 0.2
    # Not split, the ground's GVD is the street's middle line, on the curb: no place on the road.
    flat = build_scene_graph(points_map(points), BuildConfig.model_validate({"ground": {"barrier_step": None}}))
    assert not (flat.graph.places.position[:, 1] < 4.5).any()


def nearest_of(position: np.ndarray, x: float, y: float) -> int:
    return int(np.argmin(np.hypot(position[:, 0] - x, position[:, 1] - y)))


def verge_street(verge_rise: float = 0.0, unseen: tuple[float, float] | None = None):
    """A road (y < 5, z = 0), a 15 cm curb, a grass verge (y 5..7, z = 0.15) and a sidewalk
    (y >= 7, `verge_rise` metres above the verge) over x 0..30: its terrain grid, ground layers
    (every point is ground), and traversable cells; no ground points in y `unseen` (lo, hi)."""
    from terra.graph.ground import grid_layers
    from terra.graph.pipeline import terrain_grid

    rng = np.random.default_rng(0)
    xy = rng.uniform([0.0, 0.0], [30.0, 12.0], (90000, 2))
    if unseen is not None:
        xy = xy[(xy[:, 1] < unseen[0]) | (xy[:, 1] >= unseen[1])]
    y = xy[:, 1]
    z = np.where(y >= 5.0, 0.15, 0.0) + np.where(y >= 7.0, verge_rise, 0.0) + rng.normal(0.0, 0.005, len(y))
    terrain = np.where(y < 5.0, ASPHALT, np.where(y < 7.0, GRASS, SIDEWALK)).astype(np.int16)
    points = np.column_stack([xy, z])
    grid = terrain_grid(points, terrain, BuildConfig())
    return grid, grid_layers(points, np.ones(len(points), bool), grid), grid.label >= 0


# Verge places A (10, 6.2), B (20, 6.2); sidewalk C (10, 9.5), D (20, 9.5); road E (10, 2.5),
# F (20, 2.5). Edges A-B, C-D, E-F and B-F, the verge's one link, over the curb.
VERGE_PLACES = np.array(
    [[10, 6.2, 0.15], [20, 6.2, 0.15], [10, 9.5, 0.15], [20, 9.5, 0.15], [10, 2.5, 0], [20, 2.5, 0]]
)
VERGE_TERRAIN = np.array([GRASS, GRASS, SIDEWALK, SIDEWALK, ASPHALT, ASPHALT])
VERGE_EDGES = np.array([[0, 1], [2, 3], [4, 5], [1, 5]])


def verge_links(**street) -> np.ndarray:
    from terra.graph.crossings import level_links

    grid, layers, traversable = verge_street(**street)
    return level_links(VERGE_PLACES, VERGE_TERRAIN, VERGE_EDGES, traversable, grid, layers, 0.04, 6.0, 8)


def test_a_verge_reached_only_over_a_curb_is_linked_level_to_the_walk_beside_it():
    # A's nearest other place in another level piece is C (3.3 m, level), then E (3.7 m, over the
    # curb: refused); B's is D. C and D are already level with each other, E and F too; E's only
    # place within 6 m of another piece is A, across the curb; B-F's own line reads the curb.
    assert verge_links().tolist() == [[0, 2], [1, 3]]


def test_no_level_link_over_a_step_or_across_unobserved_ground():
    assert len(verge_links(verge_rise=0.15)) == 0  # a second curb between the verge and the walk
    assert len(verge_links(unseen=(6.6, 7.6))) == 0  # their boundary never seen: nothing says it is level
