"""terra.live.ros: ROS messages -> Session.add_frame arguments, with messages built by rosbags' own
types (Humble) and with stand-ins shaped as rclpy delivers them (array.array and list byte fields).
A drive fed as messages gives the same map as its frames fed directly."""

from __future__ import annotations

from array import array
from types import SimpleNamespace

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from terra.datasets.base import CameraFrame, Frame
from terra.datasets.ros.messages import MessageFactory
from terra.errors import TerraError
from terra.geometry import pose_from_xyz_quat
from terra.live import Session
from terra.live.ros import calibration_of, camera_frame, frame_arguments, pose_of, stamp_of
from terra.mapping.config import MappingConfig
from terra.sim.bag_writer import label_encoding
from tests.live.test_session import map_files

STORE = get_typestore(Stores.ROS2_HUMBLE)
FACTORY = MessageFactory(STORE, ros1=False)
FRAMES = 2


def as_rclpy(msg, data_kind: str = "array"):
    """A stand-in for the rclpy message of `msg`: the same attributes, `data` as rclpy gives it
    (array.array('B')) or as a plain list of ints."""
    fields = {name: getattr(msg, name) for name in msg.__dataclass_fields__}
    raw = np.asarray(msg.data, np.uint8).tobytes()
    fields["data"] = array("B", raw) if data_kind == "array" else list(raw)
    return SimpleNamespace(**fields)


def messages_of(frame: Frame) -> tuple:
    """The frame as a node receives it: PointCloud2, a TF transform map -> lidar, and per camera
    an rgb8 Image, its CameraInfo and mono16 label images."""
    ns = int(round(frame.stamp * 1e9))
    times = np.zeros(len(frame.points), np.uint32)
    cloud = FACTORY.pointcloud2(
        ns, "lidar", frame.points, frame.intensity, times, frame.point_labels, frame.point_instances
    )
    tf = FACTORY.tf([(ns, "map", "lidar", frame.T_map_lidar)]).transforms[0]
    cameras = []
    for cam in frame.cameras:
        cns, cal = int(round(cam.stamp * 1e9)), cam.calibration
        labels = [
            FACTORY.image(cns, cal.name, ids, label_encoding(ids))
            for ids in (cam.semantic, cam.instance)
            if ids is not None
        ]
        cameras.append(
            (FACTORY.image(cns, cal.name, cam.image, "rgb8"), FACTORY.camera_info(cns, cal.name, cal), *labels)
        )
    return cloud, tf, cameras


def test_a_drive_fed_as_messages_equals_its_frames_fed_directly(sim_sources, tmp_path):
    dataset = sim_sources["dataset"]
    by_messages = Session(tmp_path / "messages.terra", dataset.classes, MappingConfig(), graph=False, name="drive")
    direct = Session(tmp_path / "direct.terra", dataset.classes, MappingConfig(), graph=False, name="drive")
    for i in range(FRAMES):
        frame = dataset[i]
        cloud, tf, cameras = messages_of(frame)
        images = []
        for image, info, semantic, instance in cameras:
            cal = calibration_of(info, info.header.frame_id, frame.cameras[0].calibration.T_cam_lidar)
            images.append(camera_frame(as_rclpy(image), cal, semantic, instance))
        args = frame_arguments(as_rclpy(cloud, "list" if i else "array"), pose_of(tf), images)
        assert by_messages.add_frame(**args)
        # The same scan handed over as arrays, with the pose and stamps as the messages carry them.
        assert np.allclose(args["T_map_lidar"], frame.T_map_lidar, atol=1e-9)
        assert args["stamp"] == pytest.approx(frame.stamp, abs=1e-9)
        np.testing.assert_array_equal(args["points"], frame.points)
        np.testing.assert_array_equal(args["labels"], frame.point_labels)
        np.testing.assert_array_equal(args["times"], np.zeros(len(frame.points)))
        cams = [
            CameraFrame(c.calibration, stamp_of(m[0]), c.image, c.semantic, c.instance, name=c.name)
            for c, m in zip(frame.cameras, cameras, strict=True)
        ]
        assert direct.add_frame(
            frame.points,
            args["T_map_lidar"],
            args["stamp"],
            args["times"],
            cams,
            frame.intensity,
            frame.point_labels,
            frame.point_instances,
        )
        for got, want in zip(images, frame.cameras, strict=True):
            np.testing.assert_array_equal(got.image, want.image)
            np.testing.assert_array_equal(got.semantic, want.semantic)
            np.testing.assert_array_equal(got.calibration.K, want.calibration.K)
            assert got.calibration.model == want.calibration.model and got.calibration.width == want.calibration.width
    by_messages.snapshot()
    direct.snapshot()
    assert map_files(tmp_path / "messages.terra") == map_files(tmp_path / "direct.terra")


