"""The generated worlds contain what later stages and their evaluations rely on."""

import numpy as np
import pytest
from shapely.geometry import Point, Polygon

from terra.errors import TerraError
from terra.sim import SimConfig, simulate
from terra.sim.classes import SIM_CLASSES
from terra.sim.config import RouteConfig

WALKABLE = {"sidewalk", "asphalt", "dirt"}


def class_names(gt):
    return {o.class_name for o in gt.objects}


def terrain_names(gt):
    return {gt.terrain.legend[int(i)] for i in np.unique(gt.terrain.classes)}


def test_class_table():
    terrain = [c.name for c in SIM_CLASSES.terrain_classes]
    assert terrain == ["sidewalk", "grass", "asphalt", "dirt", "water"]
    objects = [c for c in SIM_CLASSES if not c.terrain and c.name not in ("unlabeled", "building", "tree")]
    assert len(objects) >= 15
    assert SIM_CLASSES.by_id(0).name == "unlabeled"


def test_tiny_has_what_tests_need(tiny_campus):
    gt = tiny_campus.ground_truth()
    assert len(tiny_campus) <= 40
    assert {"car", "building", "bicycle rack", "dumpster"} <= class_names(gt)
    assert {"sidewalk", "grass", "asphalt"} <= terrain_names(gt)
    assert len(gt.regions) >= 2 and all(r.description for r in gt.regions)
    # The cars stand in the parking lot.
    lot = next(Polygon(r.polygon) for r in gt.regions if "parking" in r.description)
    cars = [o for o in gt.objects if o.class_name == "car"]
    assert len(cars) >= 5 and all(lot.contains(Point(*o.center[:2])) for o in cars)


def test_small_campus_layout(small_campus):
    gt = small_campus.ground_truth()
    t = gt.terrain
    assert 250 <= len(small_campus) <= 350
    extent = t.resolution * np.array(t.classes.shape)
    assert np.all(np.abs(extent - 150.0) < 1.0)
    assert terrain_names(gt) >= {"sidewalk", "grass", "asphalt", "dirt", "water"}
    objects = class_names(gt) - {"building", "tree"}
    assert len(objects) >= 15, objects
    descriptions = {r.description for r in gt.regions}
    assert "large parking lot surrounded by buildings" in descriptions
    assert "two long parallel sidewalks lined by trees" in descriptions
    assert len({r.name for r in gt.regions}) == len(gt.regions)
    ids = [o.instance_id for o in gt.objects]
    assert len(set(ids)) == len(ids) and min(ids) >= 1


def test_ground_slopes_are_a_few_degrees(small_campus):
    t = small_campus.ground_truth().terrain
    gy, gx = np.gradient(t.ground_height.astype(np.float64), t.resolution)
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    assert 1.0 < slope.max() < 7.0
    assert np.ptp(t.ground_height) > 0.5  # not flat


def test_sidewalks_are_wide_enough(small_campus):
    t = small_campus.ground_truth().terrain
    side = t.classes == SIM_CLASSES.by_name("sidewalk").id
    # Run lengths of sidewalk across every row and column: the narrowest walk must carry a GVD.
    runs = []
    for grid in (side, side.T):
        padded = np.pad(grid, ((0, 0), (1, 1))).astype(np.int8)
        d = np.diff(padded, axis=1)
        starts, ends = np.nonzero(d == 1), np.nonzero(d == -1)
        runs.append((ends[1] - starts[1]) * t.resolution)
    runs = np.concatenate(runs)
    # Every column crossing an east-west walk sees its full width (>= 2.5 m) somewhere.
    assert np.percentile(runs, 5) >= 2.5 - 1e-9 or np.mean(runs >= 2.5) > 0.9


def test_objects_stand_on_the_ground(small_campus):
    gt = small_campus.ground_truth()
    for o in gt.objects:
        bottom = o.center[2] - o.size[2] / 2
        ground = gt.terrain.height_at(o.center[None, :2])[0]
        # Bases sit at the lowest ground under the footprint (buildings are sunk a little).
        reach = np.hypot(*o.size[:2]) / 2 * 0.12 + 0.05
        assert bottom <= ground + 0.05 and bottom >= ground - reach, (o.class_name, bottom, ground)


def test_route_stays_on_walkable_ground_and_passes_near_objects(small_campus):
    gt = small_campus.ground_truth()
    xy = small_campus.trajectory.T_map_base[:, :2, 3]
    names = np.array([gt.terrain.legend.get(int(c), "") for c in gt.terrain.class_at(xy)])
    assert np.isin(names, list(WALKABLE)).mean() > 0.97
    # Clear of every object footprint, and within 15 m of most objects.
    near = 0
    for o in gt.objects:
        c, s = np.cos(o.yaw), np.sin(o.yaw)
        d = xy - o.center[:2]
        local = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1)
        gap = np.linalg.norm(np.maximum(np.abs(local) - o.size[:2] / 2, 0.0), axis=1)
        if o.class_name not in ("crosswalk", "tree"):  # crosswalks are driven over, crowns overhang
            assert gap.min() > 0.3, (o.class_name, o.instance_id, gap.min())
        near += gap.min() < 15.0
    assert near / len(gt.objects) > 0.7


def test_poses_follow_the_ground(small_campus):
    ds = small_campus
    gt = ds.ground_truth()
    T = np.array([ds.gt_T_map_lidar(i) for i in range(0, len(ds), 25)])
    base = T[:, :3, 3] - 1.8 * T[:, :3, 2]  # the LiDAR sits 1.8 m up the base's z axis
    np.testing.assert_allclose(base[:, 2], gt.terrain.height_at(base[:, :2]), atol=0.03)
    np.testing.assert_allclose(np.linalg.det(T[:, :3, :3]), 1.0, atol=1e-9)
    assert np.all(np.diff(ds.trajectory.stamps) > 0)


def test_seeds_change_the_world_and_presets_are_checked():
    a = simulate("small", 1).world
    b = simulate("small", 2).world
    assert not np.array_equal(a.prims.center, b.prims.center) or not np.array_equal(a.ground.phase, b.ground.phase)
    with pytest.raises(TerraError, match="unknown preset 'moon'"):
        simulate("moon")
    with pytest.raises(TerraError, match="seed"):
        simulate("tiny", -1)


def test_odometry_drift_moves_reported_poses_not_the_data():
    cfg = SimConfig(route=RouteConfig(max_frames=12, drift_xy_per_m=0.05, drift_yaw_deg_per_m=0.2))
    drift = simulate("tiny", 0, cfg)
    exact = simulate("tiny", 0, SimConfig(route=RouteConfig(max_frames=12)))
    k = 11
    assert not np.allclose(drift[k].T_map_lidar, exact[k].T_map_lidar)
    np.testing.assert_allclose(drift.gt_T_map_lidar(k), exact[k].T_map_lidar, atol=1e-12)
    np.testing.assert_array_equal(drift[k].points, exact[k].points)
    np.testing.assert_allclose(drift[0].T_map_lidar, exact[0].T_map_lidar, atol=0.2)
