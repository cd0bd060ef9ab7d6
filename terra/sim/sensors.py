"""Sensor models: a spinning LiDAR and pinhole cameras, both rendered by ray casting a World.

Mounting: the LiDAR sits `height` metres above the robot base, axes aligned with it (x forward,
y left, z up). Cameras are mounted on the base by position and yaw/pitch/roll (CameraConfig);
their calibration carries T_cam_lidar.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from terra.geometry import CameraCalibration, invert_pose, make_pose, pixel_rays
from terra.sim.classes import CLASS_REFLECTANCE
from terra.sim.config import CameraConfig, LidarConfig
from terra.sim.kernels import shade_kernel
from terra.sim.raycast import RayTiles, cast
from terra.sim.world import World

SUN = np.array([0.45, 0.3, 0.84]) / np.linalg.norm([0.45, 0.3, 0.84])
_OPTICAL_IN_BASE = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # columns: optical x, y, z


class Lidar:
    """Spinning LiDAR: rows from the highest beam down, columns counter-clockwise from +x."""

    def __init__(self, config: LidarConfig) -> None:
        self.config = config
        lo, hi = np.radians(config.vertical_fov_deg)
        elevation = np.linspace(hi, lo, config.beams)
        azimuth = 2.0 * np.pi * np.arange(config.columns) / config.columns
        el, az = np.meshgrid(elevation, azimuth, indexing="ij")
        dirs = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1).reshape(-1, 3)
        self.tiles = RayTiles.from_grid(dirs, config.beams, config.columns, 4, 16)
        self.T_base_lidar = make_pose(np.eye(3), [0.0, 0.0, config.height])

    def render(
        self, world: World, T_map_lidar: np.ndarray, rng: np.random.Generator | None = None
    ) -> dict[str, np.ndarray]:
        """One scan: points (N, 3) float32 LiDAR frame, intensity (N,) float32 0..1, labels and
        instances (N,) int32. Rays with no return within [min_range, max_range] give no point."""
        cfg = self.config
        wobble = np.eye(3)  # beam directions of this scan, in the LiDAR frame
        if cfg.wobble_deg > 0 and rng is not None:
            angles = rng.uniform(-cfg.wobble_deg, cfg.wobble_deg, 3)
            wobble = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()
        T_cast = T_map_lidar.copy()
        T_cast[:3, :3] = T_map_lidar[:3, :3] @ wobble
        hits = cast(world, T_cast, self.tiles, cfg.max_range)
        t = hits.t
        if cfg.range_noise_m > 0 and rng is not None:
            t = t + rng.normal(0.0, cfg.range_noise_m, t.shape)
        keep = np.isfinite(t) & (t >= cfg.min_range) & (t <= cfg.max_range)
        directions = self.tiles.directions[keep] @ wobble.T if cfg.wobble_deg > 0 else self.tiles.directions[keep]
        points = (directions * t[keep, None]).astype(np.float32)
        cos_inc = np.abs(np.einsum("ij,ij->i", hits.normal[keep], hits.directions[keep]))
        intensity = (CLASS_REFLECTANCE[hits.class_id[keep]] * np.clip(cos_inc, 0.1, 1.0)).astype(np.float32)
        return {
            "points": points,
            "intensity": intensity,
            "labels": hits.class_id[keep],
            "instances": hits.instance_id[keep],
        }


def camera_pose_on_base(config: CameraConfig) -> np.ndarray:
    """T_base_cam (4x4) of a camera mount: yaw left-positive, pitch down-positive, roll, in degrees."""
    R = Rotation.from_euler("ZYX", [config.yaw_deg, config.pitch_deg, config.roll_deg], degrees=True).as_matrix()
    return make_pose(R @ _OPTICAL_IN_BASE, config.position)


class Camera:
    """A pinhole camera; renders RGB (shaded class colours), semantic and instance images."""

    def __init__(self, config: CameraConfig, T_base_lidar: np.ndarray) -> None:
        self.config = config
        self.T_base_cam = camera_pose_on_base(config)
        cx = (config.width - 1) / 2 if config.cx is None else config.cx
        cy = (config.height - 1) / 2 if config.cy is None else config.cy
        K = np.array([[config.fx, 0.0, cx], [0.0, config.fy, cy], [0.0, 0.0, 1.0]])
        self.calibration = CameraCalibration(
            config.name,
            config.width,
            config.height,
            K,
            np.asarray(config.dist, float),
            invert_pose(self.T_base_cam) @ T_base_lidar,
            config.model,
        )
        self.tiles = RayTiles.from_grid(pixel_rays(self.calibration), config.height, config.width, 16, 16)

    def render(self, world: World, T_map_cam: np.ndarray, max_range: float = 150.0) -> dict[str, np.ndarray]:
        """image (H, W, 3) uint8 RGB, semantic (H, W) int32 class ids (0 = sky), instance (H, W) int32."""
        h, w = self.config.height, self.config.width
        hits = cast(world, T_map_cam, self.tiles, max_range)
        image = shade(hits, T_map_cam[:3, 3])
        return {
            "image": image.reshape(h, w, 3),
            "semantic": hits.class_id.reshape(h, w),
            "instance": hits.instance_id.reshape(h, w),
        }


def shade(hits, origin: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours: Lambert shading of the base colour with a fine surface texture, and sky."""
    out = np.empty((hits.t.shape[0], 3), np.uint8)
    shade_kernel(hits.t, hits.directions, hits.normal, hits.color, np.asarray(origin, np.float64), SUN, out)
    return out
