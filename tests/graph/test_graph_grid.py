"""The terrain grid's class per cell: sparsely labelled stretches of a strip (hysteresis) on hand-made ground."""

from __future__ import annotations

import numpy as np
import pytest

from terra.graph.grid import build_terrain_grid
from tests.graph.fixtures import label_parts

SIDEWALK, GRASS = 0, 1
EIGHT = np.ones((3, 3), dtype=bool)


def lattice(x0: float, x1: float, y0: float, y1: float, step: float = 0.2) -> np.ndarray:
    """(n, 3) ground points (z = 0) on a lattice over [x0, x1) x [y0, y1), metres."""
    xs, ys = np.meshgrid(np.arange(x0, x1, step) + step / 2, np.arange(y0, y1, step) + step / 2)
    return np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])


def sparse_labels(points: np.ndarray, terrain: int, every: float = 2.0, width: float = 0.2) -> np.ndarray:
    """Per point: `terrain` on thin columns every `every` metres (what one glancing camera view
    labels), -1 elsewhere (ground only the LiDAR saw)."""
    on = np.mod(points[:, 0], every) < width
    return np.where(on, terrain, -1)


def strip_scene() -> tuple[np.ndarray, np.ndarray]:
    """A 3 m wide sidewalk along x: densely labelled on [0, 15) and [30, 40), labelled only on thin
    columns on [15, 30); beyond it, [40, 50) ground with a few grass columns (one mislabelled view)
    that joins no densely labelled grass."""
    dense_a, sparse, dense_b, stray = (
        lattice(0, 15, 0, 3),
        lattice(15, 30, 0, 3),
        lattice(30, 40, 0, 3),
        lattice(40, 50, 0, 3),
    )
    points = np.vstack([dense_a, sparse, dense_b, stray])
    terrain = np.concatenate(
        [
            np.full(len(dense_a), SIDEWALK),
            sparse_labels(sparse, SIDEWALK),
            np.full(len(dense_b), SIDEWALK),
            sparse_labels(stray, GRASS),
        ]
    )
    return points, terrain


def label_at(grid, x: float, y: float) -> int:
    rows, cols, _ = grid.cell_of(np.array([[x, y]]))
    return int(grid.label[rows[0], cols[0]])


def sidewalk_pieces(grid) -> int:
    return int(label_parts(grid.label == SIDEWALK, EIGHT)[1])


def test_a_sparsely_labelled_stretch_continues_the_strip_it_joins():
    points, terrain = strip_scene()
    # The window majority needs 60 % of a 3.6 m window labelled: the columns (1 in 10 of the
    # points) are far below that, so without hysteresis the strip breaks in two.
    plain = build_terrain_grid(
        points, terrain, support_radius=1.6, min_support=0.6, fill_radius=0.0, obstacle_height=None
    )
    assert label_at(plain, 22.5, 1.5) == -1
    assert sidewalk_pieces(plain) == 2
    grid = build_terrain_grid(
        points, terrain, support_radius=1.6, min_support=0.6, fill_radius=0.0, obstacle_height=None, weak_support=0.1
    )
    assert label_at(grid, 22.5, 1.5) == SIDEWALK
    assert sidewalk_pieces(grid) == 1
    # The densely labelled cells are the same either way.
    strong = plain.label >= 0
    assert np.array_equal(grid.label[strong], plain.label[strong])


def test_a_sparse_patch_that_continues_no_dense_patch_stays_unlabelled():
    points, terrain = strip_scene()
    grid = build_terrain_grid(
        points, terrain, support_radius=1.6, min_support=0.6, fill_radius=0.0, obstacle_height=None, weak_support=0.1
    )
    # The stray grass columns touch the sidewalk's end but no grass that meets min_support: they
    # take neither grass (not anchored) nor sidewalk (not their majority).
    assert label_at(grid, 46.0, 1.5) == -1
    assert not (grid.label == GRASS).any()


def test_weak_support_at_or_above_min_support_changes_nothing():
    points, terrain = strip_scene()
    plain = build_terrain_grid(points, terrain, fill_radius=0.0, obstacle_height=None)
    same = build_terrain_grid(points, terrain, fill_radius=0.0, obstacle_height=None, weak_support=0.6)
    assert np.array_equal(plain.label, same.label)


def test_hysteresis_does_not_cross_a_blocked_cell_band():
    # A wall of obstacle points across the sparse stretch (x = 22 m): its cells are blocked, so
    # the stretch beyond it joins the strip only from the far side.
    points, terrain = strip_scene()
    wall = lattice(21.8, 22.6, -1, 4)
    wall = np.vstack([wall + [0, 0, 0.8], wall + [0, 0, 1.2]])
    grid = build_terrain_grid(
        np.vstack([points, wall]), np.concatenate([terrain, np.full(len(wall), -1)]), fill_radius=0.0, weak_support=0.1
    )
    assert label_at(grid, 22.2, 1.5) == -1
    assert label_at(grid, 18.0, 1.5) == SIDEWALK and label_at(grid, 27.0, 1.5) == SIDEWALK
    assert sidewalk_pieces(grid) == 2


