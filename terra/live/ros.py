"""ROS messages -> the arguments of `terra.live.Session.add_frame`, for a node of the user's own.

Terra never imports ROS: a ROS 2 node (examples/ros2_live_node.py) subscribes with rclpy and
hands the messages it receives to these functions, which read them by attribute with the same
decoders as the bag loader (terra/datasets/ros/): sensor_msgs/PointCloud2 (any field layout),
sensor_msgs/Image and CompressedImage, sensor_msgs/CameraInfo, a pose from a
geometry_msgs/TransformStamped (what a tf2 lookup returns), Transform, Pose, PoseStamped or
nav_msgs/Odometry. Byte fields may be what rclpy gives (array.array, bytes, lists) or what rosbags
gives (NumPy arrays). Every malformed message is a TerraError naming the field.

    args = frame_arguments(cloud, pose_of(tf_buffer.lookup_transform("map", cloud.header.frame_id, stamp)),
                           [camera_frame(image, calibration)])
    session.add_frame(**args)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from terra.datasets.base import CameraFrame
from terra.datasets.ros.bag import stamps_seconds, xyz_quat_of
from terra.datasets.ros.camera_info import camera_from_info
from terra.datasets.ros.images import decode_compressed, decode_image, decode_labels
from terra.datasets.ros.pointcloud2 import decode_pointcloud2
from terra.errors import TerraError
from terra.geometry import CameraCalibration, pose_from_xyz_quat

__all__ = ["calibration_of", "camera_frame", "frame_arguments", "pose_of", "stamp_of"]


def stamp_of(msg: Any, where: str = "message") -> float:
    """The header stamp of a stamped message, seconds; TerraError when it has none."""
    header = getattr(msg, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is None or not hasattr(stamp, "sec") or not hasattr(stamp, "nanosec"):
        raise TerraError(f"{where}: no header.stamp (sec, nanosec)")
    return stamps_seconds(stamp)


def pose_of(msg: Any, where: str = "pose") -> np.ndarray:
    """The 4x4 pose (metres) a message states: T_parent_child of a geometry_msgs/TransformStamped
    or Transform, the pose of nav_msgs/Odometry (child in header.frame_id), PoseStamped or Pose."""
    for path in (("transform",), ("pose", "pose"), ("pose",), ()):
        inner = msg
        for name in path:
            inner = getattr(inner, name, None)
        if inner is not None and (
            hasattr(inner, "translation")
            and hasattr(inner, "rotation")
            or hasattr(inner, "position")
            and hasattr(inner, "orientation")
        ):
            return pose_from_xyz_quat(xyz_quat_of(inner, where))
    raise TerraError(f"{where}: expected a Transform, TransformStamped, Pose, PoseStamped or Odometry message")


def calibration_of(
    info: Any, name: str, T_cam_lidar: np.ndarray, image_size: tuple[int, int] | None = None, where: str = "CameraInfo"
) -> CameraCalibration:
    """A camera's calibration from its sensor_msgs/CameraInfo and its mount T_cam_lidar (4x4, LiDAR
    -> the camera's optical frame, metres; e.g. `pose_of` of a tf2 lookup from the LiDAR frame to
    the camera's frame_id). `image_size` (width, height) fills a CameraInfo that leaves it 0."""
    return camera_from_info(info, name, np.asarray(T_cam_lidar, float), where, image_size)


def camera_frame(
    image: Any, calibration: CameraCalibration, semantic: Any = None, instance: Any = None, where: str = "Image"
) -> CameraFrame:
    """One camera's image with its label images (sensor_msgs/Image mono16 / 32SC1 class and instance
    ids, optional): a CameraFrame for `add_frame(images=[...])`, stamped by the image's header.
    A CompressedImage (it has `format`, no `encoding`) is decoded from its JPEG or PNG bytes."""
    stamp = stamp_of(image, where)
    pixels = decode_compressed(image, where) if hasattr(image, "format") else decode_image(image, where)
    labels = [
        decode_labels(m, f"{where} {kind}") if m is not None else None
        for kind, m in (("semantic", semantic), ("instance", instance))
    ]
    return CameraFrame(calibration, stamp, pixels, labels[0], labels[1], name=f"{calibration.name}@{stamp:.6f}")


def frame_arguments(
    cloud: Any, T_map_lidar: np.ndarray, images: Sequence[CameraFrame] = (), where: str = "PointCloud2"
) -> dict[str, Any]:
    """`Session.add_frame` keyword arguments for one sensor_msgs/PointCloud2 scan: its points (N, 3)
    metres in the cloud's frame, per-point times (s after the header stamp), intensity and labels
    when the cloud has those fields, its header stamp, the pose T_map_lidar (4x4) and the images
    taken with it. Points with a NaN coordinate or at (0, 0, 0) (no return) are dropped."""
    decoded = decode_pointcloud2(cloud, where)
    return {
        "points": decoded.points,
        "T_map_lidar": np.asarray(T_map_lidar, float),
        "stamp": stamp_of(cloud, where),
        "times": decoded.times,
        "images": list(images),
        "intensity": decoded.intensity,
        "labels": decoded.labels,
        "instances": decoded.instances,
    }
