"""Grid links between same-terrain pieces, on hand-made grids with the paths worked by hand."""

from __future__ import annotations

import numpy as np
import pytest

from terra.graph.grid_links import (
    GridPathRules,
    candidate_pairs,
    link_pieces_on_grid,
    terrain_pieces,
)

CELL = 0.5
# A 20 x 30 grid of 0.5 m cells (y 0-10 m, x 0-15 m), all terrain 0, with a wall in column 14
# (x 7-7.5 m) over rows 0-15 (y 0-8 m). Place 0 sits in cell (row 4, col 13), place 1 in cell
# (row 4, col 16): 1.5 m apart, on either side of the wall.
H, W = 20, 30


def grid(top: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """label, blocked: the wall, with rows 16-19 of column 14 set to terrain `top` (-1: unlabelled)."""
    label = np.zeros((H, W), dtype=np.int16)
    blocked = np.zeros((H, W), dtype=bool)
    blocked[:16, 14] = True
    label[:16, 14] = -1
    label[16:, 14] = top
    return label, blocked


def rules(label: np.ndarray, blocked: np.ndarray, max_gap: float = 4.0, max_length: float = 20.0) -> GridPathRules:
    return GridPathRules(label, blocked, np.zeros(2), CELL, max_gap, max_length)


def centre(row: int, col: int, z: float = 0.0) -> list[float]:
    return [(col + 0.5) * CELL, (row + 0.5) * CELL, z]


POSITION = np.array([centre(4, 13), centre(4, 16)])
TERRAIN = np.array([0, 0])
NO_EDGES = np.zeros((0, 2), dtype=np.int64)
# By hand: up column 13 from row 4 to row 16 (12 steps), across row 16 to column 15 (2 steps), one
# diagonal to (15, 16) (its side cells (15, 15) and (16, 16) are free), down to row 4 (11 steps).
# The diagonals (15, 13) -> (16, 14) and (16, 14) -> (15, 15) would squeeze past the wall's top
# cell (15, 14), so they are not allowed: 25 straight steps and one diagonal.
AROUND_THE_WALL = 25 * CELL + np.sqrt(2) * CELL


def test_two_pieces_either_side_of_a_wall_are_linked_by_the_path_round_it():
    label, blocked = grid()
    links, cost = link_pieces_on_grid(POSITION, TERRAIN, NO_EDGES, rules(label, blocked), reach=12.0)
    assert links.tolist() == [[0, 1]]
    assert cost == pytest.approx([AROUND_THE_WALL])  # 13.21 m, not the straight line's 1.5 m


def test_the_link_costs_the_path_with_the_height_difference_of_its_places():
    label, blocked = grid()
    position = np.array([centre(4, 13, 0.0), centre(4, 16, 1.0)])
    _, cost = link_pieces_on_grid(position, TERRAIN, NO_EDGES, rules(label, blocked), reach=12.0)
    assert cost == pytest.approx([np.hypot(AROUND_THE_WALL, 1.0)])


def test_no_link_when_the_path_round_is_longer_than_allowed_or_there_is_none():
    label, blocked = grid()
    links, _ = link_pieces_on_grid(POSITION, TERRAIN, NO_EDGES, rules(label, blocked, max_length=13.0), reach=12.0)
    assert links.shape == (0, 2)
    blocked[16:, 14], label[16:, 14] = True, -1  # the wall reaches the grid's edge
    links, _ = link_pieces_on_grid(POSITION, TERRAIN, NO_EDGES, rules(label, blocked), reach=12.0)
    assert links.shape == (0, 2)


def test_unlabelled_cells_are_crossed_for_at_most_max_gap_metres_and_another_terrain_never():
    label, blocked = grid(top=-1)  # the way round crosses one unlabelled cell, (16, 14): 0.5 m of it
    short, _ = link_pieces_on_grid(POSITION, TERRAIN, NO_EDGES, rules(label, blocked, max_gap=0.4), reach=12.0)
    assert short.shape == (0, 2)
    links, cost = link_pieces_on_grid(POSITION, TERRAIN, NO_EDGES, rules(label, blocked, max_gap=0.5), reach=12.0)
    assert links.tolist() == [[0, 1]] and cost == pytest.approx([AROUND_THE_WALL])
    label, blocked = grid(top=1)  # grass across the way round: not a sidewalk route
    links, _ = link_pieces_on_grid(POSITION, TERRAIN, NO_EDGES, rules(label, blocked), reach=12.0)
    assert links.shape == (0, 2)


def test_places_farther_apart_than_the_reach_are_not_tried():
    label, blocked = grid()
    links, _ = link_pieces_on_grid(POSITION, TERRAIN, NO_EDGES, rules(label, blocked), reach=1.4)
    assert links.shape == (0, 2)


def test_joined_pieces_and_other_terrains_get_no_link():
    label, blocked = grid()
    links, _ = link_pieces_on_grid(POSITION, TERRAIN, np.array([[0, 1]]), rules(label, blocked), reach=12.0)
    assert links.shape == (0, 2)  # one piece already
    links, _ = link_pieces_on_grid(POSITION, np.array([0, 1]), NO_EDGES, rules(label, blocked), reach=12.0)
    assert links.shape == (0, 2)  # two terrains: cross-terrain links join those


def test_three_pieces_in_a_row_get_two_links_nearest_first():
    # Open ground, places at x 1, 3 and 5.5 m on row 4: pieces {0}, {1}, {2}. The pairs 0-1 (2 m)
    # and 1-2 (2.5 m) join all three, so 0-2 (4.5 m) is never searched.
    label, blocked = np.zeros((H, W), dtype=np.int16), np.zeros((H, W), dtype=bool)
    position = np.array([centre(4, 1), centre(4, 5), centre(4, 10)])
    terrain = np.zeros(3, dtype=np.int64)
    piece = terrain_pieces(terrain, NO_EDGES)
    assert candidate_pairs(position, terrain, piece, reach=12.0, candidates=8).tolist() == [[0, 1], [1, 2], [0, 2]]
    links, cost = link_pieces_on_grid(position, terrain, NO_EDGES, rules(label, blocked), reach=12.0)
    assert links.tolist() == [[0, 1], [1, 2]]
    assert cost == pytest.approx([2.0, 2.5])


def test_a_piece_links_from_whichever_of_its_places_gives_the_cheapest_path():
    # Piece {0, 1} (joined by an edge) and piece {2}: the nearest pair is 0-2 across the wall, but
    # place 1 at (row 18, col 13) reaches 2 above the wall: diagonals to (17, 14), (16, 15) and
    # (15, 16) (no wall cell beside them), then down to (4, 16): 3 diagonals + 11 straight
    # (7.62 m, against 13.21 m from place 0).
    label, blocked = grid()
    position = np.array([centre(4, 13), centre(18, 13), centre(4, 16)])
    terrain = np.zeros(3, dtype=np.int64)
    links, cost = link_pieces_on_grid(position, terrain, np.array([[0, 1]]), rules(label, blocked), reach=12.0)
    assert links.tolist() == [[1, 2]]
    assert cost == pytest.approx([11 * CELL + 3 * np.sqrt(2) * CELL])


def test_the_build_step_reads_the_grid_and_the_linking_configuration():
    from terra.graph.config import BuildConfig
    from terra.graph.grid import TerrainGrid
    from terra.graph.pipeline import TerrainPlaceSet, grid_links

    label, blocked = grid()
    terrain_grid = TerrainGrid(label, np.zeros((H, W), np.float32), blocked, np.zeros(2), CELL)
    places = TerrainPlaceSet(POSITION, TERRAIN, np.ones(2), NO_EDGES, np.zeros(0))
    links, cost = grid_links(places, NO_EDGES, terrain_grid, BuildConfig())
    assert links.tolist() == [[0, 1]] and cost == pytest.approx([AROUND_THE_WALL])
    off = BuildConfig.model_validate({"linking": {"grid_link_distance": None}})
    assert grid_links(places, NO_EDGES, terrain_grid, off)[0].shape == (0, 2)
    short = BuildConfig.model_validate({"linking": {"grid_link_max_length": 13.0}})
    assert grid_links(places, NO_EDGES, terrain_grid, short)[0].shape == (0, 2)
