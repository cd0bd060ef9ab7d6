"""The room around places (terra.graph.room): obstacle points and distances to them against
hand-worked geometry and shapely, its use for robot widths, and its storage."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import MultiPoint, Point

from terra.bundle import Bundle, BundleWriter
from terra.graph.grid import GridFrame, empty_grid
from terra.graph.room import ROOM_REACH, obstacle_points, place_room
from terra.graph.scene_graph import EDGE_GVD, Places, SceneGraph
from terra.graph.storage import load_scene_graph, write_scene_graph
from terra.tasks.planning import plan_path
from terra.tasks.robot import ROBOTS
from tests.graph.fixtures import copy_bundle
from tests.graph.fixtures_ground import lidar_only_bundle  # noqa: F401  # fixture

CELL = 0.4


def grid_with(blocked_cells: list[tuple[int, int]], shape=(20, 30), origin=(-2.0, 1.0), offset=(0, 0)):
    grid = empty_grid(GridFrame(origin, shape, CELL, offset))
    for r, c in blocked_cells:
        grid.blocked[r, c] = True
    return grid


def test_obstacle_points_are_those_that_block_cells():
    """Blocked cell (row 10, col 10: x 2.0 .. 2.4, y 5.0 .. 5.4 m) on ground 0.5 m high, the band
    0.3 .. 2.0 m above it: its centre, and of a point at 0.9 m, one at 0.6 m (0.1 m above the
    ground: no), one at 2.7 m (a branch overhead: no), one at 1.0 m in a free cell (no) and one
    outside the grid, only the first; a window of a larger grid (its offset) finds the same."""
    points = np.array([[2.1, 5.1, 0.9], [2.3, 5.3, 0.6], [2.2, 5.2, 2.7], [3.0, 5.1, 1.0], [50.0, 5.1, 1.0]])
    for offset in ((0, 0), (2, 3)):
        grid = grid_with([(10 - offset[0], 10 - offset[1])], origin=(-2.0, 1.0), offset=offset)
        grid.ground[:] = 0.5
        np.testing.assert_allclose(obstacle_points(points, grid, (0.3, 2.0)), [[2.2, 5.2], [2.1, 5.1]], atol=1e-12)
        assert len(obstacle_points(points, grid, None)) == 0


def test_room_by_hand():
    """A bollard 0.2 m square at (4.5, 20.0), seen as points on its sides: a place at (5.0, 19.4)
    is 0.64 m from it (to its nearest point, (4.6, 19.9)); far away, the reach; with no obstacle,
    the reach everywhere."""
    side = np.linspace(-0.1, 0.1, 5)
    bollard = np.vstack(
        [np.column_stack([4.5 + side, np.full(5, 19.9)]), np.column_stack([np.full(5, 4.6), 20.0 + side])]
    )
    places = np.array([[5.0, 19.4, 0.7], [20.0, 20.0, 0.0], [4.6, 19.9, 0.0]])
    np.testing.assert_allclose(place_room(places, bollard), [np.hypot(0.4, 0.5), ROOM_REACH, 0.0], atol=1e-9)
    assert np.all(place_room(places, np.zeros((0, 2))) == ROOM_REACH)


def test_room_agrees_with_shapely():
    """Random obstacle points and places: the room is shapely's distance to the points, up to the reach."""
    rng = np.random.default_rng(4)
    obstacles = rng.uniform(0.0, 20.0, (60, 2))
    xy = rng.uniform(-2.0, 22.0, (300, 2))
    cloud = MultiPoint([tuple(p) for p in obstacles])
    expected = np.minimum([cloud.distance(Point(x, y)) for x, y in xy], ROOM_REACH)
    np.testing.assert_allclose(place_room(xy, obstacles), expected, atol=1e-9)


def two_places(clearance: float, room: float) -> SceneGraph:
    position = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    return SceneGraph(
        terrain_classes=["ground"],
        terrain_embeddings=np.eye(1, 4, dtype=np.float32),
        places=Places(
            position,
            np.zeros(2, np.int64),
            np.full(2, clearance),
            np.tile(np.eye(1, 4, dtype=np.float32), (2, 1)),
            room=np.full(2, room),
        ),
        place_edges=np.array([[0, 1]]),
        place_edge_weight=np.array([5.0]),
        place_edge_kind=np.array([EDGE_GVD]),
        place_edge_geometry=np.zeros((1, 5), dtype=np.float32),
    )


def test_a_robot_is_checked_against_the_room_and_against_clearance_without_it():
    """A place beside a hole in the scan (clearance one 0.4 m cell) with the nearest obstacle 2 m
    away: the 0.9 m wheelchair passes; 0.3 m from an obstacle with 1 m of clearance: it does not;
    a graph that does not record the room checks the clearance as before."""
    from terra.tasks.planning import NoPathError

    chair = ROBOTS["wheelchair"]
    assert len(plan_path(two_places(clearance=0.4, room=2.0), 0, 1, robot=chair).places) == 2
    with pytest.raises(NoPathError):
        plan_path(two_places(clearance=1.0, room=0.3), 0, 1, robot=chair)
    with pytest.raises(NoPathError):
        plan_path(two_places(clearance=0.4, room=np.nan), 0, 1, robot=chair)
    assert len(plan_path(two_places(clearance=1.0, room=np.nan), 0, 1, robot=chair).places) == 2
    with pytest.raises(ValueError, match="room"):
        Places(np.zeros((2, 3)), np.zeros(2, np.int64), np.ones(2), np.zeros((2, 4), np.float32), room=np.ones(3))


def test_the_room_is_stored_and_an_older_bundle_reads_it_unknown(lidar_only_bundle, tmp_path):  # noqa: F811
    path = copy_bundle(lidar_only_bundle, tmp_path / "old.terra")
    graph = load_scene_graph(Bundle(path))
    room = np.asarray(graph.places.room)
    assert np.isfinite(room).all() and np.all((room >= 0) & (room <= ROOM_REACH))
    with BundleWriter(path, base=Bundle(path)) as writer:
        writer.remove("graph/place_room")
    old = load_scene_graph(Bundle(path))
    assert np.isnan(np.asarray(old.places.room)).all()
    with BundleWriter(path, base=Bundle(path)) as writer:  # written again: still unknown, still readable
        write_scene_graph(writer, old)
    assert np.isnan(np.asarray(load_scene_graph(Bundle(path)).places.room)).all()
