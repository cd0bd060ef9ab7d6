"""Fitted object boxes against human-labelled KITTI cars (issue 27): the points a segmentation
would give each labelled car, the ground under it from Terra's own ground filter, and the exact
3D IoU of the box fitted to them.

Frames and units: everything in the Velodyne frame of one scan (x forward, y left, z up; metres,
radians); the sensor sits at the origin. A car's points are those inside its label box grown by
`margin` metres on every side (a mask that bleeds a little, onto the ground too); the ground
height under it is the median height of the points Terra's morphological filter
(terra.graph.ground.segment_ground) calls ground in a ring up to `ring` metres around the grown
box, run on the points within `surround` metres of the box only, so that a crop of the scan
around the cars (the test data) gives the same answer as the whole scan.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terra.datasets.kitti_object import KittiObjectFrame
from terra.eval.metrics.boxes import box_iou
from terra.graph.ground import segment_ground
from terra.tasks.boxes import BoxSet, fit_object_boxes


@dataclass(frozen=True)
class CarCase:
    """One labelled car: its grown-box points (n, 3), which of them are ground (n,) bool, the
    ground height under it (metres; NaN when no ground point is near), its label box and how many
    scan points lie inside the label box itself."""

    frame: str
    index: int
    points: np.ndarray
    ground: np.ndarray
    ground_z: float
    label: BoxSet
    inside: int


def _local(points: np.ndarray, box: BoxSet) -> np.ndarray:
    """(n, 3) points in the box's axes (length, width, up) about its centre."""
    d = points - box.center[0]
    c, s = np.cos(box.yaw[0]), np.sin(box.yaw[0])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]])


def near_boxes(points: np.ndarray, boxes: BoxSet, surround: float) -> np.ndarray:
    """(n,) bool: points (n, 3) within `surround` metres (in xy, along the box axes) of any box."""
    keep = np.zeros(len(points), dtype=bool)
    for i in range(len(boxes)):
        local = _local(points, boxes[i : i + 1])
        keep |= np.all(np.abs(local[:, :2]) <= boxes.size[i, :2] / 2 + surround, axis=1)
    return keep


def car_cases(
    frame: KittiObjectFrame, margin: float = 0.2, surround: float = 4.0, ring: float = 2.0, min_points: int = 100
) -> list[CarCase]:
    """The frame's labelled cars with at least `min_points` scan points inside their label box."""
    xyz = frame.points[:, :3].astype(np.float64)
    boxes = BoxSet.from_objects(frame.boxes(("Car",))[1])
    out = []
    for i in range(len(boxes)):
        box = boxes[i : i + 1]
        local = _local(xyz, box)
        half = box.size[0] / 2
        inside = int(np.all(np.abs(local) <= half, axis=1).sum())
        if inside < min_points:
            continue
        near = np.all(np.abs(local[:, :2]) <= half[:2] + surround, axis=1)
        ground = np.zeros(len(xyz), dtype=bool)
        ground[near] = segment_ground(xyz[near])
        grown = np.all(np.abs(local) <= half + margin, axis=1)
        in_ring = near & np.all(np.abs(local[:, :2]) <= half[:2] + margin + ring, axis=1) & ~grown & ground
        ground_z = float(np.median(xyz[in_ring, 2])) if in_ring.any() else float("nan")
        out.append(CarCase(frame.name, i, xyz[grown], ground[grown], ground_z, box, inside))
    return out


def fitted_iou(case: CarCase, drop_ground: bool = False, **fit_options) -> tuple[float, BoxSet]:
    """The 3D IoU of the box fitted to the case's points (without the ground points with
    `drop_ground`: a segmentation that knows the ground) and that box; `fit_options` go to
    terra.tasks.boxes.fit_object_boxes."""
    pts = case.points[~case.ground] if drop_ground else case.points
    if len(pts) == 0:
        return 0.0, BoxSet.empty()
    ground_z = np.array([case.ground_z]) if np.isfinite(case.ground_z) else None
    (box,) = fit_object_boxes(pts, np.zeros(len(pts), dtype=np.int64), ground_z, **fit_options)
    fitted = BoxSet.from_objects([box])
    return box_iou(fitted, case.label), fitted
