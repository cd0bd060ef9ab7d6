"""Tiles and windows on hand-made grids, the facts the tiled build rests on, and tiled results
against the one-piece ones: the GVD on hand-made and random masks, the terrain grid on hand-placed
points, and the whole scene graph of the small campus built in several tiles."""

from __future__ import annotations

from typing import Any, cast

import numpy as np
import pytest
from scipy import ndimage

from terra.graph.config import BuildConfig
from terra.graph.grid import build_terrain_grid, grid_frame
from terra.graph.gvd import EIGHT, brushfire, gvd
from terra.graph.pipeline import build_scene_graph
from terra.graph.storage import load_scene_graph
from terra.graph.tiled_grid import TiledGridStats, build_terrain_grid_tiled
from terra.graph.tiled_gvd import TiledGvdStats, obstacle_components, tiled_gvd
from terra.graph.tiling import cores, window

# --------------------------------------------------------------------------- tiles and windows


def test_cores_partition_the_grid_with_smaller_last_row_and_column():
    parts = cores((7, 10), 4)
    assert [(r.start, r.stop, c.start, c.stop) for r, c in parts] == [
        (0, 4, 0, 4),
        (0, 4, 4, 8),
        (0, 4, 8, 10),
        (4, 7, 0, 4),
        (4, 7, 4, 8),
        (4, 7, 8, 10),
    ]
    cover = np.zeros((7, 10), int)
    for core in parts:
        cover[core] += 1
    assert (cover == 1).all()


def test_a_window_is_its_core_grown_and_clipped_with_its_grid_edges_closed():
    win = window((7, 10), (slice(0, 4), slice(4, 8)), margin=2)
    assert (win.rows, win.cols) == (slice(0, 6), slice(2, 10))
    assert win.closed == (True, False, False, True)  # first row and last column are the grid's edge
    assert win.core == (slice(0, 4), slice(2, 6))
    assert not win.whole and window((7, 10), (slice(0, 4), slice(4, 8)), margin=9).whole


def test_gap_counts_cells_to_the_unseen_part_beyond_open_sides_only():
    win = window((7, 10), (slice(0, 4), slice(4, 8)), margin=2)  # rows 0..5, cols 2..9; open: last row, first column
    gap = win.gap()
    # Row i of 6 is (6 - i) from row 6 (unseen); column j is (j + 1) from column 1 (unseen).
    expected = np.minimum(np.arange(6, 0, -1)[:, None], np.arange(1, 9)[None, :]).astype(np.float32)
    assert np.array_equal(gap, expected)
    assert np.isinf(window((7, 10), (slice(0, 7), slice(0, 10)), 0).gap()).all()


def test_clearance_is_the_chessboard_distance_to_unsure_or_unseen_cells():
    win = window((9, 9), (slice(0, 9), slice(0, 9)), 0)  # the whole grid: nothing unseen
    unsure = np.zeros((9, 9), bool)
    unsure[4, 4] = True
    clearance = win.clearance(unsure)
    rows, cols = np.mgrid[:9, :9]
    assert np.array_equal(clearance, np.maximum(abs(rows - 4), abs(cols - 4)).astype(np.float32))
    assert np.isinf(win.clearance(np.zeros((9, 9), bool))).all()


# --------------------------------------------------------------------------- facts relied on


def test_edt_parent_is_the_nearest_obstacle_with_the_lowest_column_then_row():
    # What makes a window's parents the whole grid's: ties are broken by position, not by where
    # the array starts. Brute force over random masks, many with ties.
    rng = np.random.default_rng(1)
    for _ in range(40):
        free = rng.random(tuple(rng.integers(4, 16, 2))) > rng.uniform(0.05, 0.4)
        if free.all():
            continue
        # scipy's untyped function returns None when given output arrays; here it returns both.
        _, (pr, pc) = cast(tuple[np.ndarray, np.ndarray], ndimage.distance_transform_edt(free, return_indices=True))
        obstacles = np.argwhere(~free)
        for r, c in np.argwhere(np.ones_like(free)):
            d2 = ((obstacles - (r, c)) ** 2).sum(axis=1)
            nearest = obstacles[d2 == d2.min()]
            best = nearest[np.lexsort((nearest[:, 0], nearest[:, 1]))[0]]
            assert (pr[r, c], pc[r, c]) == tuple(best)


