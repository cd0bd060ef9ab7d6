"""The exact IoU of gravity-aligned oriented 3D boxes (terra.tasks.boxes.BoxSet).

A box is a centre (3,) and a size (3,) in metres, map frame, with `size` measured along the box
axes before a rotation of `yaw` radians about +z. For such boxes the intersection volume is exact:
the area of the intersection of the two yawed footprints (shapely polygons) times the overlap of
the two z intervals.
"""

from __future__ import annotations

import numpy as np
import shapely

from terra.tasks.boxes import BoxSet

__all__ = ["BoxSet", "box_iou", "iou_matrix"]


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
