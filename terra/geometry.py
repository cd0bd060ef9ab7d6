"""Poses, camera projection and voxel keys.

Conventions: a pose `T_a_b` is a 4x4 homogeneous matrix taking points from frame b to frame a
(p_a = T_a_b @ p_b). Lengths are metres, angles radians. Camera frames are optical frames:
z forward, x right, y down. Image coordinates (u, v) are pixels with (0, 0) at the centre of the
top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation


def make_pose(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """4x4 pose from a 3x3 rotation and a translation in metres."""
    T = np.eye(4)
    T[:3, :3] = rotation
    T[:3, 3] = translation
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 pose (T_b_a from T_a_b)."""
    R = T[:3, :3]
    return make_pose(R.T, -R.T @ T[:3, 3])


def transform_points(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Points (N, 3) in frame b to frame a; keeps the input dtype."""
    R = T_a_b[:3, :3].astype(points_b.dtype, copy=False)
    t = T_a_b[:3, 3].astype(points_b.dtype, copy=False)
    return points_b @ R.T + t


def pose_from_xyz_quat(xyz_quat: np.ndarray) -> np.ndarray:
    """Pose from [tx, ty, tz, qx, qy, qz, qw] (metres; scalar-last unit quaternion)."""
    xyz_quat = np.asarray(xyz_quat, dtype=np.float64)
    if xyz_quat.shape != (7,):
        raise ValueError(f"expected 7 values [tx, ty, tz, qx, qy, qz, qw], got shape {xyz_quat.shape}")
    return make_pose(Rotation.from_quat(xyz_quat[3:]).as_matrix(), xyz_quat[:3])


def pose_to_xyz_quat(T: np.ndarray) -> np.ndarray:
    """[tx, ty, tz, qx, qy, qz, qw] of a pose (scalar-last quaternion, qw >= 0)."""
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    if q[3] < 0:
        q = -q
    return np.concatenate([T[:3, 3], q])


def yaw_rotation(yaw: float) -> np.ndarray:
    """3x3 rotation about +z by `yaw` radians."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class CameraCalibration:
    """A pinhole camera with OpenCV radial-tangential distortion, rigidly mounted on the LiDAR.

    K: 3x3 intrinsics in pixels. dist: [k1, k2, p1, p2, k3] (OpenCV order; zeros = none).
    T_cam_lidar: extrinsics, LiDAR frame -> camera optical frame.
    """

    name: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    T_cam_lidar: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, dtype=np.float64)
        self.dist = np.asarray(self.dist, dtype=np.float64).ravel()
        self.T_cam_lidar = np.asarray(self.T_cam_lidar, dtype=np.float64)
        if self.K.shape != (3, 3):
            raise ValueError(f"camera {self.name}: K must be 3x3, got {self.K.shape}")
        if self.dist.size not in (0, 4, 5):
            raise ValueError(f"camera {self.name}: dist must have 0, 4 or 5 coefficients, got {self.dist.size}")
        self.dist = np.pad(self.dist, (0, 5 - self.dist.size))
        if self.T_cam_lidar.shape != (4, 4):
            raise ValueError(f"camera {self.name}: T_cam_lidar must be 4x4, got {self.T_cam_lidar.shape}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"camera {self.name}: image size must be positive, got {self.width}x{self.height}")


def distort_normalized(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply OpenCV radial-tangential distortion to normalised coordinates (N, 2) = (x/z, y/z)."""
    k1, k2, p1, p2, k3 = dist
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=1)


def undistort_normalized(xy_distorted: np.ndarray, dist: np.ndarray, iterations: int = 20) -> np.ndarray:
    """Invert `distort_normalized` by fixed-point iteration (accurate for the mild lenses we model)."""
    xy = xy_distorted.copy()
    for _ in range(iterations):
        err = distort_normalized(xy, dist) - xy_distorted
        xy = xy - err
    return xy


def project_points(points_cam: np.ndarray, camera: CameraCalibration, min_depth: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Project camera-frame points (N, 3, metres) to pixels.

    Returns (uv (N, 2) float pixels, valid (N,) bool): valid means depth z > min_depth and the pixel
    lies inside the image. Rays behind the camera are never valid.
    """
    z = points_cam[:, 2]
    in_front = z > min_depth
    safe_z = np.where(in_front, z, 1.0)
    xy = points_cam[:, :2] / safe_z[:, None]
    if np.any(camera.dist):
        xy = distort_normalized(xy, camera.dist)
    K = camera.K
    u = K[0, 0] * xy[:, 0] + K[0, 1] * xy[:, 1] + K[0, 2]
    v = K[1, 1] * xy[:, 1] + K[1, 2]
    valid = in_front & (u >= -0.5) & (u < camera.width - 0.5) & (v >= -0.5) & (v < camera.height - 0.5)
    return np.stack([u, v], axis=1), valid


def pixel_rays(camera: CameraCalibration) -> np.ndarray:
    """Unit ray directions (H*W, 3) in the camera frame through every pixel centre, row-major."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    K = camera.K
    y = (v.ravel() - K[1, 2]) / K[1, 1]
    x = (u.ravel() - K[0, 2] - K[0, 1] * y) / K[0, 0]
    xy = np.stack([x, y], axis=1)
    if np.any(camera.dist):
        xy = undistort_normalized(xy, camera.dist)
    rays = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def voxel_keys(points: np.ndarray, voxel_size: float) -> np.ndarray:
    """One int64 key per point for the voxel (edge `voxel_size` metres) containing it.

    21 bits per axis: unique for |coordinate| < 2^20 voxels (about 400 km at 0.4 m).
    """
    idx = np.floor(points / voxel_size).astype(np.int64) + (1 << 20)
    return (idx[:, 0] << 42) | (idx[:, 1] << 21) | idx[:, 2]


def voxel_centres(keys: np.ndarray, voxel_size: float) -> np.ndarray:
    """Centres (N, 3, metres) of the voxels with the given keys (inverse of `voxel_keys`)."""
    mask = (1 << 21) - 1
    idx = np.stack([(keys >> 42) & mask, (keys >> 21) & mask, keys & mask], axis=1) - (1 << 20)
    return (idx + 0.5) * voxel_size
