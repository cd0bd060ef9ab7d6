"""Gravity-aligned oriented 3D boxes and their exact IoU.

A box is a centre (3,) and a size (3,) in metres, map frame, with `size` measured along the box
axes before a rotation of `yaw` radians about +z. For such boxes the intersection volume is exact:
the area of the intersection of the two yawed footprints (shapely polygons) times the overlap of
the two z intervals.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import shapely


@dataclass
class BoxSet:
    """n oriented boxes: center (n, 3) metres, size (n, 3) metres (box axes), yaw (n,) radians."""

    center: np.ndarray
    size: np.ndarray
    yaw: np.ndarray

    def __post_init__(self) -> None:
        self.center = np.asarray(self.center, dtype=np.float64).reshape(-1, 3)
        self.size = np.asarray(self.size, dtype=np.float64).reshape(-1, 3)
        self.yaw = np.asarray(self.yaw, dtype=np.float64).reshape(-1)
        if not (len(self.center) == len(self.size) == len(self.yaw)):
            raise ValueError(
                f"box arrays disagree: {len(self.center)} centres, {len(self.size)} sizes, {len(self.yaw)} yaws"
            )
        if np.any(self.size < 0):
            raise ValueError("box sizes must be non-negative")

    def __len__(self) -> int:
        return int(self.center.shape[0])

    def __getitem__(self, index) -> BoxSet:
        return BoxSet(self.center[index], self.size[index], self.yaw[index])

    @classmethod
    def empty(cls) -> BoxSet:
        return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))

    @classmethod
    def from_objects(cls, objects: Iterable) -> BoxSet:
        """From anything with `.center`, `.size`, `.yaw` (ground-truth ObjectBox, FoundObject)."""
        objects = list(objects)
        if not objects:
            return cls.empty()
        return cls(
            np.stack([np.asarray(o.center, float) for o in objects]),
            np.stack([np.asarray(o.size, float) for o in objects]),
            np.array([float(o.yaw) for o in objects]),
        )

    @property
    def volume(self) -> np.ndarray:
        """(n,) cubic metres."""
        return np.prod(self.size, axis=1)

    def footprint_corners(self) -> np.ndarray:
        """(n, 4, 2) footprint corners in the map frame, counter-clockwise."""
        half = self.size[:, None, :2] / 2.0 * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)[None]
        c, s = np.cos(self.yaw)[:, None], np.sin(self.yaw)[:, None]
        x = c * half[..., 0] - s * half[..., 1]
        y = s * half[..., 0] + c * half[..., 1]
        return np.stack([x, y], axis=-1) + self.center[:, None, :2]

    def footprints(self) -> np.ndarray:
        """(n,) shapely polygons of the footprints."""
        return shapely.polygons(self.footprint_corners())

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(n, m) whether box i contains point j (points (m, 3), map frame; boundary counts as inside)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        d = points[None, :, :] - self.center[:, None, :]  # (n, m, 3)
        c, s = np.cos(self.yaw)[:, None], np.sin(self.yaw)[:, None]
        # Rotate by -yaw into the box axes.
        local = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], d[..., 2]], axis=-1)
        eps = 1e-9
        return np.all(np.abs(local) <= self.size[:, None, :] / 2.0 + eps, axis=-1)


def iou_matrix(a: BoxSet, b: BoxSet) -> np.ndarray:
    """(len(a), len(b)) exact 3D IoU of gravity-aligned oriented boxes (0 where disjoint)."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros((len(a), len(b)))
    area = shapely.area(shapely.intersection(a.footprints()[:, None], b.footprints()[None, :]))
    z_lo = np.maximum((a.center[:, 2] - a.size[:, 2] / 2)[:, None], (b.center[:, 2] - b.size[:, 2] / 2)[None, :])
    z_hi = np.minimum((a.center[:, 2] + a.size[:, 2] / 2)[:, None], (b.center[:, 2] + b.size[:, 2] / 2)[None, :])
    inter = area * np.clip(z_hi - z_lo, 0.0, None)
    union = a.volume[:, None] + b.volume[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def box_iou(a: BoxSet, b: BoxSet) -> float:
    """IoU of the single boxes `a` and `b`."""
    return float(iou_matrix(a, b)[0, 0])
