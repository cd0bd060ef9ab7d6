"""Layouts of real robot logs from public repositories, rebuilt small in the test.

The Luminar layout is that of embarktrucks/embag `test/test.bag` (a ROS 1 bag of a truck's Luminar
LiDAR, 3.8 MB): `/luminar_pointcloud` (sensor_msgs/PointCloud2, frame `luminar_lidar`, point_step
32: x, y, z float32 at 0, 4, 8, intensity float32 at 16, time_sec uint32 at 20, time_nsec uint32 at
24, laser_id uint16 at 28; the point times are absolute, up to 88 ms before the header stamp) and
`/base_pose_ground_truth` (nav_msgs/Odometry in frame `odom` with an empty child_frame_id), and no
/tf. Mapping it needs poses from LiDAR odometry; its per-point times deskew the scans.
"""

from __future__ import annotations

import json
from fractions import Fraction

import numpy as np
import pytest

from terra.cli import run
from terra.datasets.ros.pointcloud2 import decode_pointcloud2
from terra.geometry import make_pose
from tests.datasets.fixtures_ros import factory_for, write_test_bag

STAMP_SEC = 1583971570  # the first scan's header stamp in the real bag: 1583971570.015299642
STAMP_NSEC = 15_299_642
LUMINAR_FIELDS = (("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 16, 7), ("time_sec", 20, 6))
LUMINAR_FIELDS += (("time_nsec", 24, 6), ("laser_id", 28, 4))
KINDS = {7: "<f4", 6: "<u4", 4: "<u2"}


def luminar_cloud(f, sec: int, nsec: int, points: np.ndarray, times_sec: np.ndarray, times_nsec: np.ndarray):
    """A PointCloud2 of the real Luminar layout (module docstring) with the given absolute point times."""
    dtype = np.dtype(
        {
            "names": [n for n, _, _ in LUMINAR_FIELDS],
            "formats": [KINDS[k] for _, _, k in LUMINAR_FIELDS],
            "offsets": [o for _, o, _ in LUMINAR_FIELDS],
            "itemsize": 32,
        }
    )
    cloud = np.zeros(len(points), dtype)
    cloud["x"], cloud["y"], cloud["z"] = points.T
    cloud["intensity"] = 7.0
    cloud["time_sec"], cloud["time_nsec"] = times_sec, times_nsec
    cloud["laser_id"] = np.arange(len(points)) % 4
    t = f._t
    return t["sensor_msgs/msg/PointCloud2"](
        header=f.header(sec * 1_000_000_000 + nsec, "luminar_lidar"),
        height=1,
        width=len(points),
        fields=[t["sensor_msgs/msg/PointField"](name=n, offset=o, datatype=k, count=1) for n, o, k in LUMINAR_FIELDS],
        is_bigendian=False,
        point_step=32,
        row_step=32 * len(points),
        data=np.frombuffer(cloud.tobytes(), np.uint8),
        is_dense=True,
    )


def odometry_message(f, stamp_ns: int, x: float):
    """nav_msgs/Odometry as the real bag holds it: frame 'odom', child_frame_id '' (empty)."""
    t = f._t
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=x, y=0.0, z=0.0),
        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
    )
    zeros6 = np.zeros(36)
    twist = t["geometry_msgs/msg/Twist"](
        linear=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
        angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
    )
    return t["nav_msgs/msg/Odometry"](
        header=f.header(stamp_ns, "odom"),
        child_frame_id="",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=zeros6),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=zeros6),
    )


