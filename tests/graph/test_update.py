"""Incremental graph updates (terra.graph.update): what counts as changed, the rebuilt area on the
tile lattice, and a hand-made two-part map (tests/graph/test_ids_rebuild.py) whose second version
changes only the east patch: the west places keep their ids, positions and edges exactly, the east
patch is rebuilt to the places a full build gives, and the closing full update is the full build."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from terra.graph.config import BuildConfig
from terra.graph.pipeline import build_scene_graph
from terra.graph.update import GraphUpdater, changed_points, map_digest, next_digest, point_hashes, tile_zone
from terra.live import Session
from terra.mapping.semantic_map import FusionRows, ImageTable, MetricSemanticMap, terrain_winners
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


def test_two_versions_of_one_fusion_are_compared_row_by_row_as_by_search():
    """A fusion appends rows and lists them in voxel order: the row-paired comparison gives the
    changed points the sorted search gives, whatever order each version lists its points in."""
    rng = np.random.default_rng(3)
    before = rng.uniform(0.0, 50.0, (400, 3))
    before[40:50] = np.round(before[40:50] / 0.05) * 0.05  # on the step: a 1 cm move stays in its rounding
    terrain_before = rng.integers(-1, 3, 400)
    after = np.vstack([before, rng.uniform(0.0, 50.0, (60, 3))])  # 60 rows appended
    terrain_after = np.concatenate([terrain_before, rng.integers(-1, 3, 60)])
    after[10:30] += [0.2, 0.0, 0.0]  # 20 moved past the step
    after[40:50] += [0.01, 0.0, 0.0]  # 10 moved within it
    terrain_after[60:65] = 5  # 5 re-classed
    # Each version lists its rows in its own order, as fusion.finish lists them by voxel key.
    rows_before, rows_after = rng.permutation(400), rng.permutation(460)
    old = map_digest(before[rows_before], terrain_before[rows_before], 0.05, FusionRows("f", rows_before))
    new = map_digest(after[rows_after], terrain_after[rows_after], 0.05, FusionRows("f", rows_after))
    by_row = changed_points(old, new)
    # Moved and re-classed rows count twice (where they were, where they are), added ones once.
    assert len(by_row) == 2 * 20 + 2 * 5 + 60
    expected = np.vstack([after[10:30, :2], before[10:30, :2], after[60:65, :2], before[60:65, :2], after[400:, :2]])
    np.testing.assert_allclose(np.sort(by_row, axis=0), np.sort(expected, axis=0))
    # Another fusion's map, or no rows: the sorted search, with the same answer.
    other = map_digest(after[rows_after], terrain_after[rows_after], 0.05, FusionRows("g", rows_after))
    plain = map_digest(after[rows_after], terrain_after[rows_after], 0.05)
    for searched in (changed_points(old, other), changed_points(old, plain)):
        np.testing.assert_allclose(np.sort(searched, axis=0), np.sort(by_row, axis=0))


def _drifting_map(
    points: np.ndarray, votes: np.ndarray, serial: int, changed: np.ndarray | list[int]
) -> MetricSemanticMap:
    """A live fusion's map `serial` of points (N, 3) metres listed in row order, whose rows `changed` changed."""
    n = len(points)
    rows = FusionRows("drift", np.arange(n), np.arange(n), serial, np.asarray(changed, dtype=np.int64))
    return MetricSemanticMap(
        points.astype(np.float32),
        ["asphalt", "grass"],
        votes.astype(np.uint16),
        np.zeros((2, 4), np.float32),
        sp.csr_matrix((n, 0), dtype=np.int32),
        np.zeros((0, 4), np.float32),
        ImageTable(np.zeros(0), np.zeros(0, np.int16), np.zeros((0, 4, 4)), np.zeros((0, 4), np.float32)),
        "test",
        fusion_rows=rows,
    )


