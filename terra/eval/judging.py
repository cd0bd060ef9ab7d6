"""A found object judged against the simulator's ground truth: which class a query names, and the
true object of that class nearest a found box (distance, IoU, Table II's hit rule). Shared by the
demo's summary and the live replay."""

from __future__ import annotations

import numpy as np

from terra.datasets.ground_truth import GroundTruth


def gt_class_of(query: str, gt: GroundTruth) -> str | None:
    """The ground-truth object class a query names: the longest class name in its text."""
    text = query.lower()
    names = sorted({o.class_name for o in gt.objects}, key=lambda n: (-len(n), n))
    return next((n for n in names if n.lower() in text), None)


def nearest_gt_object(
    center: np.ndarray, gt: GroundTruth, class_name: str | None, box: dict | None = None
) -> dict | None:
    """The ground-truth object of `class_name` nearest (2-D, metres) to `center`. With the found
    object's `box` (center, size, yaw), also its 3-D IoU with that object and whether it is a hit
    by Table II's relaxed rule (the boxes overlap and the found box holds the object's centre), so
    the demo's summary and Table II judge a find the same way."""
    from terra.eval.metrics.boxes import BoxSet, iou_matrix

    objects = [o for o in gt.objects if o.class_name == class_name]
    if not objects:
        return None
    xy = np.array([o.center[:2] for o in objects])
    d = np.linalg.norm(xy - np.asarray(center, float)[:2], axis=1)
    i = int(np.argmin(d))
    out = {
        "class": class_name,
        "center": [round(float(v), 4) for v in objects[i].center],
        "distance_m": round(float(d[i]), 4),
    }
    if box is not None:
        found = BoxSet(np.asarray([box["center"]]), np.asarray([box["size"]]), np.asarray([box["yaw"]]))
        truth = BoxSet.from_objects([objects[i]])
        iou = float(iou_matrix(found, truth)[0, 0])
        out.update(iou=round(iou, 4), hit=bool(iou > 0 and found.contains(truth.center)[0, 0]))
    return out
