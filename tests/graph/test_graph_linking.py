"""Cross-terrain links of dead ends and penalised bridges between components, on hand-placed nodes."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from terra.graph.linking import bridge_components, grid_line_clear, grid_line_crosses, link_across, link_dead_ends


def xy(*points):
    return np.array([[x, y, 0.0] for x, y in points])


# Terrain 0: a chain 0-1-2 along y = 0; terrain 1: three lone places.
POSITION = xy((0, 0), (10, 0), (20, 0), (25, 0), (22, 15), (100, 0))
TERRAIN = np.array([0, 0, 0, 1, 1, 1])
EDGES = np.array([[0, 1], [1, 2]])


def test_places_link_to_the_nearest_place_across_a_line():
    # A line of cells along y = 1.6..2.0 m (row 4 of a 0.4 m grid) from x = 0 to 8 m; places A
    # (1, 0) and C (5, 0) below it, B (1, 3) above it, D (20, 3) above it but past its end.
    line = np.zeros((10, 60), dtype=bool)
    line[4, :20] = True
    position = xy((1, 0), (1, 3), (5, 0), (20, 3))
    across = grid_line_crosses(line, np.zeros(2), 0.4)
    links, length = link_across(position, max_distance=6.0, candidates=8, across=across)
    # A's nearest is B (3 m, across); C's nearest across is B (5 m; A, 4 m away, is on its side);
    # B's is A; D crosses nothing within 6 m (C's line to it, 15.3 m, is too long anyway).
    assert links.tolist() == [[0, 1], [1, 2]]
    assert np.allclose(length, [3.0, 5.0])
    assert link_across(position, 2.0, 8, across)[0].shape == (0, 2)  # nothing across within 2 m


def test_dead_ends_link_to_the_nearest_other_terrain_place_within_the_bound():
    links, length = link_dead_ends(POSITION, TERRAIN, EDGES, max_distance=20.0)
    # 2 -> 3 (5 m); 3 -> 2 (the same link); 4 -> 2 (15.1 m); 0 has nothing within 20 m (25 m to
    # place 3) and 5 is 80 m from everything; 1 is not a dead end.
    assert links.tolist() == [[2, 3], [2, 4]]
    assert np.allclose(length, [5.0, np.hypot(2, 15)])
    wider, _ = link_dead_ends(POSITION, TERRAIN, EDGES, max_distance=26.0)
    assert [0, 3] in wider.tolist() and not (wider == 1).any()


def test_a_link_needs_a_clear_line_and_falls_back_to_the_next_candidate():
    def not_to_place_3(a, b):
        return ~(np.all(np.isclose(a, [25, 0]), axis=1) | np.all(np.isclose(b, [25, 0]), axis=1))

    links, _ = link_dead_ends(POSITION, TERRAIN, EDGES, max_distance=20.0, clear=not_to_place_3)
    assert links.tolist() == [[2, 4]]  # 2's nearest (3) is blocked; 4 is its next candidate


def test_grid_line_clear_only_crosses_traversable_cells():
    traversable = np.ones((10, 20), bool)
    traversable[:, 10] = False  # a wall at x in [5, 5.5) with 0.5 m cells
    clear = grid_line_clear(traversable, origin=np.zeros(2), cell_size=0.5)
    a = np.array([[1.0, 1.0], [1.0, 1.0], [6.0, 4.0]])
    b = np.array([[4.0, 4.0], [8.0, 1.0], [9.0, 1.0]])
    assert clear(a, b).tolist() == [True, False, True]
    assert not clear(np.array([[1.0, 1.0]]), np.array([[30.0, 1.0]]))[0]  # leaves the grid


def test_bridges_connect_every_component_with_the_penalty_where_blocked():
    position = xy((0, 0), (10, 0), (20, 0), (100, 0), (110, 0), (120, 0), (300, 0))
    edges = np.array([[0, 1], [1, 2], [3, 4], [4, 5]])
    pairs, cost, clear = bridge_components(position, edges, penalty=100.0)
    assert sorted(map(tuple, pairs.tolist())) == [(2, 3), (5, 6)]
    assert np.allclose(sorted(cost), [80.0, 180.0]) and clear.all()
    blocked, blocked_cost, blocked_clear = bridge_components(
        position, edges, penalty=100.0, clear=lambda a, b: np.zeros(len(a), bool)
    )
    assert sorted(map(tuple, blocked.tolist())) == [(2, 3), (5, 6)]
    assert np.allclose(sorted(blocked_cost), [8000.0, 18000.0]) and not blocked_clear.any()
    # Nothing is dropped: every place is in the one resulting component.
    all_edges = np.vstack([edges, pairs])
    graph = sp.coo_matrix((np.ones(len(all_edges)), tuple(all_edges.T)), shape=(7, 7))
    assert connected_components(graph, directed=False)[0] == 1


def test_many_components_are_joined_in_few_rounds():
    rng = np.random.default_rng(0)
    position = np.column_stack([rng.uniform(0, 1000, size=(300, 2)), np.zeros(300)])
    pairs, cost, _ = bridge_components(position, np.zeros((0, 2), np.int64), penalty=10.0)
    assert len(pairs) == 299  # a spanning forest: exactly components - 1 bridges
    graph = sp.coo_matrix((np.ones(len(pairs)), tuple(pairs.T)), shape=(300, 300))
    assert connected_components(graph, directed=False)[0] == 1
    # Boruvka with nearest neighbours gives the Euclidean minimum spanning tree.
    from scipy.sparse.csgraph import minimum_spanning_tree
    from scipy.spatial.distance import pdist, squareform

    mst = minimum_spanning_tree(squareform(pdist(position[:, :2])))
    assert np.isclose(cost.sum(), mst.sum())
