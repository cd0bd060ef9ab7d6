"""The simulated drive as a real ROS bag (ROS 1 `.bag` or ROS 2 mcap), written with `rosbags`.

Topics (log time = header stamp = the frame's stamp):
- /tf_static: base_link -> lidar and base_link -> <camera>_optical (the mounts);
- /tf: map -> base_link, the pose the robot reports (drifted when the config drifts it);
- /lidar/points: PointCloud2, x y z intensity (float32), t (uint32 ns after the stamp; 0, as the
  simulated LiDAR captures a scan at one instant), label and instance (uint32, the simulator's ids);
- /<camera>/image_raw/compressed (JPEG, quality 92, no chroma subsampling, as the folder layout
  writes) or /<camera>/image_raw (rgb8); /<camera>/camera_info; /<camera>/semantic and
  /<camera>/instance (mono16 label images; 32SC1 when an image holds an id above 65535);
- /gnss/fix: sensor_msgs/NavSatFix, one per frame, when the simulator carries a receiver (`sim.gnss`).
The folder also gets classes.json and ground_truth/ (written by terra.sim.writer), which the bag
loader reads from beside the bag.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from terra.datasets.base import Dataset, GnssDataset
from terra.datasets.ros.messages import MessageFactory
from terra.errors import TerraError
from terra.geometry import invert_pose
from terra.progress import progress

MAP, BASE, LIDAR = "map", "base_link", "lidar"
LIDAR_TOPIC = "/lidar/points"
GNSS_TOPIC, GNSS_FRAME = "/gnss/fix", "gnss"
IMAGE_FORMATS = ("jpeg", "raw")


def label_encoding(labels: np.ndarray) -> str:
    """mono16 when every id fits 16 bits (what most ROS tools display), else 32SC1: ids are never cut."""
    return "mono16" if labels.size == 0 or (int(labels.min()) >= 0 and int(labels.max()) <= 0xFFFF) else "32SC1"


def optical_frame(camera: str) -> str:
    return f"{camera}_optical"


def write_bag(
    dataset: Dataset, root: Path, version: int, image_format: str = "jpeg", show_progress: bool = True
) -> Path:
    """Write every frame of `dataset` (a SimDataset: it needs `lidar.T_base_lidar`) as a bag in
    the existing folder `root`: ROS 1 `<name>.bag` (version 1) or a ROS 2 mcap bag whose
    metadata.yaml and .mcap sit directly in `root` (version 2). Returns the bag path."""
    from rosbags.typesys import Stores, get_typestore

    lidar = getattr(dataset, "lidar", None)  # the simulator's LiDAR mount: not part of the Dataset protocol
    if lidar is None:
        raise TerraError(f"{dataset.name}: bags are written from simulated datasets (lidar.T_base_lidar)")
    ros1 = version == 1
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    factory = MessageFactory(store, ros1)
    name = dataset.name
    fixes = dataset.gnss_fixes() if isinstance(dataset, GnssDataset) else None  # one per frame
    with _open_writer(root, name, ros1) as writer:
        topics = _Topics(writer, store, ros1)
        T_base_lidar = lidar.T_base_lidar
        T_lidar_base = invert_pose(T_base_lidar)
        for i in progress(range(len(dataset)), desc="writing bag", total=len(dataset), enabled=show_progress):
            frame = dataset[i]
            ns = int(round(float(frame.stamp) * 1e9))
            if i == 0:
                mounts = [(ns, BASE, LIDAR, T_base_lidar)]
                mounts += [
                    (ns, BASE, optical_frame(c.calibration.name), T_base_lidar @ invert_pose(c.calibration.T_cam_lidar))
                    for c in frame.cameras
                ]
                topics.write("/tf_static", "tf2_msgs/msg/TFMessage", ns, factory.tf(mounts), factory)
            topics.write(
                "/tf",
                "tf2_msgs/msg/TFMessage",
                ns,
                factory.tf([(ns, MAP, BASE, frame.T_map_lidar @ T_lidar_base)]),
                factory,
            )
            if fixes is not None:
                fix = factory.navsatfix(ns, GNSS_FRAME, fixes.lat[i], fixes.lon[i], fixes.alt[i], fixes.std[i])
                topics.write(GNSS_TOPIC, "sensor_msgs/msg/NavSatFix", ns, fix, factory)
            times = np.zeros(len(frame.points), np.uint32)
            cloud = factory.pointcloud2(
                ns, LIDAR, frame.points, frame.intensity, times, frame.point_labels, frame.point_instances
            )
            topics.write(LIDAR_TOPIC, "sensor_msgs/msg/PointCloud2", ns, cloud, factory)
            for cam in frame.cameras:
                _write_camera(topics, factory, cam, int(round(float(cam.stamp) * 1e9)), image_format)
    if ros1:
        return root / f"{name}.bag"
    return root


def _write_camera(topics: _Topics, factory: MessageFactory, cam, ns: int, image_format: str) -> None:
    cal = cam.calibration
    ns_topic, frame_id = f"/{cal.name}", optical_frame(cal.name)
    if image_format == "jpeg":
        topics.write(
            f"{ns_topic}/image_raw/compressed",
            "sensor_msgs/msg/CompressedImage",
            ns,
            factory.compressed_image(ns, frame_id, cam.image),
            factory,
        )
    else:
        topics.write(
            f"{ns_topic}/image_raw", "sensor_msgs/msg/Image", ns, factory.image(ns, frame_id, cam.image), factory
        )
    topics.write(
        f"{ns_topic}/camera_info", "sensor_msgs/msg/CameraInfo", ns, factory.camera_info(ns, frame_id, cal), factory
    )
    for kind, labels in (("semantic", cam.semantic), ("instance", cam.instance)):
        if labels is not None:
            topics.write(
                f"{ns_topic}/{kind}",
                "sensor_msgs/msg/Image",
                ns,
                factory.image(ns, frame_id, labels, label_encoding(labels)),
                factory,
            )


class _Topics:
    """Connections opened on first use, in a fixed order (so the same data gives the same bytes)."""

    def __init__(self, writer, store, ros1: bool) -> None:
        self.writer, self.store, self.ros1 = writer, store, ros1
        self.connections: dict[str, object] = {}

    def write(self, topic: str, msgtype: str, ns: int, msg, factory: MessageFactory) -> None:
        if topic not in self.connections:
            self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)
        self.writer.write(self.connections[topic], ns, factory.serialize(msg, msgtype))


class _open_writer:
    """A rosbags writer as a context manager; a ROS 2 bag's files are moved up into `root`."""

    def __init__(self, root: Path, name: str, ros1: bool) -> None:
        self.root, self.name, self.ros1 = Path(root), name, ros1

    def __enter__(self):
        if self.ros1:
            from rosbags.rosbag1 import Writer

            self.writer = Writer(self.root / f"{self.name}.bag")
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            self.writer = Writer(
                self.root / self.name, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP
            )
        self.writer.open()
        return self.writer

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.writer.abort()  # removes what was written; the caller's folder is discarded anyway
            return
        self.writer.close()
        if not self.ros1:
            inner = self.root / self.name
            for item in sorted(inner.iterdir()):
                shutil.move(str(item), self.root / item.name)
            inner.rmdir()
