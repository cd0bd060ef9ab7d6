"""Change detection (terra/mapping/changes.py) on hand-made point sets: a car-sized box of object points on
flat ground, seen by the first session, and a second session that saw the ground where it stood (removed),
never came near (not seen is not gone), or saw the car from its other side (still there)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from terra.mapping.changes import ChangeSettings, _object_changes, _Sessions
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
