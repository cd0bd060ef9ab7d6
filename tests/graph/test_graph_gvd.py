"""GVD and place extraction on hand-made grids, checked against hand-worked geometry."""

from typing import Any

import numpy as np
import pytest
from scipy import ndimage

from terra.graph.gvd import brushfire, gvd
from terra.graph.places import chord_blocked, extract_places, split_path
from terra.graph.skeleton import prune_spurs, skeleton_graph
from terra.graph.thinning import thin
from tests.graph.fixtures import label_parts

# Cells, not metres: the extraction parameters the pipeline would derive at 0.4 m cells.
PARAMS: dict[str, Any] = dict(
    min_clearance=1.0,
    min_gap=1.5,
    prune_ratio=1.5,
    prune_length=2.5,
    junction_merge=1.0,
    max_deviation=9.4,
    max_distance=25.0,
)


def corridor(width=11, length=60, margin=5):
    free = np.zeros((width + 2 * margin, length + 2 * margin), bool)
    free[margin : margin + width, margin : margin + length] = True
    return free


def plus(arm=25, width=9, margin=5):
    n = 2 * arm + width + 2 * margin
    free = np.zeros((n, n), bool)
    c0 = margin + arm
    free[c0 : c0 + width, margin : n - margin] = True
    free[margin : n - margin, c0 : c0 + width] = True
    return free, c0 + width // 2