def test_a_row_counts_as_moved_once_it_is_the_tolerance_from_where_it_last_counted():
    """A voxel mean drifts a little with every scan: it counts as moved when it is more than the
    tolerance from where the digest last counted it (3 cm + 3 cm = 6 cm > 5 cm), not when a 1 cm
    move crosses a rounding boundary of the hash; a re-classed or added row always counts."""
    votes = np.array([[5, 0], [5, 0], [5, 0], [0, 5]])
    start = np.array([[0.0, 0.0, 0.0], [1.024, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    terrain_of = lambda v: terrain_winners(v, 0.5, np.int16)  # noqa: E731
    digest = next_digest(None, _drifting_map(start, votes, 1, np.arange(4)), terrain_of, 0.05)
    second = start + [[0.03, 0.0, 0.0], [0.002, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]  # 1.026 rounds up
    new = next_digest(digest, _drifting_map(second, votes, 2, [0, 1]), terrain_of, 0.05)
    assert len(changed_points(digest, new)) == 0
    assert len(changed_points(map_digest(start, terrain_of(votes), 0.05), map_digest(second, terrain_of(votes), 0.05)))
    third = np.vstack([second + [[0.03, 0.0, 0.0], [0.0] * 3, [0.0] * 3, [0.0] * 3], [[4.0, 0.0, 0.0]]])
    votes3 = np.vstack([votes, [[0, 5]]])
    votes3[2] = [0, 5]  # row 2 re-classed in place
    newer = next_digest(new, _drifting_map(third, votes3, 3, [0, 2, 4]), terrain_of, 0.05)
    # Rows 0 (6 cm from where it counted) and 2 (re-classed) where they were and are; row 4 added.
    assert sorted(changed_points(new, newer)[:, 0].round(3).tolist()) == [0.0, 0.06, 2.0, 2.0, 4.0]
    expected = third.astype(np.float32)
    expected[1] = start[1]  # moved 2 mm since it counted: where it was then
    np.testing.assert_array_equal(newer.position, expected)
    np.testing.assert_array_equal(newer.terrain, [0, 0, 1, 1, 1])


def test_a_chained_digest_classes_only_the_changed_rows_and_agrees_with_a_fresh_one(tiny_campus, tmp_path):
    """A live fusion's maps name the rows each changed since the one before: the digest chained
    through them classes and compares only those rows; its classes equal those of the whole map,
    and each entry is where the row last moved by more than the step (within the step of where it
    is now; row by row as the rule replayed here gives); a map the chain missed (or another
    fusion's) is digested whole."""
    from tests.live.test_chunk_views import _random_frame

    rng = np.random.default_rng(5)
    labels = np.unique(tiny_campus[0].point_labels)
    session = Session(tmp_path / "live.terra", tiny_campus.classes, graph=False, name="chain")
    classed: list[int] = []

    def terrain_of(votes: np.ndarray) -> np.ndarray:
        classed.append(len(votes))
        winners = terrain_winners(votes, 0.5, np.int16)
        winners[winners == 1] = -1  # a class the graph does not build on
        return winners

    digest, stamp, frames, counted_at = None, 0.0, [], np.zeros((0, 3), np.float32)
    for step in range(5):
        if step == 3:  # old ground alone, seen again with other labels: no new row, votes change
            frames = [{**frame, "labels": rng.choice(labels, 400)} for frame in frames[:2]]
        else:
            centres = ([10.0 * step, 0.0, 0.0], [rng.uniform(0.0, 10.0 * step + 1.0), 0.0, 0.0])
            frames = [_random_frame(rng, labels, np.asarray(centre)) for centre in centres] + frames
        for frame in frames[:2]:
            stamp += 0.1
            session.add_frame(frame["points"], frame["T_map_lidar"], stamp, labels=frame["labels"])
        msm = session.mapper.finish()
        assert msm.fusion_rows is not None
        if step == 3:
            assert digest is not None and len(msm) == len(digest.hashes)
            continue  # a map the chain does not see: the next is digested whole
        classed.clear()
        previous = digest
        digest = next_digest(digest, msm, terrain_of, 0.05)
        fresh = map_digest(msm.points, terrain_of(msm.terrain_votes), 0.05, msm.fusion_rows)
        np.testing.assert_array_equal(digest.terrain, fresh.terrain)
        np.testing.assert_array_equal(digest.rows, fresh.rows)
        assert np.abs(digest.position - fresh.position).max() <= 0.05
        np.testing.assert_array_equal(digest.hashes, point_hashes(digest.position, digest.terrain, 0.05))
        assert classed[-1] == len(msm)  # the fresh one
        if step in (1, 2):  # chained: only the rows the new frames touched
            assert previous is not None and msm.fusion_rows.changed is not None
            assert classed[0] == len(msm.fusion_rows.changed) < len(msm)
            kept = len(counted_at)
            moved = np.abs(fresh.position[:kept] - counted_at).max(axis=1) > np.float32(0.05)
            moved |= fresh.terrain[:kept] != previous.terrain
            counted_at = np.vstack([np.where(moved[:, None], fresh.position[:kept], counted_at), fresh.position[kept:]])
            np.testing.assert_array_equal(digest.position, counted_at)
            held = np.intersect1d(msm.fusion_rows.changed, np.flatnonzero(~moved))  # changed, not counted
            assert moved.any() and (len(held) > 0 or step == 1)
        else:  # the first, and the one after the missed map
            assert classed[0] == len(msm)
            np.testing.assert_array_equal(digest.position, fresh.position)
            counted_at = fresh.position.copy()
    session.close()


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


def test_a_long_mostly_empty_part_is_cut_into_squares_each_read_with_its_own_crop():
    """A diagonal band of changed tiles (a drive since the last sweep): one bounding box would read
    the whole square around it; cut into squares of max_crop_side, the crops read the band and its
    margins, and every rebuilt tile is still rebuilt, inside the crop of its own part."""
    update = {"tile": 10.0, "replace_margin": 0.0, "context_margin": 5.0, "min_changed_points": 1}
    along = np.arange(5.0, 400.0, 10.0)
    changed = np.column_stack([along, along])  # one point in each of 40 diagonal tiles
    whole = tile_zone(changed, BuildConfig.model_validate({"update": {**update, "max_crop_side": 1000.0}}))
    cut = tile_zone(changed, BuildConfig.model_validate({"update": {**update, "max_crop_side": 40.0}}))
    assert whole is not None and cut is not None
    assert len(whole.crops) == 1 and whole.crop_area == pytest.approx(410.0**2)
    assert len(cut.crops) == 10  # 4 x 4 tile squares along the diagonal hold 4 tiles each
    assert cut.crop_area == pytest.approx(10 * 50.0**2)
    assert cut.area == whole.area == pytest.approx(40 * 100.0)
    np.testing.assert_array_equal(cut.in_zone(changed), np.ones(len(changed), dtype=bool))
    for (x, y), k in zip(changed, cut.part(changed)):
        x0, y0, x1, y1 = cut.crops[k - 1]
        assert x0 + 5.0 <= x - 5.0 and x + 5.0 <= x1 - 5.0 and y0 + 5.0 <= y - 5.0 and y + 5.0 <= y1 - 5.0
    # A compact part is not cut, however large: its box is the area it rebuilds.
    block = np.array([[x, y] for x in along[:12] for y in along[:12]])
    square = tile_zone(block, BuildConfig.model_validate({"update": {**update, "max_crop_side": 40.0}}))
    assert square is not None and len(square.crops) == 1


# Full builds only when asked: these maps are small, and their crops cover much of them.
UPDATE = {"tile": 10.0, "replace_margin": 0.0, "context_margin": 20.0, "min_changed_points": 1, "full_fraction": 1.0}


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
        return graph.places.position[keep][order], graph.places.terrain[keep][order], graph.places.room[keep][order]

    np.testing.assert_allclose(east(inc)[0], east(full)[0], atol=1e-9)
    np.testing.assert_array_equal(east(inc)[1], east(full)[1])
    # The room read on the crop is the full build's (the crop reaches 8 m beyond, the room 3 m).
    np.testing.assert_allclose(east(inc)[2], east(full)[2], atol=1e-9)
    # One connected graph, as the full build's.
    import scipy.sparse.csgraph as csgraph

    assert csgraph.connected_components(inc.place_adjacency(), directed=False)[0] == 1


def test_the_room_read_on_a_crop_is_the_full_builds(text_embedder):
    """A pole (0.3 m square, 0.2 to 1.5 m up, points without terrain) comes into the east part:
    the update reads the room of the rebuilt places on its crop, as a full build on the whole map
    does (the crop reaches beyond the room's 3 m), and some places read less than 3 m."""
    from tests.tasks.test_tasks_synthetic import make_map

    config = BuildConfig.model_validate({"update": UPDATE})
    before = two_part_map(text_embedder, "grass", 15.0)
    after = two_part_map(text_embedder, "grass", 15.0)
    side = np.arange(-0.15, 0.151, 0.05)
    xs, ys, zs = np.meshgrid(78.0 + side, 2.5 + side, np.arange(0.2, 1.51, 0.1), indexing="ij")
    pole = np.column_stack([xs.ravel(), ys.ravel(), zs.ravel()])
    points = np.vstack([after.points, pole])
    with_pole = make_map(points, [{}] * len(points), after.bank, after.terrain_embeddings)
    with_pole.terrain_votes = np.vstack([after.terrain_votes, np.zeros((len(pole), after.terrain_votes.shape[1]))])
    with_pole.terrain_votes = with_pole.terrain_votes.astype(np.uint16)
    for msm in (before, with_pole):
        msm.points = msm.points + np.float32(0.05)
    updater = GraphUpdater(config)
    updater.update(before)
    update = updater.update(with_pole)
    assert update.update.kind == "incremental"
    full = build_scene_graph(with_pole, config).graph

    def east_room(graph):
        keep = ~_west(graph)
        order = np.lexsort(graph.places.position[keep].T[::-1])
        return graph.places.position[keep][order], graph.places.room[keep][order]

    np.testing.assert_allclose(east_room(update.graph)[0], east_room(full)[0], atol=1e-9)
    np.testing.assert_allclose(east_room(update.graph)[1], east_room(full)[1], atol=1e-9)
    assert east_room(full)[1].min() < 3.0


def test_kept_edges_keep_their_ground_geometry_and_new_ones_get_theirs(updates):
    first, second, _, _, full = updates
    a, b = first.graph, second.graph
    assert a.has_edge_geometry and b.has_edge_geometry and full.has_edge_geometry
    np.testing.assert_array_equal(b.place_edges, second.graph.place_edges)

    def by_ids(graph):
        ids = graph.places.id[graph.place_edges]
        return {(int(i), int(j)): tuple(g) for (i, j), g in zip(ids.tolist(), graph.place_edge_geometry.tolist())}

    old, new = by_ids(a), by_ids(b)
    kept = [key for key in new if key in old]
    assert kept and all(new[key] == old[key] for key in kept)
    # Flat synthetic ground: every edge, old or new, crosses no step and no slope.
    assert np.abs(b.place_edge_geometry[:, :3]).max() < 1e-3


def test_a_lidar_only_map_updates_on_its_ground(text_embedder):
    """A map with no terrain votes (a LiDAR-only log): the first update builds on `ground` as a
    full build does, the next rebuilds the changed part on its crops' segmented ground."""
    from tests.tasks.test_tasks_synthetic import BANK, make_map

    def lidar_map(east_length: float):
        msm = two_part_map(text_embedder, "grass", east_length)
        msm.points = msm.points + np.float32(0.05)
        return make_map(
            msm.points, [{}] * len(msm.points), text_embedder.embed_text(BANK), np.zeros((0, 384)), terrain_classes=[]
        )

    config = BuildConfig.model_validate({"update": UPDATE})
    updater = GraphUpdater(config)
    first = updater.update(lidar_map(30.0))
    second = updater.update(lidar_map(15.0))
    assert first.update.kind == "full" and second.update.kind == "incremental"
    assert second.graph.terrain_classes == ["ground"] == first.graph.terrain_classes
    west_a, west_b = _west(first.graph), _west(second.graph)
    np.testing.assert_array_equal(second.graph.places.id[west_b], first.graph.places.id[west_a])
    east = second.graph.places.position[~west_b]
    assert len(east) >= 1 and east[:, 0].max() < 70.0 + 15.0
    # Every place of a full build has one of the update within 2 m; with no replace margin, a kept
    # place just outside the changed tiles (whose GVD path got shorter) may stay as one extra.
    full = build_scene_graph(lidar_map(15.0), config).graph
    gap = np.linalg.norm(full.places.position[:, None, :2] - second.graph.places.position[None, :, :2], axis=2)
    assert (gap.min(axis=1) <= 2.0).all()
    assert 0 <= len(second.graph.places) - len(full.places) <= 1


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


def test_a_strip_cut_by_the_rebuilt_area_stays_one_piece_without_bridges(text_embedder):
    """One 120 m dirt strip whose middle (x 60..70) widens in the second version: the GVD edges
    the zone's border cuts are stitched to the places that replaced their lost ends, so the
    strip's places stay one connected chain with no bridge, as in a full build."""
    import scipy.sparse.csgraph as csgraph

    from terra.graph.scene_graph import EDGE_BRIDGE
    from tests.tasks.test_tasks_synthetic import BANK, TERRAINS, make_map

    def strip(bulge: bool):
        xs, ys = np.meshgrid(np.arange(0.0, 120.0, 0.2), np.arange(0.0, 8.0, 0.2), indexing="ij")
        points = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
        if bulge:
            bx, by = np.meshgrid(np.arange(60.0, 70.0, 0.2), np.arange(8.0, 14.0, 0.2), indexing="ij")
            points = np.vstack([points, np.stack([bx.ravel(), by.ravel(), np.zeros(bx.size)], axis=1)])
        msm = make_map(
            points + 0.05, [{}] * len(points), text_embedder.embed_text(BANK), text_embedder.embed_text(TERRAINS)
        )
        votes = np.zeros((len(points), len(TERRAINS)), dtype=np.uint16)
        votes[:, TERRAINS.index("dirt")] = 5
        msm.terrain_votes = votes
        return msm

    config = BuildConfig.model_validate({"update": UPDATE})
    updater = GraphUpdater(config)
    updater.update(strip(False))
    second = updater.update(strip(True))
    assert second.update.kind == "incremental" and second.update.places_kept > 0
    assert second.update.stitched_edges >= 1
    graph = second.graph
    assert (graph.place_edge_kind == EDGE_BRIDGE).sum() == 0
    assert csgraph.connected_components(graph.place_adjacency(), directed=False)[0] == 1
    # The chain is split into places from its ends: near the border the update's split points may
    # differ from a full build's by a place or two (a named difference; the closing build has none).
    full = build_scene_graph(strip(True), config).graph
    assert abs(len(graph.places) - len(full.places)) <= 2


def test_a_long_change_rebuilt_in_cut_parts_stays_one_piece_as_a_full_build(text_embedder):
    """A dirt strip 8 m wide along a 150 m diagonal that widens along 110 m of it: the rebuilt band's
    bounding box is mostly empty, so it is cut into parts (`max_crop_side` 30 m), each read with its
    own crop; the edges between neighbouring parts are stitched to each other's places, so the strip
    stays one piece without bridges, with the places of the full build but a few at the parts' borders."""
    import scipy.sparse.csgraph as csgraph

    from terra.graph.scene_graph import EDGE_BRIDGE
    from tests.tasks.test_tasks_synthetic import BANK, TERRAINS, make_map

    along, across = np.array([1.0, 1.0]) / np.sqrt(2.0), np.array([-1.0, 1.0]) / np.sqrt(2.0)

    def band(t0: float, t1: float, s0: float, s1: float) -> np.ndarray:
        t, u = np.meshgrid(np.arange(t0, t1, 0.15), np.arange(s0, s1, 0.15), indexing="ij")
        xy = t.reshape(-1, 1) * along + u.reshape(-1, 1) * across
        return np.column_stack([xy, np.zeros(len(xy))])

    def strip(wide: bool):
        points = band(0.0, 150.0, -4.0, 4.0)
        if wide:
            points = np.vstack([points, band(20.0, 130.0, 4.0, 10.0)])
        msm = make_map(
            points + 0.05, [{}] * len(points), text_embedder.embed_text(BANK), text_embedder.embed_text(TERRAINS)
        )
        votes = np.zeros((len(points), len(TERRAINS)), dtype=np.uint16)
        votes[:, TERRAINS.index("dirt")] = 5
        msm.terrain_votes = votes
        return msm

    config = BuildConfig.model_validate({"update": {**UPDATE, "context_margin": 10.0, "max_crop_side": 30.0}})
    updater = GraphUpdater(config)
    updater.update(strip(False))
    second = updater.update(strip(True))
    assert second.update.kind == "incremental", second.update.reason
    zone = tile_zone(band(20.0, 130.0, 4.0, 10.0)[:, :2], config)
    assert zone is not None and len(zone.crops) >= 4  # the cut, not one box around the diagonal
    graph = second.graph
    assert (graph.place_edge_kind == EDGE_BRIDGE).sum() == 0
    assert csgraph.connected_components(graph.place_adjacency(), directed=False)[0] == 1
    full = build_scene_graph(strip(True), config).graph
    assert abs(len(graph.places) - len(full.places)) <= 3


def test_sparse_changes_wait_for_the_sweep_and_are_rebuilt_then(text_embedder):
    """Changes too sparse for `min_changed_points` wait; every `sweep_every` updates they are
    rebuilt whatever their number, to the places the dense rule would have given."""
    sparse = BuildConfig.model_validate({"update": {**UPDATE, "min_changed_points": 10**6, "sweep_every": 2}})
    first_map = two_part_map(text_embedder, "grass", 30.0)
    second_map = two_part_map(text_embedder, "asphalt", 15.0)
    for msm in (first_map, second_map):
        msm.points = msm.points + np.float32(0.05)  # off the cell boundaries, as in `updates`
    updater = GraphUpdater(sparse)
    first = updater.update(first_map)
    waiting = updater.update(second_map)
    assert waiting.update.reason == "nothing changed" and waiting.graph is first.graph
    swept = updater.update(second_map)  # the map is as it was; the waiting changes are rebuilt now
    assert swept.update.kind == "incremental" and swept.update.sweep
    dense = GraphUpdater(BuildConfig.model_validate({"update": UPDATE}))
    dense.update(first_map)
    expected = dense.update(second_map).graph
    np.testing.assert_allclose(
        np.sort(swept.graph.places.position, axis=0), np.sort(expected.places.position, axis=0), atol=1e-9
    )
    assert updater.update(second_map).update.reason == "nothing changed"