def test_a_window_brushfire_equals_the_whole_one_where_its_distance_is_below_the_gap():
    free = np.ones((30, 40), bool)
    free[10:13, 5:35] = False  # a wall
    free[22, 20] = False  # a post
    free[25, 8] = False  # a post the window below does not see
    whole = brushfire(free)
    labels = obstacle_components(free)
    win = window(free.shape, (slice(0, 30), slice(15, 25)), margin=3)  # columns 12..27, open left and right
    part = brushfire(
        free[win.rows, win.cols],
        win.closed,
        labels[win.rows.start : win.rows.stop + 2, win.cols.start : win.cols.stop + 2],
    )
    sure = part.distance < win.gap()
    cols = slice(win.cols.start, win.cols.stop)
    assert np.array_equal(part.distance[sure], whole.distance[:, cols][sure])
    assert np.array_equal(part.parent[0][sure], whole.parent[0][:, cols][sure])
    assert np.array_equal(part.parent[1][sure] + win.cols.start, whole.parent[1][:, cols][sure])
    same = part.component[sure][:, None] == part.component[sure][None, :]
    assert np.array_equal(same, whole.component[:, cols][sure][:, None] == whole.component[:, cols][sure][None, :])
    # Cell (9, 20) is next to the wall, well inside: sure. Cell (25, 12) is 4 from the unseen post
    # at column 8, but the window's nearest obstacle is the frame, 5 away: its gap (1) flags it.
    assert sure[9, 8] and not sure[25, 0]
    assert whole.distance[25, 12] == 4.0 and part.distance[25, 0] == 5.0


# --------------------------------------------------------------------------- tiled GVD


def ring_and_corridors() -> np.ndarray:
    """A room with a square island across four tiles, two corridors leaving it across tile seams,
    one of them two cells wide at one point (a neck), and a bent wall (one obstacle component that
    leaves the window and comes back)."""
    free = np.zeros((90, 120), bool)
    free[10:60, 10:70] = True
    free[28:42, 30:50] = False  # island
    free[30:36, 70:115] = True  # east corridor
    free[60:85, 50:56] = True  # south corridor
    free[71:73, 50:53] = False  # its neck: 3 free cells left
    free[20:23, 100:118] = False  # a bent wall, two arms
    free[20:50, 115:118] = False
    return free


@pytest.mark.parametrize("tile, margin", [(16, 4), (25, 9), (40, 2), (64, 64)])
def test_tiled_gvd_equals_the_one_piece_gvd_on_a_hand_made_map(tile, margin):
    free = ring_and_corridors()
    whole = gvd(free, 1.0, 1.5)
    stats = TiledGvdStats()
    tiled = tiled_gvd(free, 1.0, 1.5, tile=tile, margin=margin, stats=stats)
    assert np.array_equal(tiled[0], whole[0]) and np.array_equal(tiled[1], whole[1])
    assert whole[0].sum() > 100 and stats.windows >= len([c for c in cores(free.shape, tile) if free[c].any()])