def scene() -> np.ndarray:
    """A static yard: ground, four walls and posts (structure LiDAR odometry can register)."""
    rng = np.random.default_rng(4)
    ground = np.c_[rng.uniform(-20, 20, (1500, 2)), np.zeros(1500)]
    walls = [np.c_[rng.uniform(-20, 20, 800), np.full(800, side), rng.uniform(0, 4, 800)] for side in (-6.0, 6.0)]
    ends = [np.c_[np.full(600, end), rng.uniform(-6, 6, 600), rng.uniform(0, 4, 600)] for end in (-20.0, 20.0)]
    posts = [np.c_[np.full(60, px), np.full(60, 5.5), np.linspace(0, 3, 60)] for px in (-12.0, -3.0, 4.0, 13.0)]
    return np.vstack([ground, *walls, *ends, *posts])


def luminar_bag(path, scans: int = 5, speed: float = 1.0):
    """The real bag's topics and layout: a truck moving `speed` m/s along x past `scene()`; scan k's
    points are measured over the 88 ms before its stamp, each at its place along the sweep."""
    f = factory_for(ros1=True)
    world = scene()
    sweep = np.linspace(-0.0877, 0.0, len(world))  # seconds before the stamp, as in the real bag
    rows = []
    for k in range(scans):
        stamp_ns = STAMP_SEC * 1_000_000_000 + STAMP_NSEC + k * 100_000_000
        point_ns = stamp_ns + np.round(sweep * 1e9).astype(np.int64)
        x_at = speed * (point_ns - STAMP_SEC * 1_000_000_000) * 1e-9  # sensor position at each point's time
        seen = world - np.c_[x_at, np.zeros((len(world), 2))]
        cloud = luminar_cloud(f, stamp_ns // 10**9, stamp_ns % 10**9, seen, point_ns // 10**9, point_ns % 10**9)
        rows.append(("/luminar_pointcloud", "sensor_msgs/msg/PointCloud2", stamp_ns, cloud))
        rows.append(("/base_pose_ground_truth", "nav_msgs/msg/Odometry", stamp_ns, odometry_message(f, stamp_ns, 0.0)))
    return write_test_bag(path, rows, ros1=True)


def test_split_second_nanosecond_times_are_relative_to_the_stamp_to_the_nanosecond():
    """time_sec + time_nsec (absolute) -> seconds after the header stamp, computed exactly with ints."""
    f = factory_for(ros1=True)
    sec = np.array([STAMP_SEC - 1, STAMP_SEC - 1, STAMP_SEC, STAMP_SEC], np.uint32)
    nsec = np.array([927_535_642, 999_675_642, 396_642, STAMP_NSEC], np.uint32)  # the real bag's extremes
    points = np.array([[1.0, 2, 3], [4, 5, 6], [7, 8, 9], [1, 1, 1]], np.float32)
    cloud = decode_pointcloud2(luminar_cloud(f, STAMP_SEC, STAMP_NSEC, points, sec, nsec))
    exact = [float(Fraction(int(s) - STAMP_SEC) + Fraction(int(n) - STAMP_NSEC, 10**9)) for s, n in zip(sec, nsec)]
    assert exact[0] == pytest.approx(-0.087764)  # the real bag's earliest point, 87.764 ms before the stamp
    assert cloud.times is not None
    np.testing.assert_allclose(cloud.times, exact, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(cloud.points, points)


def test_split_times_relative_to_the_stamp_stay_as_they_are():
    """A split pair holding a time since the stamp (whole seconds 0) is not shifted by the stamp."""
    f = factory_for(ros1=True)
    points = np.ones((2, 3), np.float32)
    cloud = decode_pointcloud2(
        luminar_cloud(f, STAMP_SEC, 0, points, np.array([0, 1], np.uint32), np.array([5_000_000, 250], np.uint32))
    )
    assert cloud.times is not None
    np.testing.assert_allclose(cloud.times, [0.005, 1.00000025], rtol=0, atol=1e-12)


def test_luminar_scans_are_deskewed_with_tf_poses(tmp_path):
    """With poses from /tf, each point moves to the LiDAR frame at the stamp by the pose at its own
    time: a truck at 1 m/s sees the street's points shifted by up to 8.8 cm; deskewed they are
    the street seen from the pose at the stamp."""
    from terra.datasets import open_dataset

    f = factory_for(ros1=True)
    world = scene()[:400]
    sweep = np.linspace(-0.0877, 0.0, len(world))
    stamp_ns = STAMP_SEC * 1_000_000_000 + STAMP_NSEC
    point_ns = stamp_ns + np.round(sweep * 1e9).astype(np.int64)
    x_at = (point_ns - STAMP_SEC * 1_000_000_000) * 1e-9
    seen = (world - np.c_[x_at, np.zeros((len(world), 2))]).astype(np.float32)
    tf_rows = [
        (STAMP_SEC * 1_000_000_000 + ms * 1_000_000, "map", "luminar_lidar", make_pose(np.eye(3), [ms * 1e-3, 0, 0]))
        for ms in range(-200, 400, 50)
    ]
    rows = [("/tf", "tf2_msgs/msg/TFMessage", ns, f.tf([row])) for row in tf_rows for ns in [row[0]]]
    cloud = luminar_cloud(f, STAMP_SEC, STAMP_NSEC, seen, point_ns // 10**9, point_ns % 10**9)
    rows.append(("/luminar_pointcloud", "sensor_msgs/msg/PointCloud2", stamp_ns, cloud))
    frame = open_dataset(write_test_bag(tmp_path / "tf.bag", rows, ros1=True))[0]
    at_stamp = world - [STAMP_NSEC * 1e-9, 0, 0]  # the street from the sensor at the stamp
    assert np.abs(seen - at_stamp).max() == pytest.approx(0.0877, abs=1e-4)  # skewed before
    np.testing.assert_allclose(frame.points, at_stamp, atol=2e-5)  # float32 metres
    assert frame.point_times is None


def test_map_with_poses_odometry_on_a_bag_whose_odometry_has_no_child_frame(tmp_path, capsys):
    """`--poses odometry` maps the bag (it stopped at the odometry topic's TF check before), the
    scans are deskewed by their split times, and without it the one line names the empty frame."""
    bag = luminar_bag(tmp_path / "luminar.bag")
    refused = tmp_path / "refused.terra"
    assert run(["map", str(bag), "--out", str(refused)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and not refused.exists()
    assert "odometry topic /base_pose_ground_truth ('odom' -> '') does not reach LiDAR frame 'luminar_lidar'" in err
    assert "frames: '', 'odom'" in err and "map with --poses odometry" in err

    out = tmp_path / "luminar.terra"
    assert run(["map", str(bag), "--out", str(out), "--poses", "odometry", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["pose_source"] == "odometry (KISS-ICP)"
    assert summary["odometry"]["scans"] == 5 and summary["odometry"]["deskewed"] == 4  # all but the first
    # 1 m/s at 10 Hz: 0.1 m a scan. The first deskewed scan meets a map of skewed ones (the first
    # scans have no velocity yet), a step of up to +0.07 m, after which the steps settle at 0.1 m.
    x = np.loadtxt(tmp_path / "luminar_poses_kitti.txt").reshape(-1, 3, 4)[:, 0, 3]
    assert np.all(np.diff(x) > 0.05) and np.diff(x)[-1] == pytest.approx(0.1, abs=0.01)


def test_inspect_describes_a_bag_without_poses_and_takes_poses(tmp_path, capsys):
    bag = luminar_bag(tmp_path / "luminar.bag", scans=2)
    assert run(["inspect", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "luminar.bag (rosbag): 2 frames" in out
    assert "  poses: no poses: map with --poses odometry (" in out and "('odom' -> '')" in out
    assert "time_sec@20, time_nsec@24" in out
    assert run(["inspect", str(bag), "--poses", "odometry", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["pose_source"] == "odometry (KISS-ICP)" and info["frames"] == 2
    assert run(["inspect", str(bag), "--poses", "gps"]) == 2
    assert "--poses 'gps': expected one of: auto, odometry" in capsys.readouterr().err