def test_weak_reach_bounds_how_far_a_strip_is_carried_into_sparse_ground():
    # The sparse stretch [15, 30) is 15 m long; carried at most 4 m from each densely labelled
    # end (8-connected steps of one 0.4 m cell), its middle stays unlabelled.
    points, terrain = strip_scene()
    grid = build_terrain_grid(points, terrain, fill_radius=0.0, obstacle_height=None, weak_support=0.1, weak_reach=4.0)
    assert label_at(grid, 17.0, 1.5) == SIDEWALK and label_at(grid, 28.0, 1.5) == SIDEWALK
    assert label_at(grid, 22.5, 1.5) == -1
    assert sidewalk_pieces(grid) == 2
    # 8 m from each end covers it.
    grid = build_terrain_grid(points, terrain, fill_radius=0.0, obstacle_height=None, weak_support=0.1, weak_reach=8.0)
    assert sidewalk_pieces(grid) == 1


def test_ground_only_the_lidar_saw_keeps_its_own_height():
    # A densely labelled sidewalk at 0 m on [0, 15) continues on [15, 17) as ground only the LiDAR
    # saw, 0.25 m lower (a ramp down the camera missed); filling labels it sidewalk. Its ground is
    # the mean of its own points, not the height of the nearest labelled cell (0 m at x = 15).
    labelled, lidar_only = lattice(0, 15, 0, 6), lattice(15, 17, 0, 6)
    lidar_only[:, 2] = -0.25
    points = np.vstack([labelled, lidar_only])
    terrain = np.concatenate([np.full(len(labelled), SIDEWALK), np.full(len(lidar_only), -1)])
    grid = build_terrain_grid(points, terrain, fill_radius=2.0, obstacle_height=(0.3, 2.0))
    assert label_at(grid, 15.6, 3.0) == SIDEWALK and label_at(grid, 16.0, 3.0) == SIDEWALK
    rows, cols, _ = grid.cell_of(np.array([[16.0, 3.0], [5.0, 3.0], [16.0, 6.8]]))
    # The last cell (beyond y = 6 m) holds no point: it takes the nearest scanned cell's height.
    assert grid.ground[rows, cols] == pytest.approx([-0.25, 0.0, -0.25], abs=1e-6)


def voxel_centres(x0: float, x1: float, y0: float, y1: float, voxel: float = 0.4) -> np.ndarray:
    """(n, 3) ground points (z = 0), one at the centre of every `voxel` square over [x0, x1) x
    [y0, y1): what the map holds (one point per 0.4 m voxel) where the LiDAR scanned densely."""
    return lattice(x0, x1, y0, y1, voxel)


def strip_beside_rings() -> tuple[np.ndarray, np.ndarray]:
    """A densely scanned 40 x 4 m strip of grass, and beside it 40 x 30 m of distant ground the
    LiDAR saw only on scan rings: one row of voxels in three (a third of its area holds points)."""
    strip = voxel_centres(0, 40, 0, 4)
    far = voxel_centres(0, 40, 4, 34)
    far = far[np.round((far[:, 1] - 4.2) / 0.4).astype(int) % 3 == 0]
    points = np.vstack([strip, far])
    return points, np.full(len(points), GRASS)


CELL_SIZES = (0.2, 0.4, 0.5, 0.6, 0.8, 1.0, 1.2)


@pytest.mark.parametrize("cell_size", CELL_SIZES)
def test_coverage_counts_the_same_square_metres_at_every_cell_size(cell_size):
    """The occupied 0.4 m squares of the rings cover 40 m x 0.4 m per ring, 25 rings: 400 m^2,
    whatever cells they are counted in."""
    from terra.graph.grid import cell_coverage, empty_grid, grid_frame

    points, terrain = strip_beside_rings()
    far = points[points[:, 1] > 4]
    grid = empty_grid(grid_frame(points, terrain, cell_size))
    covered = cell_coverage(grid, far, 0.4)
    assert float(covered.sum()) * cell_size**2 == pytest.approx(25 * 40 * 0.4, rel=1e-6)
    assert float(covered.max()) <= 1.0


def test_sparse_rings_stay_unlabelled_and_places_do_not_grow_with_the_cell_size():
    """min_support is a share of the window's area: the rings (a third of it) never reach 0.6, the
    strip (all of it) always does. Counted in whole cells, from 0.8 m cells on every cell of the
    ring ground held a point and it became a 1,200 m^2 field of places (5 places at 0.4 m, 17 at
    0.8 m); at 0.2 m cells no cell of the strip had the support (0 places)."""
    from terra.graph.config import BuildConfig
    from terra.graph.pipeline import terrain_grid, terrain_places

    points, terrain = strip_beside_rings()
    counts = []
    for cell_size in CELL_SIZES:
        config = BuildConfig.model_validate({"grid": {"cell_size": cell_size}})
        grid = terrain_grid(points, terrain, config)
        area = float((grid.label == GRASS).sum()) * cell_size**2
        assert 0.8 * 160 <= area <= 1.2 * 160, (cell_size, area)  # the 40 x 4 m strip, edges within a window
        assert label_at(grid, 20, 20) == -1 and label_at(grid, 20, 2) == GRASS
        places, _, _ = terrain_places(grid, [GRASS], config)
        counts.append(len(places.position))
    assert counts[0] > 0
    assert all(b <= a for a, b in zip(counts, counts[1:])), counts
