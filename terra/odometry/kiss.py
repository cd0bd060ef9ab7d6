"""KISS-ICP over a dataset's scans: poses for sources that have none (or when asked).

`OdometryDataset(source, config)` registers every scan once, in order, then serves the source's
frames with T_map_lidar from the odometry and the points deskewed. The map frame is the source's
first pose when the source has poses (so the map lines up with its ground truth and the errors are
measured from the same start), else the first scan's LiDAR frame.

Deskewing: a spinning LiDAR measures point i at `point_times[i]` seconds after the scan stamp,
while the robot moves. Under constant velocity between scans, the sensor at stamp + tau sits at
exp(tau / dt log(delta)) in the sensor frame at the stamp, with delta the motion between the
previous scan and this one (dt seconds apart), predicted by the last motion. Each point is moved
to the sensor frame at the stamp with that transform (rotation by slerp from identity, translation
linearly: the decoupled form, exact to second order over one sweep). KISS-ICP's own deskewing
assumes each scan spans the whole time since the previous one, which is wrong when scans are
subsampled (e.g. one every few metres), so it is turned off and done here.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from terra.datasets.base import Dataset, Frame
from terra.errors import TerraError
from terra.odometry.config import OdometryConfig
from terra.odometry.metrics import trajectory_errors
from terra.progress import progress


@dataclass
class OdometryRun:
    """stamps (F,) seconds; poses (F, 4, 4) T_map_lidar; velocity (F, 6) [rotvec rad, translation m]
    per second used to deskew frame i (zeros for the first); reference (F, 4, 4) the source's own
    poses or None; errors (trajectory_errors) when there is a reference; seconds of registration."""

    stamps: np.ndarray
    poses: np.ndarray
    velocity: np.ndarray
    reference: np.ndarray | None
    errors: dict | None
    seconds: float
    deskewed: int

    @property
    def scans_per_second(self) -> float:
        return len(self.stamps) / self.seconds if self.seconds > 0 else float("inf")


def kiss_config(config: OdometryConfig):
    """KISS-ICP's own config object from ours (every field explicit, so no environment variable
    of KISS-ICP's settings can change it)."""
    from kiss_icp.config import KISSConfig
    from kiss_icp.config.config import AdaptiveThresholdConfig, DataConfig, MappingConfig, RegistrationConfig

    return KISSConfig(
        out_dir="unused",
        data=DataConfig(max_range=config.max_range, min_range=config.min_range, deskew=False),
        registration=RegistrationConfig(
            max_num_iterations=config.max_num_iterations,
            convergence_criterion=config.convergence_criterion,
            max_num_threads=config.threads,
        ),
        mapping=MappingConfig(
            voxel_size=config.voxel_size or config.max_range / 100.0, max_points_per_voxel=config.max_points_per_voxel
        ),
        adaptive_threshold=AdaptiveThresholdConfig(
            initial_threshold=config.initial_threshold, min_motion_th=config.min_motion_th
        ),
    )


def deskew(points: np.ndarray, times: np.ndarray | None, velocity: np.ndarray) -> np.ndarray:
    """Points (N, 3) measured at `times` (N,) seconds after the stamp -> the sensor frame at the
    stamp, for a constant `velocity` [rotvec rad/s, translation m/s] (see the module docstring)."""
    if times is None or not np.any(velocity) or not np.any(times):
        return points
    tau = np.asarray(times, np.float64)[:, None]
    moved = Rotation.from_rotvec(tau * velocity[:3]).apply(np.asarray(points, np.float64)) + tau * velocity[3:]
    return moved.astype(points.dtype)


