"""Trajectories as text, in the two formats odometry tools exchange.

KITTI: one line per pose, the 12 numbers of the 3x4 matrix [R | t] row-major (here T_map_lidar,
metres). TUM: one line per pose, `stamp tx ty tz qx qy qz qw` (seconds, metres, scalar-last unit
quaternion).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from terra.geometry import pose_to_xyz_quat


def kitti_text(poses: np.ndarray) -> str:
    """(F, 4, 4) poses as KITTI lines."""
    return "".join(" ".join(f"{v:.9e}" for v in T[:3].ravel()) + "\n" for T in poses)


def tum_text(stamps: np.ndarray, poses: np.ndarray) -> str:
    """(F,) stamps and (F, 4, 4) poses as TUM lines."""
    return "".join(
        f"{t:.9f} " + " ".join(f"{v:.9f}" for v in pose_to_xyz_quat(T)) + "\n" for t, T in zip(stamps, poses)
    )


def read_kitti(text: str) -> np.ndarray:
    """Inverse of kitti_text: (F, 4, 4) poses."""
    rows = np.array([[float(v) for v in line.split()] for line in text.splitlines() if line.strip()]).reshape(-1, 12)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = rows.reshape(-1, 3, 4)
    return poses


def trajectory_paths(bundle: Path) -> tuple[Path, Path]:
    """Where the trajectory of a bundle goes: beside it, `<stem>_poses_kitti.txt` and
    `<stem>_poses_tum.txt` (KISS-ICP's own names)."""
    bundle = Path(bundle)
    stem = bundle.name.split(".")[0] or bundle.name
    return bundle.parent / f"{stem}_poses_kitti.txt", bundle.parent / f"{stem}_poses_tum.txt"


def write_trajectory(bundle: Path, stamps: np.ndarray, poses: np.ndarray) -> tuple[Path, Path]:
    """Write both formats beside `bundle`, each atomically; returns their paths."""
    from terra.bundle import atomic_write_bytes

    kitti, tum = trajectory_paths(bundle)
    atomic_write_bytes(kitti, kitti_text(poses).encode())
    atomic_write_bytes(tum, tum_text(stamps, poses).encode())
    return kitti, tum
