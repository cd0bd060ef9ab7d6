"""The checks a frame handed to a live session passes before it is fused.

A live frame comes from a program (a ROS node, a network client), not from a file Terra opened, so
everything is checked at this boundary: shapes and dtypes, finite values, a rigid pose, a stamp
that moves forward, sizes within limits. Each refusal is a `LiveFrameError`: one line naming the
field and what was expected, and a short `reason` the session counts frames by. Non-finite scan
points are not a refusal: real drivers write NaN for "no return", and fusion drops and counts them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from terra.datasets.base import CameraFrame, Frame
from terra.errors import TerraError

MAX_POINTS = 4_000_000  # points per scan (a 128-beam LiDAR gives about 260,000)
MAX_PIXELS = 50_000_000  # pixels per image
MAX_CAMERAS = 16
MAX_TRANSLATION = 1e7  # metres from the map origin, as everywhere in Terra
ROTATION_TOLERANCE = 1e-3  # |R^T R - I| and |det R - 1| of a rigid pose


class LiveFrameError(TerraError):
    """A frame refused at the live boundary. `reason`: the counter it is counted under."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


def check_live_frame(
    points: object,
    T_map_lidar: object,
    stamp: object,
    times: object = None,
    images: Sequence[CameraFrame] = (),
    intensity: object = None,
    labels: object = None,
    instances: object = None,
    last_stamp: float | None = None,
) -> Frame:
    """A Frame of the checked arrays (index set by the mapper); LiveFrameError otherwise."""
    xyz = _points(points)
    n = xyz.shape[0]
    pose = check_pose(T_map_lidar)
    when = _stamp(stamp, last_stamp)
    return Frame(
        index=-1,
        stamp=when,
        points=xyz,
        T_map_lidar=pose,
        cameras=_cameras(images, when),
        intensity=_per_point(intensity, n, "intensity", np.float32, finite=False),
        point_labels=_per_point(labels, n, "labels", np.int32),
        point_instances=_per_point(instances, n, "instances", np.int32),
        point_times=_per_point(times, n, "times", np.float64),
    )


def _points(points: object) -> np.ndarray:
    array = _numeric(points, "points")
    if array.ndim != 2 or array.shape[1] < 3:
        raise LiveFrameError("bad_points", f"points: expected an (N, 3) array of metres, got shape {array.shape}")
    if array.shape[0] > MAX_POINTS:
        raise LiveFrameError("too_large", f"points: {array.shape[0]} points, at most {MAX_POINTS} per scan")
    return np.ascontiguousarray(array[:, :3], dtype=np.float32)


def check_pose(T: object, field: str = "T_map_lidar") -> np.ndarray:
    """A finite rigid 4x4 pose (rotation orthonormal with determinant +1, last row 0 0 0 1,
    translation within 1e7 m) as float64; LiveFrameError naming `field` otherwise."""
    pose = _numeric(T, field).astype(np.float64)
    if pose.shape != (4, 4):
        raise LiveFrameError("bad_pose", f"{field}: expected a 4x4 pose, got shape {pose.shape}")
    if not np.isfinite(pose).all():
        raise LiveFrameError("bad_pose", f"{field}: the pose holds NaN or infinity")
    rotation = pose[:3, :3]
    off = float(np.abs(rotation.T @ rotation - np.eye(3)).max())
    if off > ROTATION_TOLERANCE or abs(float(np.linalg.det(rotation)) - 1.0) > ROTATION_TOLERANCE:
        raise LiveFrameError(
            "bad_pose",
            f"{field}: the rotation is not rigid (|R^T R - I| = {off:.3g}, det {np.linalg.det(rotation):.3g})",
        )
    if np.abs(pose[3] - [0.0, 0.0, 0.0, 1.0]).max() > 0.0:
        raise LiveFrameError("bad_pose", f"{field}: the last row must be 0 0 0 1")
    if float(np.abs(pose[:3, 3]).max()) > MAX_TRANSLATION:
        raise LiveFrameError("bad_pose", f"{field}: translation beyond {MAX_TRANSLATION:.0e} m")
    return pose


def _stamp(stamp: object, last_stamp: float | None) -> float:
    if isinstance(stamp, bool) or not isinstance(stamp, int | float | np.integer | np.floating):
        raise LiveFrameError("bad_stamp", f"stamp: expected seconds as a number, got {type(stamp).__name__}")
    value = float(stamp)
    if not math.isfinite(value):
        raise LiveFrameError("bad_stamp", "stamp: must be finite seconds")
    if last_stamp is not None and value <= last_stamp:
        raise LiveFrameError(
            "stamp_back", f"stamp: {value:.6f} s does not follow the last fused frame's {last_stamp:.6f} s"
        )
    return value


def _per_point(values: object, n: int, field: str, dtype, finite: bool = True) -> np.ndarray | None:
    if values is None:
        return None
    array = _numeric(values, field)
    if array.shape != (n,):
        raise LiveFrameError(f"bad_{field}", f"{field}: expected ({n},), one value per point, got shape {array.shape}")
    if finite and not np.isfinite(array).all():
        raise LiveFrameError(f"bad_{field}", f"{field}: holds NaN or infinity")
    if np.issubdtype(np.dtype(dtype), np.integer) and not np.issubdtype(array.dtype, np.integer):
        raise LiveFrameError(f"bad_{field}", f"{field}: expected integer ids, got {array.dtype}")
    return array.astype(dtype)


def _cameras(images: Sequence[CameraFrame], stamp: float) -> list[CameraFrame]:
    if not isinstance(images, Sequence) or isinstance(images, str | bytes):
        raise LiveFrameError("bad_image", "images: expected a sequence of CameraFrame")
    if len(images) > MAX_CAMERAS:
        raise LiveFrameError("too_large", f"images: {len(images)} cameras, at most {MAX_CAMERAS}")
    checked = []
    for c, camera in enumerate(images):
        where = f"images[{c}]"
        if not isinstance(camera, CameraFrame):
            raise LiveFrameError("bad_image", f"{where}: expected a CameraFrame, got {type(camera).__name__}")
        calib = camera.calibration
        if calib.height * calib.width > MAX_PIXELS:
            raise LiveFrameError("too_large", f"{where}: {calib.width} x {calib.height} pixels, at most {MAX_PIXELS}")
        image = np.asarray(camera.image)
        if image.shape != (calib.height, calib.width, 3) or image.dtype != np.uint8:
            raise LiveFrameError(
                "bad_image",
                f"{where}.image: expected ({calib.height}, {calib.width}, 3) uint8 RGB, "
                f"got {image.shape} {image.dtype}",
            )
        _stamp(camera.stamp, None)
        for name in ("semantic", "instance"):
            labels = getattr(camera, name)
            if labels is not None and np.asarray(labels).shape != (calib.height, calib.width):
                raise LiveFrameError(
                    "bad_image", f"{where}.{name}: expected ({calib.height}, {calib.width}) ids, got {np.shape(labels)}"
                )
        checked.append(camera)
    return checked


def _numeric(values: object, field: str) -> np.ndarray:
    try:
        array = np.asarray(values)
    except (ValueError, TypeError) as exc:
        raise LiveFrameError(f"bad_{field}", f"{field}: not an array ({exc})") from None
    if not np.issubdtype(array.dtype, np.number):  # booleans, strings and objects are not numbers
        raise LiveFrameError(f"bad_{field}", f"{field}: expected numbers, got dtype {array.dtype}")
    return array
