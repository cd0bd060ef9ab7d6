"""Change detection (terra/mapping/changes.py) on hand-made point sets: a car-sized box of object points on
flat ground, seen by the first session, and a second session that saw the ground where it stood (removed),
never came near (not seen is not gone), or saw the car from its other side (still there); a fence (a plane of
points, no width) put up or taken away, the ground it stands on blocked, and a car's side seen apart from its
body that is not a fence."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from terra.mapping.changes import (
    BLOCKED,
    ChangeSettings,
    TerrainChange,
    _changed_clusters,
    _object_changes,
    _Sessions,
    _terrain_changes,
)
from terra.tasks.change_report import summarise_regions

STEP = 0.4  # metres between points, the map's voxel size


def scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground points (z = 0) over 20 m x 20 m and a 4.4 x 1.8 x 1.5 m box's top and sides at x 8..12.4,
    y 9..10.8; (points (N, 3), is_car (N,), under_car (N,): ground points inside its footprint)."""
    g = np.arange(0.0, 20.0, STEP)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    ground = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    x, y, z = np.arange(8.0, 12.41, STEP), np.arange(9.0, 10.81, STEP), np.arange(0.3, 1.51, STEP)
    top = np.array([(a, b, 1.5) for a in x for b in y])
    sides = np.array([(a, b, c) for a in x for b in (y[0], y[-1]) for c in z])
    ends = np.array([(a, b, c) for a in (x[0], x[-1]) for b in y for c in z])
    car = np.vstack([top, sides, ends])
    points = np.vstack([ground, car])
    is_car = np.arange(len(points)) >= len(ground)
    under = ~is_car & (points[:, 0] > 7.9) & (points[:, 0] < 12.5) & (points[:, 1] > 8.9) & (points[:, 1] < 10.9)
    return points, is_car, under


def sessions(
    points: np.ndarray, is_car: np.ndarray, hits_1: np.ndarray, hits_2: np.ndarray, labelled: bool = True
) -> _Sessions:
    """The arrays of a joined map: object observations on the car's points (bank entry 0; none when not
    `labelled`: no camera saw it), terrain votes where each session returned from the ground."""
    hits = np.stack([hits_1, hits_2], axis=1).astype(np.int64) * 3
    votes = np.zeros((2, len(points), 1), np.int64)
    votes[:, ~is_car, 0] = hits[~is_car].T
    counts = sp.csr_matrix((is_car * 3 * labelled).astype(np.int64)[:, None])
    return _Sessions(points, hits, votes, counts, ["asphalt"])


def test_a_car_whose_ground_the_second_session_saw_is_removed():
    points, is_car, under = scene()
    data = sessions(points, is_car, ~under, ~is_car)  # the second session saw the ground under the car
    (change,) = _object_changes(data, 0, 1, ChangeSettings())
    assert change.change == "removed" and change.entry == 0
    assert np.allclose(change.before[:2], (10.2, 9.9), atol=0.3)  # pyright: ignore[reportOptionalSubscript]


def test_a_car_only_the_lidar_saw_is_judged_too():
    points, is_car, under = scene()
    (change,) = _object_changes(sessions(points, is_car, ~under, ~is_car, labelled=False), 0, 1, ChangeSettings())
    assert change.change == "removed" and change.entry == -1 and change.to_json()["entry"] is None
    far = ~is_car & (points[:, 0] < 4.0)
    assert _object_changes(sessions(points, is_car, ~under, far, labelled=False), 0, 1, ChangeSettings()) == []


def test_not_seen_is_not_gone():
    points, is_car, under = scene()
    far = ~is_car & (points[:, 0] < 4.0)  # the second session passed 4 m off the car and saw nothing of it
    assert _object_changes(sessions(points, is_car, ~under, far), 0, 1, ChangeSettings()) == []
    assert _object_changes(sessions(points, is_car, ~under, np.zeros(len(points), bool)), 0, 1, ChangeSettings()) == []


def test_a_car_seen_from_its_other_side_is_still_there():
    points, is_car, under = scene()
    far_side = (is_car & (points[:, 1] >= 10.0)) | (~is_car & ~under & (points[:, 1] > 10.0))
    near_side = (is_car & (points[:, 1] < 10.0)) | (~is_car & ~under & (points[:, 1] < 10.0))
    assert _object_changes(sessions(points, is_car, near_side, far_side), 0, 1, ChangeSettings()) == []


def test_an_added_car_is_found_the_other_way_round():
    points, is_car, under = scene()
    (change,) = _object_changes(sessions(points, is_car, ~is_car, ~under), 0, 1, ChangeSettings())
    assert change.change == "added" and change.before is None


def test_region_summary_counts_objects_and_sums_terrain_per_region():
    rows = summarise_regions(
        ["R2", "R10", "R2"],
        ["added", "moved", "removed"],
        ["R2", "R2", "R3"],
        ["a -> b"] * 2 + ["b -> a"],
        np.array([1, 1, 4]),
    )
    assert [r.region for r in rows] == ["R2", "R3", "R10"]
    assert (rows[0].added, rows[0].removed, rows[0].moved, rows[0].terrain_m2) == (1, 1, 0, {"a -> b": 2.0})
    assert rows[1].terrain_m2 == {"b -> a": 4.0} and rows[2].moved == 1


