"""Poses, camera projection and voxel keys (lens distortion models live in `terra.lens`).

Conventions: a pose `T_a_b` is a 4x4 homogeneous matrix taking points from frame b to frame a
(p_a = T_a_b @ p_b). Lengths are metres, angles radians. Camera frames are optical frames:
z forward, x right, y down. Image coordinates (u, v) are pixels with (0, 0) at the centre of the
top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike

from terra import lens


def make_pose(rotation: ArrayLike, translation: ArrayLike) -> np.ndarray:
    """4x4 pose from a 3x3 rotation and a translation (3,) in metres."""
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
    from scipy.spatial.transform import Rotation  # here: scipy.spatial costs a query command ~0.2 s

    return make_pose(Rotation.from_quat(xyz_quat[3:]).as_matrix(), xyz_quat[:3])


def pose_to_xyz_quat(T: np.ndarray) -> np.ndarray:
    """[tx, ty, tz, qx, qy, qz, qw] of a pose (scalar-last quaternion, qw >= 0)."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    if q[3] < 0:
        q = -q
    return np.concatenate([T[:3, 3], q])


def yaw_rotation(yaw: float) -> np.ndarray:
    """3x3 rotation about +z by `yaw` radians."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


MAX_IMAGE_SIDE = 65535  # pixels (JPEG's limit): larger sizes are damaged calibrations


@dataclass
class CameraCalibration:
    """A camera with a real lens model, rigidly mounted on the LiDAR.

    K: 3x3 intrinsics in pixels. dist: distortion coefficients in OpenCV order, as many as the
    calibration states (see `terra.lens`): for `model` 'pinhole' 0, 4, 5, 8, 12 or 14
    [k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y]; for 'fisheye' (equidistant)
    4 [k1, k2, k3, k4]. T_cam_lidar: extrinsics, LiDAR frame -> camera optical frame (metres).
    """

    name: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(0))
    T_cam_lidar: np.ndarray = field(default_factory=lambda: np.eye(4))
    model: str = lens.PINHOLE

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, dtype=np.float64)
        self.T_cam_lidar = np.asarray(self.T_cam_lidar, dtype=np.float64)
        if self.K.shape != (3, 3):
            raise ValueError(f"camera {self.name}: K must be 3x3, got {self.K.shape}")
        if not np.all(np.isfinite(self.K)) or self.K[0, 0] <= 0 or self.K[1, 1] <= 0 or self.K[2, 2] != 1.0:
            raise ValueError(
                f"camera {self.name}: K must be finite with positive focal lengths and K[2, 2] = 1, "
                f"got {self.K.tolist()}"
            )
        try:
            self.dist = lens.check_coefficients(self.model, self.dist)
        except ValueError as exc:
            raise ValueError(f"camera {self.name}: {exc}") from None
        if self.T_cam_lidar.shape != (4, 4) or not np.all(np.isfinite(self.T_cam_lidar)):
            raise ValueError(
                f"camera {self.name}: T_cam_lidar must be a finite 4x4 transform, got shape {self.T_cam_lidar.shape}"
            )
        if not 0 < self.width <= MAX_IMAGE_SIDE or not 0 < self.height <= MAX_IMAGE_SIDE:
            raise ValueError(
                f"camera {self.name}: image size must be 1..{MAX_IMAGE_SIDE} pixels a side, "
                f"got {self.width}x{self.height}"
            )

    @property
    def distorted(self) -> bool:
        """Whether the lens model differs from an ideal pinhole."""
        return self.model != lens.PINHOLE or lens.has_distortion(self.dist)

    @cached_property
    def max_radius2(self) -> float:
        """Largest squared undistorted normalised radius (x/z)^2 + (y/z)^2 that the image covers.

        Polynomial lens models fold back beyond the field of view: a ray far outside it can
        distort onto a pixel inside the image. Projection refuses rays beyond this radius."""
        if not self.distorted:
            return np.inf
        xy = lens.undistort(self.pixels_to_normalized(_border_pixels(self.width, self.height)), self.dist, self.model)
        r2 = np.sum(xy * xy, axis=1)
        r2 = r2[np.isfinite(r2)]
        return float(r2.max() * (1.0 + 1e-9)) if r2.size else np.inf

    def pixels_to_normalized(self, uv: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) -> distorted normalised coordinates (N, 2) through K^-1 (skew included)."""
        K = self.K
        y = (uv[:, 1] - K[1, 2]) / K[1, 1]
        x = (uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        return np.stack([x, y], axis=1)


def _border_pixels(width: int, height: int, step: int = 4) -> np.ndarray:
    """Pixel positions along the image's outer edge (pixel edges at -0.5 and size - 0.5)."""
    us = np.append(np.arange(-0.5, width - 0.5, step), width - 0.5)
    vs = np.append(np.arange(-0.5, height - 0.5, step), height - 0.5)
    top = np.stack([us, np.full_like(us, -0.5)], 1)
    bottom = np.stack([us, np.full_like(us, height - 0.5)], 1)
    left = np.stack([np.full_like(vs, -0.5), vs], 1)
    right = np.stack([np.full_like(vs, width - 0.5), vs], 1)
    return np.concatenate([top, bottom, left, right])


def project_points(
    points_cam: np.ndarray, camera: CameraCalibration, min_depth: float = 0.05
) -> tuple[np.ndarray, np.ndarray]:
    """Project camera-frame points (N, 3, metres) to pixels through the camera's lens model.

    Returns (uv (N, 2) float pixels, valid (N,) bool): valid means depth z > min_depth, the ray
    lies within the lens's field of view (see `CameraCalibration.max_radius2`) and the pixel lies
    inside the image. Rays behind the camera are never valid; uv means nothing where not valid
    (the lens model is only evaluated for rays in its field of view).
    """
    z = points_cam[:, 2]
    in_front = z > min_depth
    safe_z = np.where(in_front, z, 1.0)
    xy = points_cam[:, :2] / safe_z[:, None]
    if camera.distorted:
        in_front &= np.sum(xy * xy, axis=1) <= camera.max_radius2
        seen = np.flatnonzero(in_front)
        xy[seen] = lens.distort(xy[seen], camera.dist, camera.model)
    K = camera.K
    u = K[0, 0] * xy[:, 0] + K[0, 1] * xy[:, 1] + K[0, 2]
    v = K[1, 1] * xy[:, 1] + K[1, 2]
    valid = in_front & (u >= -0.5) & (u < camera.width - 0.5) & (v >= -0.5) & (v < camera.height - 0.5)
    return np.stack([u, v], axis=1), valid


def pixel_rays(camera: CameraCalibration) -> np.ndarray:
    """Unit ray directions (H*W, 3) in the camera frame through every pixel centre, row-major."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    xy = camera.pixels_to_normalized(np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64))
    if camera.distorted:
        xy = lens.undistort(xy, camera.dist, camera.model)
    rays = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def voxel_keys(points: np.ndarray, voxel_size: float | np.ndarray) -> np.ndarray:
    """One int64 key per point for the voxel (edge `voxel_size` metres, or (N, 1) edges, one per point)
    containing it.

    21 bits per axis: unique for |coordinate| < 2^20 voxels (about 400 km at 0.4 m).
    """
    idx = np.floor(points / voxel_size).astype(np.int64) + (1 << 20)
    return (idx[:, 0] << 42) | (idx[:, 1] << 21) | idx[:, 2]


def voxel_centres(keys: np.ndarray, voxel_size: float) -> np.ndarray:
    """Centres (N, 3, metres) of the voxels with the given keys (inverse of `voxel_keys`)."""
    mask = (1 << 21) - 1
    idx = np.stack([(keys >> 42) & mask, (keys >> 21) & mask, keys & mask], axis=1) - (1 << 20)
    return (idx + 0.5) * voxel_size