def two_rooms(size=31, door=3, wall=3, margin=5):
    """Two square rooms side by side; the wall between them (columns wall_cols) has a door."""
    free = np.zeros((size + 2 * margin, 2 * size + wall + 2 * margin), bool)
    free[margin : margin + size, margin : margin + size] = True
    free[margin : margin + size, margin + size + wall : margin + 2 * size + wall] = True
    door_rows = np.arange(margin + size // 2 - door // 2, margin + size // 2 - door // 2 + door)
    wall_cols = np.arange(margin + size, margin + size + wall)
    free[np.ix_(door_rows, wall_cols)] = True
    return free, door_rows, wall_cols


def pruned_graph(free):
    skeleton, distance = gvd(free, PARAMS["min_clearance"], PARAMS["min_gap"])
    skeleton = prune_spurs(skeleton, distance, PARAMS["prune_ratio"], PARAMS["prune_length"])
    return skeleton, skeleton_graph(skeleton, distance)


def test_brushfire_matches_brute_force_nearest_obstacle():
    rng = np.random.default_rng(3)
    free = np.asarray(ndimage.binary_opening(rng.random((24, 31)) < 0.7), dtype=bool)
    fire = brushfire(free)
    rows, cols = np.nonzero(free)
    # Obstacles: the non-free cells plus the frame just outside the grid.
    obst = np.argwhere(np.pad(~free, 1, constant_values=True)) - 1
    d = np.sqrt(((np.stack([rows, cols], 1)[:, None, :] - obst[None, :, :]) ** 2).sum(-1))
    assert np.allclose(fire.distance[rows, cols], d.min(axis=1))
    parent = np.stack([fire.parent[0][rows, cols], fire.parent[1][rows, cols]], 1)
    assert np.allclose(np.sqrt(((parent - np.stack([rows, cols], 1)) ** 2).sum(1)), d.min(axis=1))
    assert (fire.distance[~free] == 0).all()


def test_thinning_equals_scikit_image():
    skimage_morphology = pytest.importorskip("skimage.morphology")
    rng = np.random.default_rng(0)
    for _ in range(4):
        mask = ndimage.binary_opening(rng.random((90, 120)) < 0.65)
        assert np.array_equal(thin(mask), skimage_morphology.thin(mask))


def test_straight_corridor_gives_one_path_on_its_centre_line():
    free = corridor(width=11, length=60, margin=5)
    centre_row = 5 + 11 // 2
    skeleton, graph = pruned_graph(free)
    cells = np.argwhere(skeleton)
    assert (cells[:, 0] == centre_row).all()
    assert cells[:, 1].max() - cells[:, 1].min() >= 60 - 11  # spans the corridor but its ends
    assert len(graph.edges) == 1 and sorted(graph.degree()) == [1, 1]
    places = extract_places(free, **PARAMS)
    assert (places.cells[:, 0] == centre_row).all()
    # One chain: P places, P - 1 edges, each no longer than max_distance.
    assert len(places.edges) == len(places.cells) - 1
    assert (places.length <= PARAMS["max_distance"] + 1e-9).all()
    assert np.isclose(places.length.sum(), cells[:, 1].max() - cells[:, 1].min())
    assert np.allclose(places.clearance, 6.0)  # centre of an 11-cell corridor: 6 cells to a wall


def test_plus_shaped_corridor_gives_exactly_one_junction():
    free, centre = plus(arm=25, width=9)
    _, graph = pruned_graph(free)
    degree = graph.degree()
    junctions = np.flatnonzero(degree >= 3)
    assert len(junctions) == 1 and degree[junctions[0]] == 4
    assert tuple(graph.node_cell[junctions[0]]) == (centre, centre)
    ends = graph.node_cell[degree == 1]
    assert len(ends) == 4
    # Each dead end lies on an arm's centre line, far out along it.
    for r, c in ends:
        assert (r == centre and abs(c - centre) > 20) or (c == centre and abs(r - centre) > 20)


def test_two_rooms_joined_by_a_door_give_one_edge_through_it():
    free, door_rows, wall_cols = two_rooms()
    skeleton, _ = pruned_graph(free)
    in_wall = np.argwhere(skeleton[:, wall_cols[0] : wall_cols[-1] + 1])
    assert len(in_wall) == len(wall_cols) and np.isin(in_wall[:, 0], door_rows).all()
    # Paths up to 40 cells stay unsplit, so no place falls inside the doorway itself.
    places = extract_places(free, **{**PARAMS, "max_distance": 40.0})
    assert not np.isin(places.cells[:, 1], wall_cols).any()
    side = places.cells[:, 1] > wall_cols.mean()
    crossing = side[places.edges[:, 0]] != side[places.edges[:, 1]]
    assert crossing.sum() == 1
    assert side.any() and (~side).any()


def test_gvd_loops_around_an_obstacle_island():
    free = np.zeros((60, 60), bool)
    free[5:55, 5:55] = True
    free[25:35, 25:35] = False  # an island: its own obstacle component
    _, graph = pruned_graph(free)
    assert len(graph.edges) >= len(graph.node_cell)  # a cycle exists
    places = extract_places(free, **PARAMS)
    centre = np.array([29.5, 29.5])
    angles = np.arctan2(*(places.cells - centre).T)
    assert np.ptp(angles) > 1.5 * np.pi  # places surround the island
    r = np.linalg.norm(places.cells - centre, axis=1)
    assert (r > 5).all() and (r < 25 * np.sqrt(2)).all()


def test_every_patch_without_gvd_gets_one_place_at_its_largest_clearance():
    free = np.zeros((40, 40), bool)
    free[5:10, 5:10] = True  # a 5x5 patch: its GVD is pruned to nothing but a point
    free[20:35, 20:23] = True
    places = extract_places(free, **PARAMS)
    labels, n = label_parts(free)
    assert set(labels[places.cells[:, 0], places.cells[:, 1]]) == {1, 2}
    small = places.cells[labels[places.cells[:, 0], places.cells[:, 1]] == 1]
    assert len(small) == 1 and tuple(small[0]) == (7, 7)


def test_split_path_follows_the_max_distance_and_max_deviation_rules():
    straight = np.stack([np.zeros(101, int), np.arange(101)], axis=1)
    cuts = split_path(straight, max_deviation=3.0, max_distance=25.0)
    assert cuts == [25, 50, 75]
    # An L: one leg of 40 cells down, one of 40 across; the corner deviates ~28 cells from the chord.
    ell = np.vstack([np.stack([np.arange(40), np.zeros(40, int)], 1), np.stack([np.full(41, 40), np.arange(41)], 1)])
    cuts = split_path(ell, max_deviation=3.0, max_distance=1000.0)
    assert cuts == [40]


def test_a_chord_across_an_obstacle_is_split_whatever_its_deviation():
    # A path along row 10 bowing 4 rows round a bench (rows 9-11, cols 18-22): the chord from end
    # to end runs through the bench, well within max_deviation of the path.
    cols = np.arange(41)
    rows = 10 + np.clip(8 - np.abs(cols - 20), 0, 4)
    path = np.column_stack([rows, cols])
    bench = np.zeros((30, 50), bool)
    bench[9:12, 18:23] = True
    assert not bench[path[:, 0], path[:, 1]].any()  # the path itself goes round it
    assert split_path(path, max_deviation=9.4, max_distance=100.0) == []
    cuts = split_path(path, max_deviation=9.4, max_distance=100.0, obstacles=bench)
    assert cuts
    ends = [0, *cuts, len(path) - 1]
    pieces = zip(path[ends[:-1]].astype(float), path[ends[1:]].astype(float))
    assert not any(chord_blocked(bench, a, b) for a, b in pieces)
    assert chord_blocked(bench, np.array([10.0, 0.0]), np.array([10.0, 40.0]))


def test_no_place_edge_runs_through_an_obstacle_the_gvd_goes_round():
    """A 13-cell corridor with a bench 3 cells wide beside its centre line: the GVD bows round it
    within max_deviation, so without the obstacle rule one chord ran straight through the bench."""
    free = corridor(width=13, length=80)
    bench = np.zeros_like(free)
    bench[10:13, 40:46] = True  # rows 10-12 of the corridor's 5-17, off its centre row 11
    plain = extract_places(free & ~bench, **{**PARAMS, "max_distance": 100.0})
    chords = [(plain.cells[i].astype(float), plain.cells[j].astype(float)) for i, j in plain.edges]
    assert any(chord_blocked(bench, a, b) for a, b in chords)
    places = extract_places(free & ~bench, **{**PARAMS, "max_distance": 100.0}, obstacles=bench)
    chords = [(places.cells[i].astype(float), places.cells[j].astype(float)) for i, j in places.edges]
    assert not any(chord_blocked(bench, a, b) for a, b in chords)
    assert len(places.cells) > len(plain.cells)


def test_a_small_plaza_off_a_road_gets_a_place():
    """A 10 m road (25 cells) with a 12 m x 5.6 m pad beside it, like a service yard off a street:
    the GVD branches into the pad are pruned as corner spurs, so without the pocket rule no place
    lies in it; with it (5 m = 12.5 cells) the pad holds a place joined to the road's places, and
    only the branches reaching beyond 5 m from the kept GVD come back."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    free = np.zeros((60, 130), bool)
    free[30:55, 5:125] = True
    free[16:30, 50:80] = True
    in_pad = lambda cells: (cells[:, 0] < 30) & (cells[:, 1] >= 50) & (cells[:, 1] < 80)  # noqa: E731
    plain = extract_places(free, **PARAMS)
    assert not in_pad(plain.cells).any()
    covered = extract_places(free, **PARAMS, cover_radius=12.5)
    assert in_pad(covered.cells).any()
    assert all(free[r, c] for r, c in covered.cells)
    n = len(covered.cells)
    graph = sp.coo_matrix((np.ones(len(covered.edges)), (covered.edges[:, 0], covered.edges[:, 1])), shape=(n, n))
    assert connected_components(graph, directed=False)[0] == 1
    # Sparse elsewhere: a few pocket and corner places, not a grid of them.
    assert n <= len(plain.cells) + 6


def test_pieces_of_one_patch_are_joined_through_it():
    """A corridor with a one-cell neck (narrower than the minimum clearance): its GVD breaks in two
    pieces, which are joined along the shortest path through the neck."""
    free = corridor(width=11, length=80)
    free[5:16, 45] = False
    free[10, 45] = True  # the neck
    places = extract_places(free, **PARAMS)
    n = len(places.cells)
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    graph = sp.coo_matrix((np.ones(len(places.edges)), (places.edges[:, 0], places.edges[:, 1])), shape=(n, n))
    assert connected_components(graph, directed=False)[0] == 1
    # The join runs through the neck: its length is at least the straight distance between its ends.
    gap = np.linalg.norm(np.diff(places.cells[places.edges].astype(float), axis=1)[:, 0], axis=1)
    assert np.all(places.length >= gap - 1e-9)