def fenced(side: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """Ground points (z = 0) over 20 m x 20 m and a fence's panel, a plane of points 3.2 m long (x 8..11.2)
    and 0.3 to 1.1 m high at y = `side`, no thickness at all; (points (N, 3), is_fence (N,))."""
    g = np.arange(0.0, 20.0, STEP)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    ground = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    panel = np.array([(x, side, z) for x in np.arange(8.0, 11.21, STEP) for z in np.arange(0.3, 1.11, 0.2)])
    points = np.vstack([ground, panel])
    return points, np.arange(len(points)) >= len(ground)


def test_a_fence_put_up_is_added_though_it_has_no_width():
    points, is_fence = fenced()
    data = sessions(points, is_fence, ~is_fence, np.ones(len(points), bool))  # the ground was open before
    (change,) = _object_changes(data, 0, 1, ChangeSettings())
    assert change.change == "added" and change.size[1] < 0.3 and change.size[0] > 3.0
    assert _object_changes(data, 0, 1, ChangeSettings(thin_length=4.0)) == []  # shorter than that: a sliver
    assert _object_changes(data, 0, 1, ChangeSettings(thin_height=1.5)) == []  # lower than that: not judged
    gone = sessions(points, is_fence, np.ones(len(points), bool), ~is_fence)
    assert [c.change for c in _object_changes(gone, 0, 1, ChangeSettings())] == ["removed"]


def test_the_ground_a_fence_stands_on_is_blocked_in_a_line_of_cells():
    points, is_fence = fenced(side=10.2)
    data = sessions(points, is_fence, ~is_fence, np.ones(len(points), bool))
    data.terrain_classes[:] = ["sidewalk"]
    settings = ChangeSettings()
    _, removed, added = _changed_clusters(data, 0, 1, settings)
    terrain, cells, pairs = _terrain_changes(data, 0, 1, settings, (removed, added))
    assert terrain == [TerrainChange("sidewalk", BLOCKED, 4.0)]  # x 8..11.2 in 1 m cells, one row
    np.testing.assert_array_equal(cells, [[8.5, 10.5], [9.5, 10.5], [10.5, 10.5], [11.5, 10.5]])
    assert pairs == ["sidewalk -> blocked"] * 4
    # A line of cells as long as a fence (`thin_length`) counts though it is fewer cells than a patch needs
    terrain, _, _ = _terrain_changes(data, 0, 1, ChangeSettings(min_patch=5), (removed, added))
    assert terrain == [TerrainChange("sidewalk", BLOCKED, 4.0)]
    assert _terrain_changes(data, 0, 1, ChangeSettings(min_patch=5, thin_length=5.0), (removed, added))[0] == []
    gone = sessions(points, is_fence, np.ones(len(points), bool), ~is_fence)
    gone.terrain_classes[:] = ["sidewalk"]
    _, removed, added = _changed_clusters(gone, 0, 1, settings)
    assert _terrain_changes(gone, 0, 1, settings, (removed, added))[0] == [TerrainChange(BLOCKED, "sidewalk", 4.0)]
    water = sessions(points, is_fence, ~is_fence, np.ones(len(points), bool))
    water.terrain_classes[:] = ["water"]  # not ground one walks on: nothing to block
    _, removed, added = _changed_clusters(water, 0, 1, settings)
    assert added and _terrain_changes(water, 0, 1, settings, (removed, added))[0] == []


def test_a_cars_side_seen_apart_from_its_body_is_not_a_fence():
    """The first session saw one side of a car (a plane of points 4.4 m long), the second its other side,
    1.8 m away, and the ground around the car, but not under it: a wall of its own has open ground on both
    sides, this one the car on one."""
    g = np.arange(0.0, 20.0, STEP)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    ground = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    x, z = np.arange(8.0, 12.41, STEP), np.arange(0.3, 1.51, 0.2)
    near = np.array([(a, 8.95, c) for a in x for c in z])  # in the cells of the open ground at y = 8.8
    far = np.array([(a, 10.75, c) for a in x for c in z])
    points = np.vstack([ground, near, far])
    is_car = np.arange(len(points)) >= len(ground)
    under = ~is_car & (points[:, 1] > 8.9) & (points[:, 1] < 10.8)
    first = (~is_car & ~under) | (np.arange(len(points)) < len(ground) + len(near)) & is_car
    second = (~is_car & ~under) | (np.arange(len(points)) >= len(ground) + len(near))
    data = sessions(points, is_car, first, second)
    assert _object_changes(data, 0, 1, ChangeSettings()) == []
    # Without looking at both sides, the first side would be a fence taken away and the second one put up.
    assert [c.change for c in _object_changes(data, 0, 1, ChangeSettings(thin_side=0.0))] == ["moved"]
