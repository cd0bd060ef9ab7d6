"""Ground under an object outline (terra.graph.grid.block_under_objects): a parked car seen from
one side leaves a ring of blocked cells around free ground; that ground is blocked, while walls,
large outlines and open ground stay as they are."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from terra.graph.config import BuildConfig
from terra.graph.grid import TerrainGrid, block_under_objects
from terra.graph.pipeline import terrain_grid
from tests.graph.fixtures_ground import points_map
from tests.graph.test_graph_crossings import curb_street, street_map

CELL = 0.4


def grid_of(blocked: np.ndarray) -> TerrainGrid:
    """A grid of label 0 everywhere but the blocked cells (-1), origin (0, 0), 0.4 m cells."""
    label = np.where(blocked, -1, 0).astype(np.int16)
    return TerrainGrid(label, np.zeros(blocked.shape, np.float32), blocked.copy(), np.zeros(2), CELL)


def test_the_ground_inside_a_car_outline_open_on_one_side_is_blocked():
    blocked = np.zeros((10, 16), bool)
    blocked[2, 2:14] = True  # the car's side along the curb: 12 cells, 4.8 m
    blocked[2:7, 2] = blocked[2:7, 13] = True  # its two ends; its far side (row 6) unseen
    grid = grid_of(blocked)
    assert block_under_objects(grid, 6.0) == 4 * 10  # rows 3-6 between columns 3 and 12
    assert grid.blocked[3:7, 2:14].all() and (grid.label[3:7, 3:13] == -1).all()
    assert not grid.blocked[7:].any() and not grid.blocked[:2].any()  # open ground stays free


def test_walls_and_large_outlines_enclose_nothing():
    wall = np.zeros((10, 40), bool)
    wall[4, 2:38] = True  # a straight wall: its hull is a line
    assert block_under_objects(grid_of(wall), 6.0) == 0
    yard = np.zeros((40, 40), bool)
    yard[2, 2:30] = yard[2:30, 2] = True  # an L-shaped building 11 m a side: it frames a yard
    grid = grid_of(yard)
    assert block_under_objects(grid, 6.0) == 0 and not grid.blocked[5, 5]
    assert block_under_objects(grid, 12.0) > 0  # counted as an object when the limit allows it


def car_street():
    """curb_street with a car on the sidewalk against the curb (x 20-24.6, y 5.3-7.3): points on
    its two ends and its curb side, 0.45-1.4 m up, none on its far side or roof (a LiDAR on the
    road sees only those); the ground under it keeps its points."""
    points, terrain = curb_street()
    rng = np.random.default_rng(1)
    sides = []
    for x0, y0, x1, y1 in ((20.0, 5.3, 20.0, 7.3), (24.6, 5.3, 24.6, 7.3), (20.0, 5.3, 24.6, 5.3)):
        t = rng.uniform(0.0, 1.0, 600)
        sides.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0), rng.uniform(0.45, 1.4, 600)]))
    body = np.vstack(sides)
    msm = street_map(points, terrain)
    votes = np.vstack([msm.terrain_votes, np.zeros((len(body), 3), np.uint16)])  # the car: no terrain
    bare = points_map(np.vstack([points, body]))
    return replace(
        bare, terrain_classes=msm.terrain_classes, terrain_votes=votes, terrain_embeddings=msm.terrain_embeddings
    )


def test_a_built_grid_blocks_the_ground_under_a_parked_car():
    msm = car_street()
    terrain = msm.terrain_index(0.5, dtype=np.int16)
    under = np.array([[21.0, 6.2], [22.3, 6.6], [23.6, 6.0]])  # free ground under the car's body
    for extent, blocked in ((6.0, True), (None, False)):
        config = BuildConfig.model_validate({"grid": {"object_extent": extent}})
        grid = terrain_grid(msm.points, terrain, config)
        rows, cols, inside = grid.cell_of(under)
        assert inside.all() and (grid.blocked[rows, cols] == blocked).all()
        rows, cols, _ = grid.cell_of(np.array([[22.3, 9.5], [10.0, 2.0]]))  # the open sidewalk and the road
        assert not grid.blocked[rows, cols].any()
