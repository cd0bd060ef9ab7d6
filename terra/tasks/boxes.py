"""Gravity-aligned oriented bounding boxes fitted to object points.

A box is a centre (3,) and size (3,) in metres, map frame, and a yaw in radians about +z: size[0]
lies along the box's x axis, which points along (cos yaw, sin yaw). Boxes are gravity aligned (no
roll or pitch), as outdoor objects stand on the ground and as the ground-truth boxes are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely


@dataclass(frozen=True)
class OrientedBox:
    """center, size: (3,) metres; yaw: radians in [-pi/2, pi/2), size[0] >= size[1]."""

    center: np.ndarray
    size: np.ndarray
    yaw: float

    def corners_xy(self) -> np.ndarray:
        """(4, 2) footprint corners, counter-clockwise, metres."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        half = self.size[:2] / 2
        local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
        return local @ np.array([[c, s], [-s, c]]) + self.center[:2]


def wrap_half_turn(yaw: float) -> float:
    """An axis direction in radians, folded into [-pi/2, pi/2) (a box is symmetric under pi)."""
    return float((yaw + np.pi / 2) % np.pi - np.pi / 2)


def fit_oriented_box(points: np.ndarray, padding: float = 0.0) -> OrientedBox:
    """The box whose footprint is the minimum-area rectangle around the points' xy convex hull
    (rotating calipers, via shapely) and whose z extent spans the points.

    points: (n, 3) metres, map frame, n >= 1. padding: metres added to every dimension.
    The x axis is the rectangle's longer side. Collinear points give a zero width, one point a
    zero footprint (before padding).
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise ValueError(f"expected (n, 3) points with n >= 1, got shape {pts.shape}")
    z_lo, z_hi = pts[:, 2].min(), pts[:, 2].max()
    rect = shapely.minimum_rotated_rectangle(shapely.multipoints(pts[:, :2]))
    if isinstance(rect, shapely.Polygon):
        corners = np.asarray(rect.exterior.coords)[:4]
        edges = np.roll(corners, -1, axis=0)[:2] - corners[:2]
        lengths = np.linalg.norm(edges, axis=1)
        long_side = int(np.argmax(lengths))
        axis = edges[long_side]
        size_xy = (lengths[long_side], lengths[1 - long_side])
        center_xy = corners.mean(axis=0)
    elif isinstance(rect, shapely.LineString):
        ends = np.asarray(rect.coords)[[0, -1]]
        axis = ends[1] - ends[0]
        size_xy = (float(np.linalg.norm(axis)), 0.0)
        center_xy = ends.mean(axis=0)
    else:  # all points share one xy
        axis = np.array([1.0, 0.0])
        size_xy = (0.0, 0.0)
        center_xy = pts[0, :2]
    yaw = wrap_half_turn(float(np.arctan2(axis[1], axis[0])))
    center = np.array([center_xy[0], center_xy[1], (z_lo + z_hi) / 2])
    size = np.array([size_xy[0], size_xy[1], z_hi - z_lo]) + padding
    return OrientedBox(center=center, size=size, yaw=yaw)
