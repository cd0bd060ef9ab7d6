"""ROS 1 and ROS 2 bags ("rosbag"): a robot's own log as a frame stream, with no ROS installed.

Reads through `rosbags` (ROS 1 .bag, ROS 2 sqlite3 and mcap). One frame per LiDAR scan
(sensor_msgs/PointCloud2, stamped by its header), with:
- its pose T_map_lidar from /tf (interpolated at the scan stamp: linear translation, slerp
  rotation), or from a nav_msgs/Odometry topic, or none: then `needs_odometry` is set and
  `terra map` runs LiDAR odometry (terra.odometry) over the scans;
- each camera's nearest image (sensor_msgs/Image or CompressedImage, delivered RGB) within
  `max_gap` seconds, its CameraInfo intrinsics and lens model, and T_cam_lidar from /tf_static;
- per-point time, intensity and, when the cloud carries them, per-point labels. With poses from
  /tf or an odometry topic, a scan whose points carry times is deskewed: every point is moved to
  the LiDAR frame at the scan stamp with the pose at its own time (the frame then has no times).

The bag is indexed once when opened (where each message is, not the messages), so memory does
not grow with the bag's length and `dataset[i]` reads frame i directly (resume needs that).
Topics need no configuration when the bag makes them unambiguous; the `dataset` config section
(RosbagConfig) names them otherwise. Ground truth, when the recording comes from the simulator,
is read from beside the bag (classes.json, ground_truth/).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field

from terra.datasets.base import CameraFrame, ClassTable, Frame, PosesUnavailable, SemanticClass, SourceInfo
from terra.datasets.folder_io import read_classes
from terra.datasets.gnss import NOT_READ, GnssFixes, anchor_fields
from terra.datasets.registry import Loader
from terra.datasets.ros.bag import Bag, bag_paths, is_bag, recording_name
from terra.datasets.ros.camera_info import camera_from_info
from terra.datasets.ros.images import decode_compressed, decode_image, decode_labels
from terra.datasets.ros.index import BagIndex, Stream, index_bag
from terra.datasets.ros.navsat import choose_gnss, read_fixes
from terra.datasets.ros.pointcloud2 import decode_pointcloud2
from terra.datasets.ros.tf import TfTree, quoted
from terra.datasets.ros.topics import CameraTopics, choose_cameras, choose_lidar, choose_odometry
from terra.datasets.sync import nearest
from terra.errors import TerraError
from terra.geometry import CameraCalibration
from terra.schemas import Section

PREFERRED_MAP_FRAMES = ("map", "odom", "world")


class CameraTopicsConfig(Section):
    """One camera of the bag."""

    name: str | None = Field(default=None, description="camera name (default: the image topic's namespace)")
    image_topic: str = Field(..., description="sensor_msgs/Image or CompressedImage topic")
    info_topic: str | None = Field(
        default=None, description="sensor_msgs/CameraInfo topic (default: camera_info beside the image)"
    )
    semantic_topic: str | None = Field(
        default=None, description="optional label image (mono16 class ids) for the labels backend"
    )
    instance_topic: str | None = Field(default=None, description="optional label image (mono16 instance ids)")


class RosbagConfig(Section):
    """Options of the bag loader (the `dataset` section of a config file). Unset topics and frames
    are found in the bag when that is unambiguous."""

    lidar_topic: str | None = Field(default=None, description="sensor_msgs/PointCloud2 topic of the LiDAR")
    cameras: list[CameraTopicsConfig] | None = Field(
        default=None, description="cameras to use (default: every image topic with a camera_info beside it)"
    )
    lidar_frame: str | None = Field(
        default=None, description="TF frame of the LiDAR (default: the clouds' header.frame_id)"
    )
    map_frame: str | None = Field(
        default=None, description="TF frame the poses are in (default: map, odom or world above the LiDAR)"
    )
    poses: Literal["auto", "tf", "topic", "odometry"] = Field(
        default="auto",
        description="pose source: tf (/tf), topic (nav_msgs/Odometry), odometry (KISS-ICP on the scans), "
        "auto (the first that exists)",
    )
    odometry_topic: str | None = Field(default=None, description="nav_msgs/Odometry topic for poses: topic")
    gnss_topic: str | None = Field(
        default=None,
        description="sensor_msgs/NavSatFix topic whose fixes anchor the drive on the Earth (default: the bag's "
        "only one)",
    )
    max_gap: float = Field(default=0.05, gt=0.0, description="seconds an image may lie from its scan's stamp")
    max_pose_gap: float = Field(
        default=0.5, gt=0.0, description="seconds between the two TF samples a scan's pose is interpolated from"
    )
    deskew: bool = Field(
        default=True,
        description="with per-point times and poses from /tf or an odometry topic: move every point into the "
        "LiDAR frame at the scan stamp, with the pose at its own time",
    )


@dataclass
class _FrameRef:
    """Where frame i's messages are: its scan, pose, and per camera (index, image key, stamp, label keys)."""

    stamp: float
    cloud: tuple[str, int, int]
    T_map_lidar: np.ndarray
    cameras: list[tuple[int, tuple, float, tuple | None, tuple | None]] = field(default_factory=list)


