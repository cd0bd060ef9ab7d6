"""KITTI object-detection frames (the devkit's `training/` layout) as LiDAR points and labelled
boxes in the LiDAR frame, for checking fitted boxes against human labels.

A frame NNNNNN is three files under one folder: `velodyne/NNNNNN.bin` (float32 x, y, z,
reflectance, Velodyne frame, metres), `label_2/NNNNNN.txt` (terra.datasets.kitti_labels) and
`calib/NNNNNN.txt` (`R0_rect` 3x3 and `Tr_velo_to_cam` 3x4, rows; terra.datasets.kitti_common).
Labels live in the rectified camera-0 frame: a point p_velo maps to R0_rect Tr_velo_to_cam p_velo
there, so the labels come back to the LiDAR frame by the inverse of that product.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from terra.datasets.ground_truth import ObjectBox
from terra.datasets.kitti_common import read_calib_file
from terra.datasets.kitti_labels import KittiLabel, box_in_frame, read_label_file
from terra.errors import TerraError
from terra.geometry import invert_pose


@dataclass(frozen=True)
class KittiObjectFrame:
    """One frame: points (n, 4) float32 (x, y, z metres, reflectance; Velodyne frame), its labels
    and T_velo_rect (4x4: rectified camera 0 -> Velodyne, metres)."""

    name: str
    points: np.ndarray
    labels: list[KittiLabel]
    T_velo_rect: np.ndarray

    def boxes(self, types: tuple[str, ...] = ("Car",)) -> tuple[list[KittiLabel], list[ObjectBox]]:
        """The labels of the given types and their boxes in the Velodyne frame (centre, size as
        length, width, height, yaw of the length axis about +z; metres, radians), numbered by their
        line among the chosen labels (class id 0: KITTI's types are names)."""
        chosen = [label for label in self.labels if label.type in types]
        boxes = [box_in_frame(label, self.T_velo_rect) for label in chosen]
        return chosen, [
            ObjectBox(i, 0, label.type, b.center, b.size, b.yaw()) for i, (label, b) in enumerate(zip(chosen, boxes))
        ]


def velo_from_rect(calib_path: Path) -> np.ndarray:
    """T_velo_rect (4x4) from an object calibration file's R0_rect and Tr_velo_to_cam."""
    calib = read_calib_file(calib_path)
    R0 = np.eye(4)
    R0[:3, :3] = calib.matrix("R0_rect", (3, 3), "the rectifying rotation of camera 0, row-major")
    return invert_pose(R0 @ calib.pose_3x4("Tr_velo_to_cam"))


def object_frames(folder: Path) -> list[str]:
    """The frame names (NNNNNN) that have a scan, a label file and a calibration file in `folder`."""
    folder = Path(folder)
    scans = sorted(p.stem for p in (folder / "velodyne").glob("*.bin"))
    names = [
        n for n in scans if (folder / "label_2" / f"{n}.txt").is_file() and (folder / "calib" / f"{n}.txt").is_file()
    ]
    if not names:
        raise TerraError(f"{folder}: no KITTI object frame (velodyne/N.bin with label_2/N.txt and calib/N.txt)")
    return names


def read_object_frame(folder: Path, name: str) -> KittiObjectFrame:
    """Frame `name` of a KITTI object folder (module docstring); TerraError naming the file when
    one is missing or malformed."""
    from terra.datasets.folder_io import read_raw

    folder = Path(folder)
    points = read_raw(folder / "velodyne" / f"{name}.bin", "float32", "KITTI Velodyne scan")
    if points.size % 4:
        raise TerraError(f"{folder / 'velodyne' / name}.bin: {points.size} floats, not x y z reflectance quadruples")
    labels = read_label_file(
        folder / "label_2" / f"{name}.txt", tracking=False, frame=int(name) if name.isdigit() else -1
    )
    return KittiObjectFrame(name, points.reshape(-1, 4), labels, velo_from_rect(folder / "calib" / f"{name}.txt"))
