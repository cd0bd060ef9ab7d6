"""The bag loader on real bag files written by the simulator (ROS 1 .bag, ROS 2 mcap) and on small
hand-made bags: what `terra inspect` reads, an independent reader's view of the same files, random
access, the map equal to the folder's, and bad input as one line with exit code 2."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

from terra.cli import run
from terra.datasets import open_dataset
from terra.errors import TerraError
from tests.datasets.fixtures_ros import FRAMES, factory_for, scan, write_test_bag

if TYPE_CHECKING:
    from terra.datasets.rosbag import RosbagDataset


def open_bag(path, format: str = "auto", options: dict | None = None) -> RosbagDataset:
    """open_dataset, checked to have opened the bag loader's dataset."""
    from terra.datasets.rosbag import RosbagDataset

    dataset = open_dataset(path, format, options)
    assert isinstance(dataset, RosbagDataset)
    return dataset


def _inspect(capsys, source) -> dict:
    assert run(["inspect", str(source), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("fmt", ["rosbag1", "rosbag2"])
def test_inspect_reads_the_calibration_topics_and_tf_as_written(capsys, sim_sources, fmt):
    info = _inspect(capsys, sim_sources[fmt])
    truth = sim_sources["dataset"].calibrations[0]
    cam = info["cameras"][0]
    assert info["format"] == "rosbag" and info["frames"] == FRAMES and info["pose_source"] == "tf map -> lidar"
    assert (cam["width"], cam["height"], cam["model"]) == (truth.width, truth.height, "pinhole")
    np.testing.assert_array_equal(cam["K"], truth.K)
    np.testing.assert_array_equal(cam["dist"], truth.dist)
    np.testing.assert_allclose(cam["T_cam_lidar"], truth.T_cam_lidar, atol=1e-12)
    topics = {t["topic"]: t for t in info["details"]["topics"]}
    assert (
        topics["/lidar/points"]["count"] == FRAMES and topics["/lidar/points"]["type"] == "sensor_msgs/msg/PointCloud2"
    )
    stamps = sim_sources["dataset"].trajectory.stamps[:FRAMES]
    assert topics["/lidar/points"]["rate_hz"] == pytest.approx((FRAMES - 1) / (stamps[-1] - stamps[0]), rel=1e-6)
    edges = {(e["parent"], e["child"]): e["static"] for e in info["details"]["tf"]}
    assert edges == {("base_link", "lidar"): True, ("base_link", "cam0_optical"): True, ("map", "base_link"): False}
    section = info["details"]["dataset"]
    assert section["lidar_topic"] == "/lidar/points" and section["poses"] == "tf"
    assert section["cameras"][0]["image_topic"] == "/cam0/image_raw/compressed"
    assert run(["inspect", str(sim_sources[fmt])]) == 0
    assert "dataset section" in capsys.readouterr().out


def test_mcap_bag_reads_with_the_mcap_package(sim_sources):
    """Our writer checked by a reader that is not ours: the `mcap` package lists the messages and
    rosbags' CDR deserializer (not our loader) decodes a cloud whose points equal the frame's."""
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore
    from rosbags.typesys.stores.ros2_humble import sensor_msgs__msg__PointCloud2

    path = next(Path(sim_sources["rosbag2"]).glob("*.mcap"))
    store = get_typestore(Stores.ROS2_HUMBLE)
    counts: dict[str, int] = {}
    first_cloud = None
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic == "/lidar/points" and first_cloud is None:
                assert schema is not None
                assert schema.name == "sensor_msgs/msg/PointCloud2" and channel.message_encoding == "cdr"
                first_cloud = store.deserialize_cdr(message.data, schema.name)
                assert message.log_time == 0
    assert counts["/lidar/points"] == FRAMES and counts["/cam0/camera_info"] == FRAMES and counts["/tf_static"] == 1
    assert isinstance(first_cloud, sensor_msgs__msg__PointCloud2)
    xyz = np.frombuffer(first_cloud.data.tobytes(), np.float32).reshape(-1, 7)[:, :3]
    np.testing.assert_array_equal(xyz, sim_sources["dataset"][0].points)


def test_random_access_equals_sequential_reading(sim_sources):
    dataset = open_dataset(sim_sources["rosbag1"])
    forward = [dataset[i] for i in range(len(dataset))]
    again = dataset[2]
    np.testing.assert_array_equal(again.points, forward[2].points)
    np.testing.assert_array_equal(again.cameras[0].image, forward[2].cameras[0].image)
    np.testing.assert_array_equal(again.T_map_lidar, forward[2].T_map_lidar)
    truth = sim_sources["dataset"]
    for i in range(len(dataset)):
        np.testing.assert_allclose(forward[i].T_map_lidar, truth[i].T_map_lidar, atol=1e-12)
        np.testing.assert_array_equal(forward[i].point_labels, truth[i].point_labels)


@pytest.mark.parametrize("fmt", ["rosbag1", "rosbag2"])
def test_a_dropped_or_refused_recording_leaves_no_open_file(sim_sources, tmp_path, fmt):
    import gc
    import warnings

    from terra.datasets.rosbag import RosbagConfig, RosbagDataset

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ResourceWarning)
        dataset = open_bag(sim_sources[fmt])
        assert len(dataset) and dataset[0].points.size
        reader = dataset.bag.reader
        del dataset
        gc.collect()
        assert reader.stack is None  # closed when the dataset went
        # A recording refused after it was opened (no such LiDAR topic) is closed at once.
        with pytest.raises(TerraError, match="no topic '/missing'"):
            RosbagDataset(sim_sources[fmt], RosbagConfig(lidar_topic="/missing"))
        gc.collect()
    assert not [w for w in caught if issubclass(w.category, ResourceWarning)]


@pytest.mark.slow
def test_map_from_the_bag_equals_the_map_from_the_folder(sim_sources, tmp_path):
    """Same counts, bank, points, terrain votes, image embeddings. What differs: T_map_cam by at
    most ~1e-15 m (the camera mount goes through a /tf_static quaternion), and so the fusion state's
    exact voxel sums.
    JPEG does not make the images differ: the bag and the folder hold the same JPEG bytes (same
    encoder and settings), which decode to the same pixels. The folder's own global map is not
    used, as a bag has none (with it, association differs)."""
    from terra.bundle import Bundle

    config = tmp_path / "c.yaml"
    config.write_text("mapping:\n  fusion:\n    use_global_map: false\n")
    bundles = {}
    for fmt in ("terra-folder", "rosbag2"):
        assert (
            run(["map", str(sim_sources[fmt]), "--out", str(tmp_path / f"{fmt}.terra"), "--config", str(config), "-q"])
            == 0
        )
        bundles[fmt] = Bundle(tmp_path / f"{fmt}.terra")
    folder, bag = bundles["terra-folder"], bundles["rosbag2"]
    differ = sorted(n for n, e in folder.files.items() if bag.files[n].sha256 != e.sha256)
    # The fusion state's float64 voxel sums carry the same ~1e-15 m (the scan poses too go through a
    # quaternion), below what the float32 map points resolve.
    assert differ in (["map/images/T_map_cam.npy"], ["map/images/T_map_cam.npy", "map/state/voxel_sums.npy"])
    np.testing.assert_allclose(folder.array("map/images/T_map_cam"), bag.array("map/images/T_map_cam"), atol=1e-12)
    np.testing.assert_allclose(folder.array("map/state/voxel_sums"), bag.array("map/state/voxel_sums"), atol=1e-9)
    meta_f, meta_b = folder.json("map/meta.json"), bag.json("map/meta.json")
    assert meta_f == meta_b  # the bag's name is the simulated world's, like the folder's


# ------------------------------------------------------------------------------ bad input
def _assert_one_line_exit_2(capsys, argv, fragment, out: Path | None = None):
    assert run(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and fragment in err, err
    if out is not None:
        assert not out.exists() and not list(out.parent.glob(f".{out.name}*"))


def test_truncated_and_corrupt_bags(capsys, sim_sources, tmp_path):
    bag1 = next(Path(sim_sources["rosbag1"]).glob("*.bag"))
    data = bag1.read_bytes()
    (tmp_path / "cut.bag").write_bytes(data[: len(data) // 2])
    _assert_one_line_exit_2(
        capsys, ["map", str(tmp_path / "cut.bag"), "--out", str(tmp_path / "a.terra")], "cut.bag", tmp_path / "a.terra"
    )
    mcap = next(Path(sim_sources["rosbag2"]).glob("*.mcap"))
    data = mcap.read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    _assert_one_line_exit_2(
        capsys,
        ["map", str(tmp_path / "cut.mcap"), "--out", str(tmp_path / "b.terra")],
        "cut.mcap",
        tmp_path / "b.terra",
    )
    (tmp_path / "bad.mcap").write_bytes(b"\x89GARBAGE" + data[8:])  # not an mcap file at all
    _assert_one_line_exit_2(capsys, ["inspect", str(tmp_path / "bad.mcap")], "bad.mcap")


def test_missing_topic_lists_the_topics_that_exist(capsys, sim_sources, tmp_path):
    config = tmp_path / "c.yaml"
    config.write_text("dataset:\n  lidar_topic: /os_cloud_node/points\n")
    _assert_one_line_exit_2(
        capsys,
        ["map", str(sim_sources["rosbag2"]), "--out", str(tmp_path / "m.terra"), "--config", str(config)],
        "no topic '/os_cloud_node/points' for the LiDAR; sensor_msgs/PointCloud2 topics: /lidar/points",
        tmp_path / "m.terra",
    )


def test_tf_that_does_not_connect_names_both_frames(capsys, tmp_path):
    f = factory_for()
    bag = write_test_bag(
        tmp_path / "bag",
        [
            ("/tf", "tf2_msgs/msg/TFMessage", 0, f.tf([(0, "map", "base_link", np.eye(4))])),
            ("/points", "sensor_msgs/msg/PointCloud2", 0, f.pointcloud2(0, "velodyne", scan())),
        ],
    )
    config = tmp_path / "c.yaml"
    config.write_text("dataset:\n  poses: tf\n  map_frame: map\n")
    _assert_one_line_exit_2(
        capsys,
        ["map", str(bag), "--out", str(tmp_path / "m.terra"), "--config", str(config)],
        "TF does not connect 'map' and 'velodyne'",
        tmp_path / "m.terra",
    )


def _camera_bag(tmp_path, encoding="rgb8", with_info=True):
    from terra.geometry import CameraCalibration

    f = factory_for(ros1=True)
    cal = CameraCalibration("cam", 8, 6, np.array([[5.0, 0, 4], [0, 5.0, 3], [0, 0, 1]]))
    rows = [
        (
            "/tf_static",
            "tf2_msgs/msg/TFMessage",
            0,
            f.tf([(0, "base", "lidar", np.eye(4)), (0, "base", "cam", np.eye(4))]),
        )
    ]
    for k in range(3):
        ns = k * 100_000_000
        rows.append(("/tf", "tf2_msgs/msg/TFMessage", ns, f.tf([(ns, "odom", "base", np.eye(4))])))
        rows.append(("/points", "sensor_msgs/msg/PointCloud2", ns, f.pointcloud2(ns, "lidar", scan(seed=k))))
        image = f.image(ns, "cam", np.full((6, 8, 3), 40 * k, np.uint8))
        image.encoding = encoding
        rows.append(("/cam/image", "sensor_msgs/msg/Image", ns, image))
        if with_info:
            rows.append(("/cam/camera_info", "sensor_msgs/msg/CameraInfo", ns, f.camera_info(ns, "cam", cal)))
    return write_test_bag(tmp_path / "cam.bag", rows, ros1=True)


def test_unsupported_encoding_and_missing_camera_info(capsys, tmp_path):
    bag = _camera_bag(tmp_path, encoding="yuv422")
    _assert_one_line_exit_2(
        capsys, ["map", str(bag), "--out", str(tmp_path / "m.terra")], "image encoding 'yuv422'", tmp_path / "m.terra"
    )
    (tmp_path / "nocam").mkdir()
    bag = _camera_bag(tmp_path / "nocam", with_info=False)
    config = tmp_path / "c.yaml"
    config.write_text("dataset:\n  cameras:\n  - image_topic: /cam/image\n")
    _assert_one_line_exit_2(
        capsys,
        ["map", str(bag), "--out", str(tmp_path / "n.terra"), "--config", str(config)],
        "no camera_info topic '/cam/camera_info'",
        tmp_path / "n.terra",
    )


def test_ros1_bag_with_odometry_frame_poses_and_camera(tmp_path):
    """A hand-made ROS 1 bag: poses through odom -> base -> lidar, images paired, info as stated."""
    dataset = open_bag(_camera_bag(tmp_path))
    assert len(dataset) == 3 and dataset.pose_source == "tf odom -> lidar"
    frame = dataset[2]
    assert frame.cameras[0].image.shape == (6, 8, 3) and frame.cameras[0].image[0, 0, 0] == 80
    np.testing.assert_array_equal(frame.points, scan(seed=2))
    assert dataset.calibrations[0].K[0, 0] == 5.0


def test_one_corrupt_image_is_skipped_and_counted(tmp_path):
    """The second of three JPEG images is cut short: that frame keeps its scan, loses its image."""
    f = factory_for()
    from terra.geometry import CameraCalibration

    cal = CameraCalibration("cam", 8, 6, np.array([[5.0, 0, 4], [0, 5.0, 3], [0, 0, 1]]))
    rows = [
        (
            "/tf_static",
            "tf2_msgs/msg/TFMessage",
            0,
            f.tf([(0, "base", "lidar", np.eye(4)), (0, "base", "cam", np.eye(4))]),
        )
    ]
    for k in range(3):
        ns = k * 100_000_000
        image = f.compressed_image(ns, "cam", np.full((6, 8, 3), 50, np.uint8))
        if k == 1:
            image.data = image.data[:30]
        rows += [
            ("/tf", "tf2_msgs/msg/TFMessage", ns, f.tf([(ns, "map", "base", np.eye(4))])),
            ("/points", "sensor_msgs/msg/PointCloud2", ns, f.pointcloud2(ns, "lidar", scan(seed=k))),
            ("/cam/image_raw/compressed", "sensor_msgs/msg/CompressedImage", ns, image),
            ("/cam/camera_info", "sensor_msgs/msg/CameraInfo", ns, f.camera_info(ns, "cam", cal)),
        ]
    dataset = open_bag(write_test_bag(tmp_path / "bag", rows))
    frames = [dataset[i] for i in range(len(dataset))]
    assert [len(fr.cameras) for fr in frames] == [1, 0, 1]
    assert dataset.skipped["images_skipped_undecodable"] == 1
    assert "0.100 s" in dataset.skipped_notes["images_skipped_undecodable"]


def _two_camera_rows(f, late_right_at: int):
    """Three scans; cameras left and right at each scan's stamp, except right's image `late_right_at`,
    which comes 0.2 s late (no scan within max_gap)."""
    from terra.geometry import CameraCalibration

    K = np.array([[5.0, 0, 4], [0, 5.0, 3], [0, 0, 1]])
    cams = {
        "left": CameraCalibration("left", 8, 6, K),
        "right": CameraCalibration("right", 8, 6, K, np.array([0.1, 0.01, 0, 0]), model="fisheye"),
    }
    mount = {"left": make_pose_y(0.3), "right": make_pose_y(-0.3)}
    rows = [
        (
            "/tf_static",
            "tf2_msgs/msg/TFMessage",
            0,
            f.tf([(0, "base", "lidar", np.eye(4))] + [(0, "base", f"{c}_optical", mount[c]) for c in cams]),
        )
    ]
    for k in range(3):
        ns = k * 100_000_000
        rows += [
            ("/tf", "tf2_msgs/msg/TFMessage", ns, f.tf([(ns, "map", "base", np.eye(4))])),
            ("/points", "sensor_msgs/msg/PointCloud2", ns, f.pointcloud2(ns, "lidar", scan(seed=k))),
        ]
        for c, cal in cams.items():
            t = ns + (200_000_000 if c == "right" and k == late_right_at else 0)
            rows += [
                (
                    f"/{c}/image_raw",
                    "sensor_msgs/msg/Image",
                    t,
                    f.image(t, f"{c}_optical", np.full((6, 8, 3), 10 * k, np.uint8)),
                ),
                (f"/{c}/camera_info", "sensor_msgs/msg/CameraInfo", t, f.camera_info(t, f"{c}_optical", cal)),
            ]
    return rows, cams, mount


def make_pose_y(y: float) -> np.ndarray:
    T = np.eye(4)
    T[1, 3] = y
    return T


def test_two_cameras_sqlite3_storage_and_unpaired_images_counted(tmp_path):
    from terra.geometry import invert_pose

    rows, cams, mount = _two_camera_rows(factory_for(), late_right_at=1)
    dataset = open_bag(write_test_bag(tmp_path / "bag", rows, sqlite=True))
    assert dataset.bag.storage == "rosbag2 (sqlite3)" and len(dataset) == 3
    assert [c.name for c in dataset.calibrations] == ["left", "right"]
    right = dataset.calibrations[1]
    assert right.model == "fisheye" and right.dist.tolist() == [0.1, 0.01, 0.0, 0.0]
    np.testing.assert_allclose(right.T_cam_lidar, invert_pose(mount["right"]), atol=1e-12)
    assert [len(dataset[i].cameras) for i in range(3)] == [2, 1, 2]
    assert dataset.skipped == {"scans_without_image_right": 1, "images_unpaired_right": 1}
    assert "0.100 s" in dataset.skipped_notes["scans_without_image_right"]


def test_poses_from_a_nav_msgs_odometry_topic(tmp_path):
    """No /tf: poses come from /odom (odom -> base) and the static base -> lidar mount."""
    from rosbags.typesys import Stores, get_typestore
    from scipy.spatial.transform import Rotation

    from terra.geometry import make_pose

    store = get_typestore(Stores.ROS2_HUMBLE)
    f, t = factory_for(store), store.types
    T_base_lidar = make_pose(Rotation.from_euler("z", 0.2).as_matrix(), np.array([0.4, 0.0, 1.1]))
    rows = [("/tf_static", "tf2_msgs/msg/TFMessage", 0, f.tf([(0, "base", "lidar", T_base_lidar)]))]
    for k in range(4):
        ns = k * 100_000_000
        q = Rotation.from_euler("z", 0.3 * k).as_quat()
        pose = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=1.0 * k, y=0.5, z=0.0),
            orientation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        odom = t["nav_msgs/msg/Odometry"](
            header=f.header(ns, "odom"),
            child_frame_id="base",
            pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](
                    linear=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                    angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                ),
                covariance=np.zeros(36),
            ),
        )
        rows.append(("/odom", "nav_msgs/msg/Odometry", ns, odom))
        if k < 3:  # scans halfway between odometry messages: interpolated
            rows.append(
                (
                    "/points",
                    "sensor_msgs/msg/PointCloud2",
                    ns + 50_000_000,
                    f.pointcloud2(ns + 50_000_000, "lidar", scan(seed=k)),
                )
            )
    dataset = open_bag(write_test_bag(tmp_path / "bag", rows))
    assert dataset.pose_source == "odometry topic /odom (odom -> lidar)" and len(dataset) == 3
    expected = make_pose(Rotation.from_euler("z", 0.3 * 1.5).as_matrix(), np.array([1.5, 0.5, 0.0])) @ T_base_lidar
    np.testing.assert_allclose(dataset[1].T_map_lidar, expected, atol=1e-12)


def test_a_bag_without_poses_maps_with_odometry(tmp_path):
    f = factory_for()
    rows = [
        (
            "/points",
            "sensor_msgs/msg/PointCloud2",
            k * 100_000_000,
            f.pointcloud2(k * 100_000_000, "lidar", scan(seed=0)),
        )
        for k in range(3)
    ]
    dataset = open_bag(write_test_bag(tmp_path / "bag", rows))
    assert dataset.needs_odometry and not dataset.has_poses and dataset.pose_source == "odometry (KISS-ICP)"


def test_two_lidar_topics_inspect_still_describes_and_map_asks_which(capsys, tmp_path):
    f = factory_for()
    rows = []
    for k in range(2):
        ns = k * 100_000_000
        rows += [
            ("/front/points", "sensor_msgs/msg/PointCloud2", ns, f.pointcloud2(ns, "front", scan(seed=k))),
            ("/rear/points", "sensor_msgs/msg/PointCloud2", ns, f.pointcloud2(ns, "rear", scan(seed=k))),
        ]
    bag = write_test_bag(tmp_path / "bag", rows)
    info = _inspect(capsys, bag)
    assert {t["topic"] for t in info["details"]["topics"]} == {"/front/points", "/rear/points"}
    assert "set dataset.lidar_topic" in info["details"]["problem"]
    _assert_one_line_exit_2(
        capsys,
        ["map", str(bag), "--out", str(tmp_path / "m.terra")],
        "2 PointCloud2 topics (/front/points, /rear/points)",
        tmp_path / "m.terra",
    )


def test_mapping_a_bag_resumes_after_an_interruption_to_the_same_bytes(sim_sources, tmp_path):
    """Random access is what resume needs: an interrupted run continues at its checkpoint, reading
    only the frames after it, and ends with the bytes of an uninterrupted run."""
    from terra.mapping.config import MappingConfig
    from terra.mapping.pipeline import run_mapping
    from tests.mapping.fixtures import folder_digest

    config = MappingConfig(checkpoint_every=2)
    reference = run_mapping(
        open_dataset(sim_sources["rosbag1"]), config, tmp_path / "ref.terra", show_progress=False
    ).bundle

    class Stopping:
        def __init__(self, source, stop_at=None):
            self.source, self.stop_at, self.loaded = source, stop_at, []
            self.name, self.classes = source.name, source.classes

        def __len__(self):
            return len(self.source)

        def __getitem__(self, index):
            if index == self.stop_at:
                raise KeyboardInterrupt
            self.loaded.append(index)
            return self.source[index]

        def global_map(self):
            return None

    out = tmp_path / "map.terra"
    with pytest.raises(KeyboardInterrupt):
        run_mapping(Stopping(open_dataset(sim_sources["rosbag1"]), stop_at=3), config, out, show_progress=False)
    again = Stopping(open_dataset(sim_sources["rosbag1"]))
    assert run_mapping(again, config, out, show_progress=False).resumed_from == 2
    assert again.loaded == [2, 3, 4]
    assert folder_digest(out) == folder_digest(reference.path)


def test_raw_image_bag_gives_the_simulator_pixels_and_jpeg_differs_by_under_one_level(sim_sources, tmp_path):
    from terra.sim.writer import write_dataset

    raw = open_bag(
        write_dataset(sim_sources["dataset"], tmp_path / "raw", format="rosbag1", progress=False, bag_images="raw")
    )
    jpeg = open_dataset(sim_sources["rosbag2"])
    assert raw.camera_topics[0].image == "/cam0/image_raw"
    exact = raw[1].cameras[0].image
    np.testing.assert_array_equal(exact, sim_sources["dataset"][1].cameras[0].image)
    lossy = jpeg[1].cameras[0].image.astype(int)
    assert 0 < np.abs(lossy - exact).mean() < 1.0


def _ros1_records(data: bytes, start: int, end: int):
    """(header fields, data bytes) of each ROS bag v2.0 record in data[start:end]: a record is a
    4-byte header length, `name=value` fields each with a 4-byte length, a 4-byte data length, data."""
    import struct

    pos = start
    while pos < end:
        (hlen,) = struct.unpack_from("<I", data, pos)
        fields, p = {}, pos + 4
        while p < pos + 4 + hlen:
            (flen,) = struct.unpack_from("<I", data, p)
            name, _, value = data[p + 4 : p + 4 + flen].partition(b"=")
            fields[name.decode()] = value
            p += 4 + flen
        (dlen,) = struct.unpack_from("<I", data, p)
        yield fields, data[p + 4 : p + 4 + dlen]
        pos = p + 4 + dlen


def test_ros1_bag_reads_with_a_hand_written_parser(sim_sources):
    """The ROS 1 bag checked without rosbags: the bag v2.0 record layout and the ROS 1 wire format
    of PointCloud2 parsed by hand (uncompressed chunks, as the simulator writes them)."""
    import struct

    data = next(Path(sim_sources["rosbag1"]).glob("*.bag")).read_bytes()
    assert data.startswith(b"#ROSBAG V2.0\n")
    topics, clouds = {}, []
    for fields, chunk in _ros1_records(data, 13, len(data)):
        if fields["op"] != b"\x05":  # chunks only (they hold the connections and messages)
            continue
        assert fields["compression"] == b"none"
        for inner, body in _ros1_records(chunk, 0, len(chunk)):
            if inner["op"] == b"\x07":  # connection: its topic
                topics[inner["conn"]] = inner["topic"].decode()
            elif inner["op"] == b"\x02" and topics.get(inner["conn"]) == "/lidar/points":
                clouds.append(body)
    assert len(clouds) == FRAMES
    body = clouds[3]
    _seq, sec, nsec, n = struct.unpack_from("<IIII", body, 0)
    p = 16 + n  # after the frame_id string
    height, width, nfields = struct.unpack_from("<III", body, p)
    p += 12
    for _ in range(nfields):
        (n,) = struct.unpack_from("<I", body, p)
        p += 4 + n + 9  # name, offset u32, datatype u8, count u32
    _big, point_step, _row_step, size = struct.unpack_from("<?III", body, p)
    points = np.frombuffer(body, np.uint8, size, p + 13).reshape(-1, point_step)[:, :12].copy().view("<f4")
    truth = sim_sources["dataset"][3]
    assert sec + nsec * 1e-9 == pytest.approx(truth.stamp, abs=1e-9) and height * width == len(truth.points)
    np.testing.assert_array_equal(points, truth.points)


def test_scans_are_deskewed_with_the_tf_poses_at_each_point_time(tmp_path):
    """The robot turns at 0.3 rad/s while moving at (1, -0.5, 0.1) m/s (TF every 10 ms); each
    point is measured at its column's time in a 0.1 s sweep. Deskewed, the scan is the scene in
    the LiDAR frame at the stamp."""
    from scipy.spatial.transform import Rotation

    from terra.geometry import invert_pose, make_pose, transform_points

    def T_map_lidar(t):
        return make_pose(Rotation.from_rotvec([0, 0, 0.3 * t]).as_matrix(), np.array([1.0, -0.5, 0.1]) * t)

    f = factory_for()
    stamp_ns = 1_000_000_000
    rows = [("/tf_static", "tf2_msgs/msg/TFMessage", 0, f.tf([(0, "base", "lidar", np.eye(4))]))]
    for k in range(0, 131):
        ns = stamp_ns - 100_000_000 + k * 10_000_000
        rows.append(("/tf", "tf2_msgs/msg/TFMessage", ns, f.tf([(ns, "map", "base", T_map_lidar(ns * 1e-9))])))
    world = np.random.default_rng(4).normal(0, 15, (1024, 3))
    times_ns = (np.arange(1024) * 97_656).astype(np.uint32)  # 1024 columns over 0.1 s
    seen = np.stack(
        [
            transform_points(invert_pose(T_map_lidar(1.0 + tn * 1e-9)), world[i : i + 1])[0]
            for i, tn in enumerate(times_ns)
        ]
    )
    rows.append(
        (
            "/points",
            "sensor_msgs/msg/PointCloud2",
            stamp_ns,
            f.pointcloud2(stamp_ns, "lidar", seen.astype(np.float32), times_ns=times_ns),
        )
    )
    dataset = open_dataset(write_test_bag(tmp_path / "bag", sorted(rows, key=lambda r: r[2])))
    frame = dataset[0]
    expected = transform_points(invert_pose(T_map_lidar(1.0)), world)
    assert frame.point_times is None
    assert np.abs(seen - expected).max() > 0.1  # the skew is real
    np.testing.assert_allclose(frame.points, expected, atol=2e-5)  # float32 points
    raw = open_dataset(tmp_path / "bag", options={"deskew": False})[0]
    np.testing.assert_allclose(raw.points, seen, atol=1e-5)
    assert raw.point_times is not None
    np.testing.assert_allclose(raw.point_times, times_ns * 1e-9)


def test_the_printed_dataset_section_is_a_valid_config_that_opens_the_same_bag(capsys, sim_sources, tmp_path):
    import yaml

    from terra.config import load_dataset_options

    info = _inspect(capsys, sim_sources["rosbag1"])
    config = tmp_path / "terra.yaml"
    config.write_text(yaml.safe_dump({"dataset": info["details"]["dataset"]}))
    dataset = open_bag(sim_sources["rosbag1"], "rosbag", load_dataset_options(config))
    assert dataset.lidar_topic == "/lidar/points" and dataset.pose_source == info["pose_source"]
    assert [c.semantic for c in dataset.camera_topics] == ["/cam0/semantic"] and len(dataset) == FRAMES
    config.write_text("dataset:\n  lidar_topc: /lidar/points\n")
    with pytest.raises(TerraError, match=r"\[rosbag\]: field 'lidar_topc'"):
        open_dataset(sim_sources["rosbag1"], "rosbag", load_dataset_options(config))


@pytest.mark.parametrize("static", [True, False])
@pytest.mark.parametrize(
    "rotation, fragment",
    [((0.0, 0.0, 0.0, 0.0), "quaternion has zero length"), ((float("nan"), 0.0, 0.0, 1.0), "must be finite")],
)
def test_a_degenerate_transform_is_one_line(capsys, tmp_path, static, rotation, fragment):
    f = factory_for()
    message = f.tf([(0, "map", "velodyne", np.eye(4))])
    q = message.transforms[0].transform.rotation
    q.x, q.y, q.z, q.w = rotation
    topic = "/tf_static" if static else "/tf"
    bag = write_test_bag(
        tmp_path / "bag",
        [
            (topic, "tf2_msgs/msg/TFMessage", 0, message),
            ("/points", "sensor_msgs/msg/PointCloud2", 0, f.pointcloud2(0, "velodyne", scan())),
        ],
    )
    config = tmp_path / "c.yaml"
    config.write_text("dataset:\n  poses: tf\n  map_frame: map\n")
    argv = ["map", str(bag), "--out", str(tmp_path / "m.terra"), "--config", str(config)]
    _assert_one_line_exit_2(capsys, argv, fragment, tmp_path / "m.terra")


@pytest.mark.parametrize("keep", [0, 8, 9, 64])
@pytest.mark.parametrize("command", ["map", "inspect"])
def test_a_ros2_bag_cut_after_a_few_bytes_is_one_line(capsys, sim_sources, tmp_path, keep, command):
    import shutil

    bag = shutil.copytree(sim_sources["rosbag2"], tmp_path / "cut")
    mcap = next(bag.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[:keep])
    argv = ["map", str(bag), "--out", str(tmp_path / "a.terra")] if command == "map" else ["inspect", str(bag)]
    _assert_one_line_exit_2(capsys, argv, str(bag), tmp_path / "a.terra" if command == "map" else None)


def test_a_bag_of_unlabelled_images_warns_that_the_map_has_no_semantics(capsys, tmp_path):
    """The labels backend skips every image of a camera bag without label topics: the map is written,
    with one loud warning naming the reason and the remedy, and `terra build` says what the map lacks."""
    bag = _camera_bag(tmp_path)
    out = tmp_path / "m.terra"
    assert run(["map", str(bag), "--out", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    warnings = [line for line in err.splitlines() if "warning" in line]
    assert len(warnings) == 1 and "all 3 images were skipped" in warnings[0], err
    assert "perception.backend: models" in warnings[0] and "no semantic labels" in warnings[0]
    _assert_one_line_exit_2(capsys, ["build", str(out)], "the map has no camera terrain semantics")


def test_strict_refuses_a_map_whose_images_were_all_skipped(capsys, tmp_path):
    """`--strict`: exit 2 with one line naming the reason and the remedy, nothing written, and an
    existing bundle at --out (with --overwrite) left as it was."""
    bag = _camera_bag(tmp_path)
    out = tmp_path / "m.terra"
    assert run(["map", str(bag), "--out", str(out), "--strict", "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("terra: error: --strict: all 3 images were skipped (")
    assert "perception.backend: models" in err and "label topics" in err and "nothing was written" in err
    assert not out.exists() and not list(tmp_path.glob("m.terra.*"))
    assert run(["map", str(bag), "--out", str(out), "-q"]) == 0  # without --strict: written, with the warning
    capsys.readouterr()
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert run(["map", str(bag), "--out", str(out), "--strict", "--overwrite", "-q"]) == 2
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert not list(tmp_path.glob("m.terra.*"))