def test_tiled_gvd_grows_windows_until_the_result_is_proven():
    # A 60 x 60 open square: its centre is 30 cells from any obstacle, so a 4-cell overlap cannot
    # prove the core; the window must grow to at least 2 d + 6 cells around the centre.
    free = np.zeros((70, 70), bool)
    free[5:65, 5:65] = True
    stats = TiledGvdStats()
    tiled = tiled_gvd(free, 1.0, 1.5, tile=10, margin=4, stats=stats)
    whole = gvd(free, 1.0, 1.5)
    assert np.array_equal(tiled[0], whole[0]) and np.array_equal(tiled[1], whole[1])
    assert stats.max_margin >= 32 and stats.windows > len(cores(free.shape, 10))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tiled_gvd_equals_the_one_piece_gvd_on_random_maps(seed):
    rng = np.random.default_rng(seed)
    H, W = rng.integers(80, 140, 2)
    free = np.ones((H, W), bool)
    rows, cols = np.mgrid[:H, :W]
    for _ in range(25):
        r, c, a, b = rng.integers(0, H), rng.integers(0, W), rng.integers(1, 12), rng.integers(1, 12)
        if rng.random() < 0.5:
            free &= (rows - r) ** 2 + (cols - c) ** 2 > a * a
        else:
            free &= ~((abs(rows - r) < a) & (abs(cols - c) < b))
    free = ndimage.binary_opening(free, EIGHT)
    whole = gvd(free, 1.0, 1.5)
    tiled = tiled_gvd(free, 1.0, 1.5, tile=int(rng.integers(12, 40)), margin=int(rng.integers(2, 12)))
    assert np.array_equal(tiled[0], whole[0]) and np.array_equal(tiled[1], whole[1])


# --------------------------------------------------------------------------- tiled terrain grid


def hand_placed_points() -> tuple[np.ndarray, np.ndarray]:
    """Two terrain strips (class 0 along y = 5, class 1 along y = 15) scanned every 0.2 m on a
    slope, unlabelled ground between them, posts on both, and a lone wall 40 m away from any
    terrain point (its ground is the nearest terrain cell's, far outside a small window); a patch
    far north makes the grid reach the wall."""
    xs = np.arange(0.0, 60.0, 0.2)
    strip0 = np.array([(x, y, 0.01 * x) for x in xs for y in np.arange(3.0, 7.0, 0.2)])
    strip1 = np.array([(x, y, 0.01 * x + 0.1) for x in xs for y in np.arange(13.0, 17.0, 0.2)])
    between = np.array([(x, y, 0.01 * x + 0.05) for x in xs[::2] for y in np.arange(8.0, 12.0, 0.4)])
    posts = np.array([(x, y, z) for x in (10.1, 30.3, 50.5) for y in (5.1, 15.1) for z in (0.6, 1.0, 1.4)])
    far = np.array(
        [(x, y, 0.0) for x in np.arange(0.0, 4.0, 0.2) for y in np.arange(96.0, 100.0, 0.2)]
    )  # widens the grid
    wall = np.array([(50.0 + 0.1 * k, 57.0, 0.3 + 0.05 * j) for k in range(20) for j in range(20)])
    points = np.vstack([strip0, strip1, far, between, posts, wall])
    terrain = np.concatenate(
        [
            np.zeros(len(strip0)),
            np.ones(len(strip1)),
            np.zeros(len(far)),
            -np.ones(len(between) + len(posts) + len(wall)),
        ]
    ).astype(int)
    return points, terrain


def test_tiled_terrain_grid_equals_the_one_piece_grid():
    points, terrain = hand_placed_points()
    args: dict[str, Any] = dict(
        cell_size=0.4,
        obstacle_height=(0.3, 2.0),
        obstacle_min_points=2,
        support_radius=1.2,
        min_support=0.6,
        fill_radius=1.0,
    )
    whole = build_terrain_grid(points, terrain, **args)
    tiled = build_terrain_grid_tiled(points, terrain, **args, tile=20, margin=8)
    assert tiled.shape == whole.shape == grid_frame(points, terrain, 0.4).shape
    assert np.array_equal(tiled.origin, whole.origin)
    assert np.array_equal(tiled.label, whole.label) and np.array_equal(tiled.blocked, whole.blocked)
    # Ground is the same wherever a stage reads it: cells holding points, and around labels.
    rows, cols, inside = whole.cell_of(points)
    read = np.asarray(ndimage.binary_dilation(whole.label >= 0, EIGHT, iterations=2), dtype=bool)
    read[rows[inside], cols[inside]] = True
    assert np.array_equal(tiled.ground[read], whole.ground[read])
    # The wall (40 m from any terrain point) is blocked in both: its ground had to come from afar.
    wall_row, wall_col, _ = whole.cell_of(np.array([[51.0, 57.0]]))
    assert whole.blocked[wall_row[0], wall_col[0]] and (whole.label >= 0).sum() > 1000