def _recent_velocity(poses: np.ndarray, stamps: np.ndarray, window: float) -> np.ndarray:
    """Body-frame velocity [rotvec rad/s, translation m/s] over the last `window` seconds of the
    estimated poses (at least the last step). A one-step estimate feeds its own error back: a
    velocity error skews the next scan, which biases its registration, which errs the velocity
    again, and the loop oscillates; averaging over a few scans damps it."""
    last = len(poses) - 1
    if last < 1:
        return np.zeros(6)
    first = min(int(np.searchsorted(stamps, stamps[last] - window)), last - 1)
    dt = stamps[last] - stamps[first]
    if dt <= 0:
        return np.zeros(6)
    delta = np.linalg.inv(poses[first]) @ poses[last]
    return np.concatenate([Rotation.from_matrix(delta[:3, :3]).as_rotvec(), delta[:3, 3]]) / dt


def run_odometry(dataset: Dataset, config: OdometryConfig, show_progress: bool = True) -> OdometryRun:
    """Register every scan of `dataset` in order with KISS-ICP (see the module docstring)."""
    from kiss_icp.kiss_icp import KissICP

    n = len(dataset)
    if n == 0:
        raise TerraError(f"dataset {dataset.name!r} has no frames to run odometry on")
    odometry = KissICP(kiss_config(config))
    stamps, poses, velocity = np.zeros(n), np.tile(np.eye(4), (n, 1, 1)), np.zeros((n, 6))
    reference, seconds, deskewed = np.full((n, 4, 4), np.nan), 0.0, 0
    for i in progress(range(n), desc="odometry", total=n, enabled=show_progress, unit="scans"):
        frame = dataset[i]
        stamps[i], reference[i] = frame.stamp, frame.T_map_lidar
        start = time.perf_counter()
        if i > 0 and config.deskew and frame.point_times is not None:
            velocity[i] = _recent_velocity(poses[:i], stamps[:i], config.velocity_window_s)
            deskewed += int(np.any(frame.point_times))
        points = deskew(np.asarray(frame.points, np.float64), frame.point_times, velocity[i])
        points = points[np.isfinite(points).all(axis=1)]
        odometry.register_frame(points, np.zeros(0))
        seconds += time.perf_counter() - start
        poses[i] = odometry.last_pose
    has_reference = bool(np.isfinite(reference).all())
    anchor = reference[0] if has_reference else np.eye(4)
    poses = anchor @ poses
    errors = trajectory_errors(poses, reference) if has_reference else None
    return OdometryRun(stamps, poses, velocity, reference if has_reference else None, errors, seconds, deskewed)


class OdometryDataset:
    """`source`'s frames with odometry poses and deskewed points (see the module docstring)."""

    def __init__(self, source: Dataset, config: OdometryConfig | None = None, show_progress: bool = True) -> None:
        self.source = source
        self.name = source.name
        self.classes = source.classes
        self.run = run_odometry(source, config or OdometryConfig(), show_progress)
        self.pose_source = "odometry (KISS-ICP)"
        self.has_poses = True

    def __len__(self) -> int:
        return len(self.source)

    def __getitem__(self, index: int) -> Frame:
        frame = self.source[index]
        frame.points = deskew(np.asarray(frame.points, np.float32), frame.point_times, self.run.velocity[index])
        frame.T_map_lidar = self.run.poses[index].copy()
        return frame

    def __getattr__(self, name: str):
        # Everything else (calibrations, ground_truth, info, skipped counters) is the source's.
        if name == "source":
            raise AttributeError(name)
        return getattr(self.source, name)

    def global_map(self) -> np.ndarray | None:
        return None  # a source's own global map is in its own pose frame, not the odometry's


POSE_MODES = ("auto", "odometry")


def with_poses(dataset: Dataset, mode: str, config: OdometryConfig, show_progress: bool = True) -> Dataset:
    """`dataset` itself, or an OdometryDataset over it when `mode` is 'odometry' or the source
    has no poses of its own (a bag without /tf or odometry topic: `needs_odometry`)."""
    if mode not in POSE_MODES:
        raise TerraError(f"--poses {mode!r}: expected one of: {', '.join(POSE_MODES)}")
    if mode == "odometry" or getattr(dataset, "needs_odometry", False):
        return OdometryDataset(dataset, config, show_progress)
    return dataset