def test_rclpy_byte_fields_decode_as_rosbags_messages_do():
    points = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [-4.0, 5.5, 0.25], [np.nan, 1.0, 1.0]], np.float32)
    cloud = FACTORY.pointcloud2(
        1_500_000_000, "lidar", points, np.arange(4, dtype=np.float32), np.array([0, 10, 20, 30], np.uint32)
    )
    T = pose_from_xyz_quat(np.array([1.0, -2.0, 0.5, 0.0, 0.0, np.sin(0.3), np.cos(0.3)]))
    reference = frame_arguments(cloud, T)
    for kind in ("array", "list"):
        args = frame_arguments(as_rclpy(cloud, kind), T)
        for name in ("points", "intensity", "times"):
            np.testing.assert_array_equal(args[name], reference[name])
    # (0, 0, 0) is "no return" and NaN rows are dropped; times are seconds after the stamp.
    np.testing.assert_array_equal(reference["points"], points[[0, 2]])
    np.testing.assert_allclose(reference["times"], [0.0, 20e-9])
    assert reference["stamp"] == 1.5 and reference["labels"] is None

    rgb = np.random.default_rng(0).integers(0, 256, (4, 6, 3), dtype=np.uint8)
    bgr = FACTORY.image(7, "cam", rgb[:, :, ::-1], "bgr8")
    info = FACTORY.camera_info(7, "cam", _calibration())
    cal = calibration_of(as_rclpy_info(info), "cam", np.eye(4))
    np.testing.assert_array_equal(camera_frame(as_rclpy(bgr), cal).image, rgb)
    jpeg = FACTORY.compressed_image(7, "cam", rgb)
    fake_jpeg = SimpleNamespace(header=jpeg.header, format=jpeg.format, data=bytes(np.asarray(jpeg.data).tobytes()))
    np.testing.assert_array_equal(camera_frame(fake_jpeg, cal).image, camera_frame(jpeg, cal).image)


def as_rclpy_info(info):
    """CameraInfo as rclpy gives it: `d` an array.array of doubles, `k`, `r`, `p` NumPy arrays."""
    fields = {name: getattr(info, name) for name in info.__dataclass_fields__}
    fields["d"] = array("d", np.asarray(info.d, float))
    return SimpleNamespace(**fields)


def _calibration():
    from terra.geometry import CameraCalibration

    return CameraCalibration("cam", 6, 4, np.array([[5.0, 0, 3], [0, 5.0, 2], [0, 0, 1]]), np.zeros(0), np.eye(4))


def test_poses_from_tf_odometry_and_pose_messages():
    t = STORE.types
    xyzq = [3.0, 4.0, -1.0, 0.0, np.sin(0.2), 0.0, np.cos(0.2)]
    want = pose_from_xyz_quat(np.array(xyzq))
    point = t["geometry_msgs/msg/Point"](x=xyzq[0], y=xyzq[1], z=xyzq[2])
    quat = t["geometry_msgs/msg/Quaternion"](x=xyzq[3], y=xyzq[4], z=xyzq[5], w=xyzq[6])
    pose = t["geometry_msgs/msg/Pose"](position=point, orientation=quat)
    header = FACTORY.header(2_000_000_000, "map")
    covariance = np.zeros(36)
    odometry = t["nav_msgs/msg/Odometry"](
        header=header,
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=covariance),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](
                linear=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
            ),
            covariance=covariance,
        ),
    )
    stamped = t["geometry_msgs/msg/PoseStamped"](header=header, pose=pose)
    transform = FACTORY.tf([(0, "map", "base_link", want)]).transforms[0]
    for msg in (odometry, stamped, pose, transform, transform.transform):
        np.testing.assert_allclose(pose_of(msg), want, atol=1e-12)
    assert stamp_of(odometry) == 2.0


def test_malformed_messages_name_the_field():
    cloud = FACTORY.pointcloud2(0, "lidar", np.ones((3, 3), np.float32))
    no_x = as_rclpy(cloud)
    no_x.fields = [f for f in cloud.fields if f.name != "x"]
    with pytest.raises(TerraError, match="no field 'x'"):
        frame_arguments(no_x, np.eye(4))
    bad = as_rclpy(cloud, "list")
    bad.data = [300] * len(bad.data)
    with pytest.raises(TerraError, match="field 'data' must hold bytes"):
        frame_arguments(bad, np.eye(4))
    text = as_rclpy(cloud)
    text.data = "not bytes"
    with pytest.raises(TerraError, match="field 'data' must hold bytes, got str"):
        frame_arguments(text, np.eye(4))
    with pytest.raises(TerraError, match="expected a Transform"):
        pose_of(cloud)
    with pytest.raises(TerraError, match="no header.stamp"):
        stamp_of(SimpleNamespace(data=b""))
    zero = FACTORY.tf([(0, "map", "lidar", np.eye(4))]).transforms[0]
    zero.transform.rotation.w = 0.0
    with pytest.raises(TerraError, match="zero length"):
        pose_of(zero)


def test_the_example_node_says_what_it_needs_without_ros(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    example = Path(__file__).resolve().parents[2] / "examples" / "ros2_live_node.py"
    done = subprocess.run(
        [sys.executable, str(example), "--out", str(tmp_path / "live.terra")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    try:
        import rclpy  # noqa: F401  # pyright: ignore[reportMissingImports]
    except ImportError:
        assert done.returncode == 2 and "needs ROS 2 (rclpy, tf2_ros, sensor_msgs)" in done.stderr
        assert not (tmp_path / "live.terra").exists()