def assert_same_grid(tiled, whole, points: np.ndarray) -> None:
    assert tiled.shape == whole.shape and np.array_equal(tiled.origin, whole.origin)
    assert np.array_equal(tiled.label, whole.label) and np.array_equal(tiled.blocked, whole.blocked)
    rows, cols, inside = whole.cell_of(points)
    read = np.asarray(ndimage.binary_dilation(whole.label >= 0, EIGHT, iterations=2), dtype=bool)
    read[rows[inside], cols[inside]] = True
    assert np.array_equal(tiled.ground[read], whole.ground[read])


def test_tiled_terrain_grid_equals_the_one_piece_grid_with_the_default_hysteresis():
    points, terrain = hand_placed_points()
    grid = BuildConfig().grid
    args = {
        "cell_size": 0.4,
        "obstacle_height": (0.3, 2.0),
        "obstacle_min_points": 2,
        "support_radius": 1.2,
        "min_support": 0.6,
        "fill_radius": 1.0,
        "weak_support": grid.weak_support,
        "weak_reach": grid.weak_reach,
    }
    whole = build_terrain_grid(points, terrain, **args)
    stats = TiledGridStats()
    tiled = build_terrain_grid_tiled(points, terrain, **args, tile=20, margin=8, stats=stats)
    assert_same_grid(tiled, whole, points)
    assert stats.windows >= 20 and stats.one_piece is None


@pytest.mark.parametrize("cell_size", [0.3, 0.6, 1.0])
def test_tiled_terrain_grid_with_area_coverage_equals_the_one_piece_grid(cell_size):
    """Coverage shares counted on 0.4 m squares that straddle cells (and tile borders)."""
    points, terrain = hand_placed_points()
    grid = BuildConfig().grid
    args = {
        "cell_size": cell_size,
        "obstacle_height": (0.3, 2.0),
        "obstacle_min_points": 2,
        "support_radius": 1.2,
        "min_support": 0.6,
        "fill_radius": 1.0,
        "weak_support": grid.weak_support,
        "weak_reach": grid.weak_reach,
        "support_cell": 0.4,
    }
    whole = build_terrain_grid(points, terrain, **args)
    stats = TiledGridStats()
    tiled = build_terrain_grid_tiled(points, terrain, **args, tile=20, margin=8, stats=stats)
    assert_same_grid(tiled, whole, points)
    assert stats.windows >= 4 and stats.one_piece is None and (whole.label >= 0).any()


def sparsely_labelled_strip() -> tuple[np.ndarray, np.ndarray]:
    """A 4 m wide strip along x (0-60 m, y 3-7 m) scanned every 0.2 m, all of it ground without a
    terrain class except: labelled class 0 every 0.2 m for x < 20 and x >= 40, and between them
    one labelled point in every 2nd column and 3rd row of 0.4 m cells (1/6 of the cells: between
    weak_support 0.1 and min_support 0.6). A patch at y 40 m makes the grid taller than a tile."""
    xs, ys = np.arange(0.0, 60.0, 0.2) + 0.05, np.arange(3.0, 7.0, 0.2) + 0.05
    ground = np.array([(x, y, 0.0) for x in xs for y in ys])
    dense = np.array([(x, y, 0.0) for x in xs if x < 20.0 or x >= 40.0 for y in ys])
    sparse = np.array([(x, y, 0.0) for x in np.arange(20.1, 40.0, 0.8) for y in np.arange(3.1, 7.0, 1.2)])
    far = np.array([(x, y, 0.0) for x in np.arange(0.05, 4.0, 0.2) for y in np.arange(40.05, 44.0, 0.2)])
    points = np.vstack([ground, dense, sparse, far])
    terrain = np.concatenate([-np.ones(len(ground)), np.zeros(len(dense) + len(sparse) + len(far))]).astype(int)
    return points, terrain


