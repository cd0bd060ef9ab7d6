"""Solid shapes the world is built from (their ray intersection is in terra/sim/kernels.py).

Every shape is gravity-aligned with a yaw about +z (map frame, metres, radians):
- box: `half` = half sizes along its own x, y, z axes;
- cylinder: vertical axis; `half` = (radius, radius, half height);
- ellipsoid: `half` = semi-axes along its own x, y, z axes.
Each carries the class id and instance id its hits are labelled with, and an RGB colour.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BOX, CYLINDER, ELLIPSOID = 0, 1, 2


@dataclass
class Primitives:
    """Arrays of P shapes in the map frame: kind (P,) int8, center (P, 3), half (P, 3), yaw (P,),
    class_id (P,) int32, instance_id (P,) int32, color (P, 3) uint8."""

    kind: np.ndarray
    center: np.ndarray
    half: np.ndarray
    yaw: np.ndarray
    class_id: np.ndarray
    instance_id: np.ndarray
    color: np.ndarray

    def __len__(self) -> int:
        return int(self.kind.shape[0])

    @property
    def bounding_radius(self) -> np.ndarray:
        """(P,) radius of a sphere about `center` that holds the shape, metres."""
        h = self.half
        return np.where(self.kind == ELLIPSOID, h.max(axis=1), np.linalg.norm(h, axis=1))

    @classmethod
    def empty(cls) -> Primitives:
        return cls(
            np.zeros(0, np.int8),
            np.zeros((0, 3)),
            np.zeros((0, 3)),
            np.zeros(0),
            np.zeros(0, np.int32),
            np.zeros(0, np.int32),
            np.zeros((0, 3), np.uint8),
        )

    @classmethod
    def from_rows(cls, rows: list[tuple]) -> Primitives:
        """From rows (kind, center(3), half(3), yaw, class_id, instance_id, color(3))."""
        if not rows:
            return cls.empty()
        kind, center, half, yaw, cid, iid, color = zip(*rows)
        return cls(
            np.asarray(kind, np.int8),
            np.asarray(center, float).reshape(-1, 3),
            np.asarray(half, float).reshape(-1, 3),
            np.asarray(yaw, float),
            np.asarray(cid, np.int32),
            np.asarray(iid, np.int32),
            np.asarray(color, np.uint8).reshape(-1, 3),
        )
