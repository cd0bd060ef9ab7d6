"""A second visit of a simulated world (terra/sim/revisit.py, `terra sim --revisit`): the listed changes are
the changes made to the world, the poses are reported in the listed frame, and no change means no change."""

from __future__ import annotations

import json

import numpy as np
import pytest

from terra.cli import run
from terra.geometry import invert_pose
from terra.sim.classes import class_id
from terra.sim.config import RevisitConfig, SimConfig
from terra.sim.dataset import simulate
from terra.sim.revisit import rerouted, session_pose


@pytest.fixture(scope="module")
def revisit():
    return simulate("tiny", 0, SimConfig(revisit=RevisitConfig(frame=(50.0, -10.0, 90.0))))


def test_the_listed_object_changes_are_made_in_the_world(tiny_campus, revisit):
    before, after = tiny_campus.world, revisit.world
    truth = revisit.revisit
    kinds = [c["change"] for c in truth.objects]
    assert kinds.count("moved") == 2 and kinds.count("removed") == 3 and kinds.count("added") == 3  # 2 cars, a fence
    ids_after = {o.instance_id for o in after.objects}
    for change in truth.objects:
        iid = change["instance_id"]
        if change["change"] == "removed":
            assert iid not in ids_after and iid not in set(after.prims.instance_id)
            assert iid in set(before.prims.instance_id)
        elif change["change"] == "added":
            assert iid in ids_after and iid not in set(before.prims.instance_id)
            centres = after.prims.center[after.prims.instance_id == iid]
            assert np.linalg.norm(centres[:, :2].mean(axis=0) - change["to"][:2]) < 2.5  # parts around the car
        else:
            old = before.prims.center[before.prims.instance_id == iid]
            new = after.prims.center[after.prims.instance_id == iid]
            shift = (new - old)[:, :2]
            np.testing.assert_allclose(shift, np.broadcast_to(shift[0], shift.shape), atol=1e-9)  # one rigid shift
            assert np.linalg.norm(shift[0]) == pytest.approx(change["distance"], abs=1e-3)
            assert 3.0 <= change["distance"] <= 6.0
    removed_bench = [c for c in truth.objects if c["class"] == "bench"]
    assert len(removed_bench) == 1 and removed_bench[0]["change"] == "removed"


def test_the_lawn_patch_turns_to_dirt_and_nothing_else_changes(tiny_campus, revisit):
    before, after = tiny_campus.world.terrain, revisit.world.terrain
    (patch,) = [t for t in revisit.revisit.terrain if t["to"] == "dirt"]  # a fence blocks ground, not repaints it
    changed = before.classes != after.classes
    assert np.all(before.classes[changed] == class_id("grass")) and np.all(after.classes[changed] == class_id("dirt"))
    assert changed.sum() * before.resolution**2 == pytest.approx(patch["area_m2"])
    (x0, y0), (x1, y1) = patch["polygon"][0], patch["polygon"][2]
    xs, ys = before.cell_centres()
    inside = np.outer((ys > y0) & (ys < y1), (xs > x0) & (xs < x1))
    np.testing.assert_array_equal(changed, inside)


def test_a_fence_closes_a_sidewalk_end_to_end(tiny_campus, revisit):
    before, after, truth = tiny_campus.world, revisit.world, revisit.revisit
    fence = class_id("fence")
    assert not np.isin(fence, before.prims.class_id)  # no first visit has a fence: its worlds are as they were
    (added,) = [c for c in truth.objects if c["class"] == "fence"]
    assert added["change"] == "added" and added["from"] is None
    (blocked,) = [t for t in truth.terrain if t["to"] == "blocked"]
    assert blocked["from"] == "sidewalk"
    parts = after.prims.instance_id == added["instance_id"]
    assert np.all(after.prims.class_id[parts] == fence) and parts.sum() == 4  # 3 posts <= 2.5 m apart, a panel
    length, width, height = added["extent"]
    assert width == pytest.approx(0.1) and 1.0 <= height <= 1.5
    # Turned across the walkway: its length runs over the sidewalk's width, from one edge to the other.
    (x0, y0), (x1, y1) = blocked["polygon"][0], blocked["polygon"][2]
    across = int(np.argmax([x1 - x0, y1 - y0]))  # the axis the fence runs along
    assert [x1 - x0, y1 - y0][across] == pytest.approx(length)
    assert [x1 - x0, y1 - y0][1 - across] == pytest.approx(before.terrain.resolution)  # one row of cells
    assert blocked["area_m2"] == pytest.approx(length * before.terrain.resolution)
    assert x0 < added["to"][0] < x1 and y0 < added["to"][1] < y1
    terrain = before.terrain
    middle = (np.array([x0, y0]) + [x1, y1]) / 2
    step = np.eye(2)[across] * (length / 2 + terrain.resolution / 2)
    cells = middle + np.outer(np.linspace(-length / 2 + 0.1, length / 2 - 0.1, 12), np.eye(2)[across])
    assert np.all(terrain.class_at(cells) == class_id("sidewalk"))  # it stands on sidewalk all along
    assert np.all(terrain.class_at(np.array([middle - step, middle + step])) != class_id("sidewalk"))  # edge to edge
    np.testing.assert_array_equal(after.terrain.class_at(cells), terrain.class_at(cells))  # still paved, blocked
    walkway = middle + np.outer([-4.0, 4.0], np.eye(2)[1 - across])  # sidewalk goes on both ways past it
    assert np.all(terrain.class_at(walkway) == class_id("sidewalk"))
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled module

    distance = cKDTree(after.route).query(cells)[0]
    assert distance.min() >= 2.0 and distance.max() <= 14.0  # passed, not driven through; within its LiDAR's reach


