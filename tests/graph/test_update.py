"""Incremental graph updates (terra.graph.update): what counts as changed, the rebuilt area on the
tile lattice, and a hand-made two-part map (tests/graph/test_ids_rebuild.py) whose second version
changes only the east patch: the west places keep their ids, positions and edges exactly, the east
patch is rebuilt to the places a full build gives, and the closing full update is the full build."""

from __future__ import annotations

import numpy as np
import pytest

from terra.graph.config import BuildConfig
from terra.graph.pipeline import build_scene_graph
from terra.graph.update import GraphUpdater, changed_points, map_digest, tile_zone
from tests.graph.test_ids_rebuild import WEST_END, two_part_map


def test_changed_points_are_the_added_removed_moved_and_reclassed():
    before = np.array([[0.1, 0.1, 0.0], [1.1, 0.1, 0.0], [2.1, 0.1, 0.0], [3.1, 0.1, 0.0], [4.1, 0.1, 0.0]])
    terrain_before = np.array([0, 0, 1, 1, -1])
    after = np.array(
        [
            [0.1, 0.1, 0.0],  # the same
            [1.12, 0.1, 0.0],  # moved 2 cm: below the tolerance
            [2.2, 0.1, 0.0],  # moved 10 cm
            [3.1, 0.1, 0.0],  # re-classed 1 -> 0
            [5.1, 0.1, 0.0],  # added; the point at x = 4.1 is gone
        ]
    )
    terrain_after = np.array([0, 0, 1, 0, 0])
    old, new = map_digest(before, terrain_before, 0.05), map_digest(after, terrain_after, 0.05)
    changed = changed_points(old, new)
    # A moved or re-classed point counts where it was and where it is.
    assert sorted(changed[:, 0].round(3).tolist()) == [2.1, 2.2, 3.1, 3.1, 4.1, 5.1]
    assert len(changed_points(new, new)) == 0
    # Several points in one voxel (a prior map, a synthetic one) are told apart by position.
    twice = np.vstack([before, before + [0.2, 0.0, 0.0]])
    moved = twice.copy()
    moved[-1, 0] += 0.1
    both = np.concatenate([terrain_before, terrain_before])
    changed = changed_points(map_digest(twice, both, 0.05), map_digest(moved, both, 0.05))
    assert sorted(changed[:, 0].round(3).tolist()) == [4.3, 4.4]


def test_the_zone_is_the_changed_tiles_grown_with_a_crop_around_each_part():
    config = BuildConfig.model_validate(
        {"update": {"tile": 10.0, "replace_margin": 5.0, "context_margin": 3.0, "min_changed_points": 2}}
    )
    # Two changed points in tile (2, 1) and one alone in tile (9, 9): the lone one is too few.
    changed = np.array([[21.0, 11.0], [25.0, 15.0], [95.0, 95.0]])
    zone = tile_zone(changed, config)
    assert zone is not None
    # Tile (2, 1) grown by one tile (5 m rounds up to a tile): tiles 1..3 x 0..2, 9 tiles.
    assert zone.area == pytest.approx(900.0)
    assert zone.in_zone(np.array([[10.5, 0.5], [39.5, 29.5]])).tolist() == [True, True]
    assert zone.in_zone(np.array([[9.5, 5.0], [40.5, 5.0], [95.0, 95.0]])).tolist() == [False, False, False]
    assert zone.crops == [(7.0, -3.0, 43.0, 33.0)]
    # Within embedding.max_range (20 m = 2 tiles) of the zone, and not beyond.
    assert zone.near_zone(np.array([[-9.5, 5.0], [59.5, 5.0], [60.5, 5.0]])).tolist() == [True, True, False]
    assert tile_zone(changed[2:], config) is None


UPDATE = {"tile": 10.0, "replace_margin": 0.0, "context_margin": 20.0, "min_changed_points": 1}