class RosbagDataset:
    """Frames of a ROS 1 / ROS 2 recording (see the module docstring)."""

    def __init__(self, path: Path, config: RosbagConfig | None = None, show_progress: bool = True) -> None:
        self.path = Path(path)
        self.config = config = config or RosbagConfig()
        self.root = self.path if self.path.is_dir() else self.path.parent
        self.name = recording_name(bag_paths(self.path))
        self.classes: ClassTable = read_classes(self.root) or ClassTable([SemanticClass(0, "unlabeled")])
        self.skipped: dict[str, int] = {}
        self.skipped_notes: dict[str, str] = {}
        self._pose_lookup: tuple[TfTree, str] | None = (
            None  # (TF tree, map frame) when poses come from TF or an odometry topic: deskewing
        )
        self.bag = Bag(self.path)
        try:
            self._open(config, show_progress)
        except BaseException:  # a refused recording leaves no open file behind
            self.bag.close()
            raise

    def close(self) -> None:
        """Close the recording (frames can no longer be read)."""
        self.bag.close()

    def _open(self, config: RosbagConfig, show_progress: bool) -> None:
        """Topics, message index, poses, calibrations and frames of the open recording."""
        self.lidar_topic = choose_lidar(self.bag, config.lidar_topic)
        self.gnss_topic = choose_gnss(self.bag, config.gnss_topic)  # None: no receiver, or several unnamed
        self._anchor: dict | None | object = NOT_READ  # wgs84_anchor, read once
        self.camera_topics = choose_cameras(self.bag, config.cameras)
        odom_topic = choose_odometry(self.bag, config.odometry_topic) if config.poses in ("auto", "topic") else None
        if config.poses == "topic" and odom_topic is None:
            found = ", ".join(self.bag.topics_of_type("nav_msgs/msg/Odometry")) or "none"
            raise TerraError(
                f"{self.path}: poses: topic needs dataset.odometry_topic (nav_msgs/Odometry topics: {found})"
            )
        stamped = [self.lidar_topic] + [t for c in self.camera_topics for t in (c.image, c.semantic, c.instance) if t]
        self.index: BagIndex = self._index(stamped, odom_topic, show_progress)
        scans = self.index.streams[self.lidar_topic]
        if len(scans) == 0:
            raise TerraError(f"{self.path}: topic {self.lidar_topic} has no messages")
        first_cloud = self.bag.deserialize(self.index.first[self.lidar_topic], self.lidar_topic)
        decode_pointcloud2(first_cloud, f"{self.path} {self.lidar_topic}")  # an unsupported layout fails here
        self.lidar_frame = (config.lidar_frame or first_cloud.header.frame_id).lstrip("/")
        self.cloud_fields = [
            {"name": f.name, "offset": int(f.offset), "datatype": int(f.datatype), "count": int(f.count)}
            for f in first_cloud.fields
        ]
        poses, valid, self.pose_source, self.needs_odometry, self.map_frame = self._poses(scans.stamps, odom_topic)
        self.has_poses = bool(np.isfinite(poses).all()) if len(poses) else False
        self.calibrations = [self._calibration(cam) for cam in self.camera_topics]
        self._frames = self._pair(scans, poses, valid)
        if not self._frames:
            raise PosesUnavailable(
                f"{self.path}: no scan of {self.lidar_topic} has a pose ({self.pose_source}); "
                f"first: {self.skipped_notes.get('scans_without_pose', '')}"
            )

    # ------------------------------------------------------------------ setup
    def _index(self, stamped: list[str], odom_topic: str | None, show_progress: bool) -> BagIndex:
        """Where the messages of the chosen topics are (one pass over the bag; a recording that is
        still growing keeps its index up to date instead: terra/datasets/ros/follow.py)."""
        return index_bag(self.bag, stamped, odom_topic, show_progress)

    def _poses(self, stamps: np.ndarray, odom_topic: str | None):
        """(poses (S, 4, 4), valid (S,), source in words, needs odometry, map frame) at the scan stamps.
        PosesUnavailable when the configured (or found) pose source does not reach the LiDAR frame."""
        if self.config.poses == "odometry":
            return self._reference_poses(stamps)
        try:
            return self._source_poses(stamps, odom_topic)
        except PosesUnavailable:
            raise
        except TerraError as exc:  # a TF tree or odometry topic that does not reach the LiDAR frame
            raise PosesUnavailable(str(exc)) from None

    def _source_poses(self, stamps: np.ndarray, odom_topic: str | None):
        """_poses from /tf or the odometry topic (or none at all: then odometry is needed)."""
        mode, tree = self.config.poses, self.index.tf
        map_frame = self.config.map_frame or self._auto_map_frame(tree)
        if mode == "tf" and map_frame is None:
            raise PosesUnavailable(
                f"{self.path}: no moving TF transform above LiDAR frame '{self.lidar_frame}' gives poses "
                f"(frames: {quoted(tree.frames())}); set dataset.map_frame or another dataset.poses"
            )
        if mode in ("tf", "auto") and map_frame is not None:
            poses, valid = tree.lookup(map_frame, self.lidar_frame, stamps, self.config.max_pose_gap)
            self._pose_lookup = (tree, map_frame)
            return poses, valid, f"tf {map_frame} -> {self.lidar_frame}", False, map_frame
        odometry, odometry_frames = self.index.odometry, self.index.odometry_frames
        if odom_topic is not None and odometry is not None and odometry_frames is not None:
            parent, child = odometry_frames
            try:
                poses, valid = odometry.lookup(parent, self.lidar_frame, stamps, self.config.max_pose_gap)
            except TerraError as exc:
                raise PosesUnavailable(
                    f"{self.path}: odometry topic {odom_topic} ('{parent}' -> '{child}') does not reach LiDAR "
                    f"frame '{self.lidar_frame}' ({exc})"
                ) from None
            self._pose_lookup = (odometry, parent)
            return poses, valid, f"odometry topic {odom_topic} ({parent} -> {self.lidar_frame})", False, parent
        nan = np.full((len(stamps), 4, 4), np.nan)
        return nan, np.ones(len(stamps), bool), "odometry (KISS-ICP)", True, None

    def _reference_poses(self, stamps: np.ndarray):
        """_poses for `poses: odometry`: every scan is a frame; its pose (NaN where /tf cannot give one)
        only measures the odometry's error against /tf, so nothing about the TF tree can refuse the bag."""
        tree = self.index.tf
        map_frame = self.config.map_frame or self._auto_map_frame(tree)
        poses = np.full((len(stamps), 4, 4), np.nan)
        if map_frame is not None:
            try:
                found, valid = tree.lookup(map_frame, self.lidar_frame, stamps, self.config.max_pose_gap)
                poses[valid] = found[valid]
            except TerraError:
                pass  # no reference: the odometry's errors are not measured
        return poses, np.ones(len(stamps), bool), "odometry (KISS-ICP)", True, map_frame

    def _auto_map_frame(self, tree) -> str | None:
        """The preferred frame (map, odom, world) above the LiDAR's first moving transform, else the
        root of its tree; None when no moving transform lies above the LiDAR."""
        if self.lidar_frame not in tree.frames():
            return None
        chain = tree.ancestors(self.lidar_frame)
        moving = [k for k, f in enumerate(chain[:-1]) if f in tree.dynamic]
        if not moving:
            return None
        above = chain[moving[0] + 1 :]
        return next((f for f in PREFERRED_MAP_FRAMES if f in above), above[-1])

    def _calibration(self, cam: CameraTopics) -> CameraCalibration:
        raw = self.index.first.get(cam.info) if cam.info in self.index.first else None
        if raw is None:
            raw = next((r for _, _, r in self.bag.read([cam.info])), None)
        if raw is None:
            raise TerraError(f"{self.path}: camera {cam.name}: topic {cam.info} has no CameraInfo message")
        info = self.bag.deserialize(raw, cam.info)
        frame = info.header.frame_id.lstrip("/")
        where = f"{self.path} {cam.info}"
        tree = self.index.tf
        if not tree.is_static(frame, self.lidar_frame):
            raise TerraError(
                f"{where}: TF between camera frame '{frame}' and LiDAR frame '{self.lidar_frame}' moves; "
                "expected a fixed mount in /tf_static"
            )
        T_cam_lidar = tree.lookup(frame, self.lidar_frame, np.zeros(1))[0][0]
        size = None
        first = self.index.first.get(cam.image)
        if first is not None:  # an unsupported encoding fails here, before mapping starts
            image = self._decode_image(cam.image, first)
            size = (image.shape[1], image.shape[0])
        return camera_from_info(info, cam.name, T_cam_lidar, where, size)

    def _pair(self, scans: Stream, poses: np.ndarray, valid: np.ndarray) -> list[_FrameRef]:
        """Frames: scans with a pose, each with every camera's nearest image within max_gap."""
        streams = self.index.streams
        used = [np.zeros(len(streams[c.image]), bool) for c in self.camera_topics]
        frames = []
        for k in range(len(scans)):
            t = float(scans.stamps[k])
            if not valid[k]:
                self._skip(
                    "scans_without_pose",
                    f"scan at {t:.3f} s: no {self.pose_source} pose within {self.config.max_pose_gap} s samples",
                )
                continue
            ref = _FrameRef(t, scans.key(self.lidar_topic, k), poses[k])
            for c, cam in enumerate(self.camera_topics):
                images = streams[cam.image]
                j, gap = nearest(images.stamps, t)
                if gap > self.config.max_gap:
                    self._skip(
                        f"scans_without_image_{cam.name}",
                        f"scan at {t:.3f} s: nearest {cam.image} image is "
                        f"{gap:.3f} s away (max_gap {self.config.max_gap} s)",
                    )
                    continue
                used[c][j] = True
                stamp = float(images.stamps[j])
                ref.cameras.append(
                    (
                        c,
                        images.key(cam.image, j),
                        stamp,
                        self._label_key(cam.semantic, stamp),
                        self._label_key(cam.instance, stamp),
                    )
                )
            frames.append(ref)
        for c, cam in enumerate(self.camera_topics):
            unused = np.flatnonzero(~used[c])
            if unused.size:
                self._skip(
                    f"images_unpaired_{cam.name}",
                    f"{cam.image} image at {streams[cam.image].stamps[unused[0]]:.3f} s is no scan's nearest image",
                    int(unused.size),
                )
        return frames

    def _label_key(self, topic: str | None, stamp: float) -> tuple | None:
        if topic is None:
            return None
        stream = self.index.streams[topic]
        j, gap = nearest(stream.stamps, stamp)
        return stream.key(topic, j) if gap <= 1e-6 else None

    def gnss_fixes(self) -> GnssFixes | None:
        """The fixes of the bag's NavSatFix topic (terra.datasets.ros.navsat), or None without one."""
        if self.gnss_topic is None:
            return None
        fixes, left_out = read_fixes(self.bag, self.gnss_topic)
        if left_out:
            note = f"{self.gnss_topic}: NavSatFix messages without a fix (status < 0 or NaN)"
            self._skip("gnss_without_fix", note, left_out)
        return fixes

    def wgs84_anchor(self) -> dict | None:
        """The anchor of the poses' frame fitted to the bag's GNSS fixes (terra.datasets.gnss), or None:
        no NavSatFix topic, too few fixes, or poses that odometry will only compute while mapping.
        Read once (a pass over the fixes' topic), then kept."""
        if self._anchor is NOT_READ:
            self._anchor = self._fit_anchor()
        return self._anchor  # pyright: ignore[reportReturnType]  # read: a dict or None

    def _fit_anchor(self) -> dict | None:
        if self.needs_odometry or not self._frames:
            return None
        fixes = self.gnss_fixes()
        if fixes is None or len(fixes) == 0:
            return None
        stamps = np.array([f.stamp for f in self._frames])
        positions = np.array([f.T_map_lidar[:3, 3] for f in self._frames])
        return anchor_fields(stamps, positions, fixes, f"GNSS fixes of {self.name} ({self.gnss_topic})")

    def _skip(self, counter: str, note: str, count: int = 1) -> None:
        self.skipped[counter] = self.skipped.get(counter, 0) + count
        self.skipped_notes.setdefault(counter, note)

    # ------------------------------------------------------------------ frames
    def __len__(self) -> int:
        return len(self._frames)

    def __getitem__(self, index: int) -> Frame:
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range (0..{len(self) - 1})")
        ref = self._frames[index]
        keys = [ref.cloud] + [k for _, key, _, sem, inst in ref.cameras for k in (key, sem, inst) if k is not None]
        raws = self.bag.fetch(keys)
        if ref.cloud not in raws:
            raise TerraError(f"{self.path}: scan at {ref.stamp:.3f} s could not be read back from {self.lidar_topic}")
        where = f"{self.path} {self.lidar_topic} at {ref.stamp:.3f} s"
        cloud = decode_pointcloud2(self.bag.deserialize(raws[ref.cloud], self.lidar_topic, where), where)
        if self.config.deskew and self._pose_lookup is not None and cloud.times is not None and np.any(cloud.times):
            cloud.points, cloud.times = self._deskew(cloud.points, cloud.times, ref, self._pose_lookup), None
        cams = []
        for c, key, stamp, sem, inst in ref.cameras:
            camera = self._camera_frame(c, key, stamp, sem, inst, raws)
            if camera is not None:
                cams.append(camera)
        return Frame(
            index,
            ref.stamp,
            cloud.points,
            ref.T_map_lidar.copy(),
            cams,
            cloud.intensity,
            cloud.labels,
            cloud.instances,
            point_times=cloud.times,
        )

    def _deskew(
        self, points: np.ndarray, times: np.ndarray, ref: _FrameRef, pose_lookup: tuple[TfTree, str]
    ) -> np.ndarray:
        """Points measured at stamp + times (s) -> the LiDAR frame at the stamp: p' = T_lidar(stamp)^-1
        T_map_lidar(stamp + t) p, poses interpolated per distinct time (a spinning LiDAR's columns).
        Times past the pose data hold the last pose."""
        tree, target = pose_lookup
        unique, inverse = np.unique(times, return_inverse=True)
        T, _ = tree.lookup(target, self.lidar_frame, ref.stamp + unique, self.config.max_pose_gap)
        rel = np.linalg.inv(ref.T_map_lidar) @ T
        moved = np.einsum("nij,nj->ni", rel[inverse, :3, :3], points.astype(np.float64)) + rel[inverse, :3, 3]
        return moved.astype(np.float32)

    def _camera_frame(
        self, c: int, key: tuple, stamp: float, sem: tuple | None, inst: tuple | None, raws: dict
    ) -> CameraFrame | None:
        """Camera c's image of a frame, or None (counted) when it cannot be decoded."""
        cam, cal = self.camera_topics[c], self.calibrations[c]
        try:
            if key not in raws:
                raise TerraError(f"{self.path} {cam.image} at {stamp:.3f} s: message could not be read back")
            image = self._decode_image(cam.image, raws[key], stamp)
            labels = [
                decode_labels(self.bag.deserialize(raws[k], k[0]), f"{self.path} {k[0]} at {stamp:.3f} s")
                if k is not None and k in raws
                else None
                for k in (sem, inst)
            ]
        except TerraError as exc:
            self._skip("images_skipped_undecodable", str(exc))
            return None
        return CameraFrame(cal, stamp, image, labels[0], labels[1], name=f"{cam.image}@{stamp:.6f}")

    def _decode_image(self, topic: str, raw: bytes, stamp: float | None = None) -> np.ndarray:
        where = f"{self.path} {topic}" + (f" at {stamp:.3f} s" if stamp is not None else "")
        msg = self.bag.deserialize(raw, topic, where)
        if self.bag.topics[topic].msgtype.endswith("CompressedImage"):
            return decode_compressed(msg, where)
        return decode_image(msg, where)

    def global_map(self) -> np.ndarray | None:
        """Bags ship no global map."""
        return None

    def ground_truth(self):
        """Ground truth beside the bag (simulated recordings), else TerraError."""
        from terra.datasets.ground_truth import load_ground_truth

        return load_ground_truth(self.root)

    def info(self) -> SourceInfo:
        from terra.datasets.ros.describe import describe_dataset

        return describe_dataset(self)


def _detect(path: Path) -> bool:
    return is_bag(path)


def _open(path: Path, config: RosbagConfig) -> RosbagDataset:
    bag_paths(path)
    return RosbagDataset(path, config)


LOADER = Loader(
    "rosbag",
    _detect,
    _open,
    RosbagConfig,
    "ROS 1 .bag, ROS 2 bag folder (sqlite3 or mcap) or .mcap file: PointCloud2, images, CameraInfo, TF",
    without_poses={"poses": "odometry"},
)