def test_poses_are_reported_in_the_revisit_frame_on_another_route(tiny_campus, revisit):
    T_world_session = session_pose(revisit.config.revisit)
    np.testing.assert_allclose(T_world_session[:2, 3], [50.0, -10.0])
    for i in (0, len(revisit) - 1):
        expected = invert_pose(T_world_session) @ revisit.gt_T_map_lidar(i)
        np.testing.assert_allclose(revisit[i].T_map_lidar, expected, atol=1e-9)
    route = tiny_campus.world.route
    np.testing.assert_allclose(revisit.world.route[-1], route[0])  # reversed: it ends where the first began
    assert np.linalg.norm(revisit.world.route[0] - route[-1]) > 5.0  # and starts elsewhere
    removed = [c["instance_id"] for c in revisit.revisit.objects if c["change"] == "removed"]
    for i in range(0, len(revisit), 7):
        assert not np.isin(revisit[i].point_instances, removed).any()  # the LiDAR sees no removed thing


def test_rerouted_starts_at_the_fraction_of_the_reversed_route():
    route = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    np.testing.assert_allclose(rerouted(route, 0.25), [[10.0, 5.0], [10.0, 0.0], [0.0, 0.0]])


def test_a_revisit_without_changes_changes_nothing(tiny_campus):
    none = RevisitConfig(cars_moved=0, cars_removed=0, cars_added=0, benches_removed=0, lawns_to_dirt=0, fences_added=0)
    same = simulate("tiny", 0, SimConfig(revisit=none))
    assert same.revisit is not None and same.revisit.objects == [] and same.revisit.terrain == []
    np.testing.assert_array_equal(same.world.prims.center, tiny_campus.world.prims.center)
    np.testing.assert_array_equal(same.world.terrain.classes, tiny_campus.world.terrain.classes)


def test_terra_sim_revisit_writes_the_truth(tmp_path, capsys):
    out = tmp_path / "visit2"
    assert run(["sim", "--preset", "tiny", "--revisit", "--max-frames", "2", "--out", str(out), "-q"]) == 0
    truth = json.loads((out / "revisit.json").read_text())
    np.testing.assert_allclose(truth["T_world_session"], session_pose(RevisitConfig()), atol=1e-12)
    assert {c["change"] for c in truth["objects"]} == {"moved", "removed", "added"}
    config = tmp_path / "revisit.yaml"
    config.write_text("sim:\n  revisit:\n    cars_moved: 1\n")
    capsys.readouterr()
    assert run(["sim", "--preset", "tiny", "-c", str(config), "--out", str(tmp_path / "x"), "-q"]) == 2
    assert "sim.revisit is read with --revisit" in capsys.readouterr().err


def test_changes_lie_where_the_revisit_drives(revisit):
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled module

    route = cKDTree(revisit.world.route)
    for change in revisit.revisit.objects:
        for key in ("from", "to"):
            if change[key] is not None:
                assert route.query(change[key][:2])[0] <= 20.0, change  # within what its LiDAR sees
    for change in revisit.revisit.objects:
        if change["change"] == "added":  # parked clear of the route, not across it
            assert route.query(change["to"][:2])[0] > 2.0


def test_footprints_side_by_side_in_a_parking_row_do_not_overlap():
    from terra.sim.revisit import _footprint, _overlap

    size = np.array([4.4, 1.9])
    car = _footprint(np.array([0.0, 0.0]), np.pi / 2, size)  # facing north: 1.9 m wide along x
    assert not _overlap(car, _footprint(np.array([2.8, 0.0]), np.pi / 2, size))  # the next stall, 0.9 m apart
    assert _overlap(car, _footprint(np.array([1.5, 0.0]), np.pi / 2, size))
    assert _overlap(car, _footprint(np.array([0.0, 3.0]), 0.0, size))  # across its length