@pytest.fixture(scope="module")
def updates(text_embedder):
    """Updater over the grass-east version, then the asphalt-east one; and the full builds."""
    config = BuildConfig.model_validate({"update": UPDATE})
    first_map = two_part_map(text_embedder, "grass", 30.0)
    second_map = two_part_map(text_embedder, "asphalt", 15.0)
    for msm in (first_map, second_map):
        # Off the cell boundaries: a point exactly on one falls on either side by the last bit of
        # the grid's origin, which a crop's grid has elsewhere (real scans are never that exact).
        msm.points = msm.points + np.float32(0.05)
    updater = GraphUpdater(config)
    first = updater.update(first_map)
    second = updater.update(second_map)
    same = updater.update(second_map)
    closing = updater.update(second_map, full=True)
    full = build_scene_graph(second_map, config).graph
    return first, second, same, closing, full


def _west(graph) -> np.ndarray:
    return graph.places.position[:, 0] < WEST_END


def test_a_first_update_is_a_full_build_then_only_the_changed_part_is_rebuilt(updates):
    first, second, same, _, _ = updates
    assert first.update.kind == "full"
    assert second.update.kind == "incremental"
    assert second.update.places_kept == int(_west(first.graph).sum())
    # The east patch (x 70..100 before, 70..85 now) is the zone; nothing west of 60 m is in it.
    assert 0 < second.update.zone_area <= 40.0 * 10.0
    assert same.update.kind == "incremental" and same.update.reason == "nothing changed"
    assert same.graph is second.graph


def test_places_away_from_the_change_keep_ids_positions_and_edges(updates):
    first, second, _, _, _ = updates
    a, b = first.graph, second.graph
    west_a, west_b = np.flatnonzero(_west(a)), np.flatnonzero(_west(b))
    assert len(west_a) >= 5
    np.testing.assert_array_equal(b.places.id[west_b], a.places.id[west_a])
    np.testing.assert_array_equal(b.places.position[west_b], a.places.position[west_a])
    np.testing.assert_array_equal(b.places.embedding[west_b], a.places.embedding[west_a])

    def west_edges(graph, index):
        ids = graph.places.id
        inside = set(index.tolist())
        return sorted(
            (int(min(ids[i], ids[j])), int(max(ids[i], ids[j])))
            for i, j in graph.place_edges
            if i in inside and j in inside
        )

    assert west_edges(b, west_b) == west_edges(a, west_a)
    # New places take fresh ids above every id given before.
    east_b = np.flatnonzero(~_west(b))
    assert len(east_b) >= 1 and b.places.id[east_b].min() >= a.next_ids()["p"]


def test_the_rebuilt_part_has_the_places_of_a_full_build(updates):
    _, second, _, _, full = updates
    inc = second.graph

    def east(graph):
        keep = ~_west(graph)
        order = np.lexsort(graph.places.position[keep].T[::-1])
        return graph.places.position[keep][order], graph.places.terrain[keep][order]

    np.testing.assert_allclose(east(inc)[0], east(full)[0], atol=1e-9)
    np.testing.assert_array_equal(east(inc)[1], east(full)[1])
    # One connected graph, as the full build's.
    import scipy.sparse.csgraph as csgraph

    assert csgraph.connected_components(inc.place_adjacency(), directed=False)[0] == 1


def test_the_closing_full_update_is_the_full_build(updates):
    _, second, _, closing, full = updates
    assert closing.update.kind == "full"
    np.testing.assert_array_equal(closing.graph.places.position, full.places.position)
    np.testing.assert_array_equal(closing.graph.place_edges, full.place_edges)
    np.testing.assert_array_equal(closing.graph.place_edge_weight, full.place_edge_weight)
    for level in range(1, len(full.regions) + 1):
        np.testing.assert_array_equal(closing.graph.place_region(level), full.place_region(level))
    # ... with the ids of the incremental graph it replaces.
    kept = np.isin(closing.graph.places.id, second.graph.places.id)
    assert kept[_west(closing.graph)].all()