@pytest.mark.parametrize("weak_reach, middle_labelled", [(6.0, False), (16.0, True)])
def test_tiled_grid_equals_one_piece_where_the_hysteresis_labels_cells_across_tile_borders(weak_reach, middle_labelled):
    points, terrain = sparsely_labelled_strip()
    args = {
        "cell_size": 0.4,
        "obstacle_height": (0.3, 2.0),
        "obstacle_min_points": 2,
        "support_radius": 0.8,
        "min_support": 0.6,
        "fill_radius": 0.0,
    }
    plain = build_terrain_grid(points, terrain, **args)
    whole = build_terrain_grid(points, terrain, **args, weak_support=0.1, weak_reach=weak_reach)
    tile = 20
    stats = TiledGridStats()
    tiled = build_terrain_grid_tiled(
        points, terrain, **args, weak_support=0.1, weak_reach=weak_reach, tile=tile, margin=4, stats=stats
    )
    assert_same_grid(tiled, whole, points)
    # The hysteresis did label the sparse stretch, from both ends, in cells on tile borders.
    extra = (whole.label == 0) & (plain.label < 0)
    rows, cols = np.nonzero(extra)
    assert len(rows) > 150
    assert np.isin(cols % tile, (0, tile - 1)).sum() > 20  # cells on both sides of several tile borders
    # Hand-worked bound: weak_reach / 0.4 m cells along the chain from each dense end (20 m, 40 m).
    strip_row, _, _ = whole.cell_of(np.array([[0.0, 5.0]]))
    _, mid, _ = whole.cell_of(np.array([[30.0, 5.0]]))
    _, near_left, _ = whole.cell_of(np.array([[20.0 + weak_reach - 1.0, 5.0]]))
    assert whole.label[strip_row[0], near_left[0]] == 0
    assert (whole.label[strip_row[0], mid[0]] == 0) == middle_labelled
    # Cores were computed in windows open on their sides (a first-column core's window ends at
    # tile + margin < W), not in the whole grid.
    assert stats.windows >= 8 and tile + stats.max_margin < whole.shape[1]


def test_an_unbounded_hysteresis_builds_the_grid_in_one_piece_and_says_why():
    points, terrain = sparsely_labelled_strip()
    args: dict[str, Any] = {
        "cell_size": 0.4,
        "support_radius": 0.8,
        "fill_radius": 0.0,
        "weak_support": 0.1,
        "weak_reach": None,
    }
    stats = TiledGridStats()
    tiled = build_terrain_grid_tiled(points, terrain, **args, tile=20, margin=4, stats=stats)
    whole = build_terrain_grid(points, terrain, **args)
    assert_same_grid(tiled, whole, points)
    assert stats.windows == 0 and stats.one_piece is not None and "weak_reach is null" in stats.one_piece


# --------------------------------------------------------------------------- the scene graph


def test_tiled_build_equals_the_one_piece_build_on_the_small_campus(small_graph_bundle):
    from terra.mapping.storage import load_map

    one_piece = load_scene_graph(small_graph_bundle)  # built with default tiles: the small grid is one tile
    config = BuildConfig.model_validate({"tiles": {"size": 60.0, "overlap": 10.0}})
    build = build_scene_graph(load_map(small_graph_bundle), config)
    tiled = build.graph
    assert (
        build.stats.gvd_tiles is not None and build.stats.gvd_tiles.windows >= 9
    )  # a 150 m campus in 60 m tiles: at least 3 x 3 per terrain
    assert np.array_equal(tiled.places.position, one_piece.places.position)
    assert np.array_equal(tiled.places.terrain, one_piece.places.terrain)
    assert np.array_equal(tiled.place_edges, one_piece.place_edges)
    assert np.array_equal(tiled.place_edge_kind, one_piece.place_edge_kind)
    assert np.array_equal(tiled.place_edge_weight, one_piece.place_edge_weight)
    assert len(tiled.regions) == len(one_piece.regions)
    for level in range(1, len(one_piece.regions) + 1):
        assert np.array_equal(tiled.place_region(level), one_piece.place_region(level))
