"""Decoding ultralytics YOLO segmentation outputs into detections with masks on the original image.

Two export layouts exist, both with the mask prototypes as the second output, `output1` of shape
(1, nm, H_in / 4, W_in / 4) (nm = 32):

- raw (YOLOv8 / YOLO11 / FastSAM, and YOLOE exports): `output0` of shape (1, 4 + nc + nm, anchors).
  Per anchor: box centre x, y, width, height in input pixels; nc class scores (already through a
  sigmoid; no objectness); nm mask coefficients. Needs confidence filtering and NMS.
- end-to-end (YOLO26 and `nms=True` exports): `output0` of shape (1, max_det, 6 + nm). Per row:
  x1, y1, x2, y2 in input pixels, score, class index, nm mask coefficients. Already suppressed.

A detection's mask is sigmoid(coefficients . prototypes) > threshold, sampled bilinearly at each
original pixel's centre mapped through the letterbox (one interpolation, where ultralytics resizes
twice), and cropped to the box (pixel column c is inside when x1 <= c < x2, as ultralytics'
crop_mask). Only the box's pixels are ever computed: a 30-mask 640 x 480 image costs its boxes,
not 30 full frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from terra.perception.letterbox import Letterbox

MAX_WH = 7680.0  # class offset of class-aware NMS (boxes of different classes never overlap)
MAX_NMS = 30000  # candidates entering NMS, highest scores first


@dataclass
class Detections:
    """n detections on an image of `shape` (H, W), best score first.

    boxes: (n, 4) float64 x1, y1, x2, y2 in image pixels. scores: (n,) float32. classes: (n,) int64
    model class indices. mask_boxes: (n, 4) int64 row0, col0, row1, col1 (end exclusive) of each mask's
    pixels; mask_crops: n boolean crops of those boxes (tight: every row and column holds a pixel).
    """

    shape: tuple[int, int]
    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    scores: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    classes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    mask_boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    mask_crops: list[np.ndarray] = field(default_factory=list)

    def __len__(self) -> int:
        return int(self.scores.shape[0])


@dataclass(frozen=True)
class DecodeSettings:
    """Thresholds of decoding: minimum score, NMS IoU, detections kept, mask probability threshold,
    smallest mask (pixels), and whether NMS ignores classes (class-agnostic proposals)."""

    conf: float = 0.25
    iou: float = 0.7
    max_det: int = 100
    mask_threshold: float = 0.5
    min_pixels: int = 1
    agnostic: bool = False


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float, max_det: int) -> np.ndarray:
    """Indices kept by greedy non-maximum suppression of (n, 4) x1, y1, x2, y2 boxes: highest score
    first (ties by index), dropping boxes overlapping a kept one with IoU > `iou`; at most `max_det`."""
    order = np.argsort(-np.asarray(scores, np.float64), kind="stable")
    x1, y1, x2, y2 = (np.asarray(boxes, np.float64)[:, k] for k in range(4))
    areas = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    keep: list[int] = []
    while order.size and len(keep) < max_det:
        i, rest = order[0], order[1:]
        keep.append(int(i))
        w = np.clip(np.minimum(x2[i], x2[rest]) - np.maximum(x1[i], x1[rest]), 0, None)
        h = np.clip(np.minimum(y2[i], y2[rest]) - np.maximum(y1[i], y1[rest]), 0, None)
        inter = w * h
        union = areas[i] + areas[rest] - inter
        overlap = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
        order = rest[overlap <= iou]
    return np.asarray(keep, dtype=np.int64)


def _raw_candidates(pred: np.ndarray, nc: int, nm: int, settings: DecodeSettings) -> tuple[np.ndarray, ...]:
    """(boxes xyxy input pixels, scores, classes, coefficients) of a raw (4 + nc + nm, anchors) output."""
    pred = np.asarray(pred, dtype=np.float32)
    class_scores = pred[4 : 4 + nc]
    classes = class_scores.argmax(axis=0)
    scores = class_scores[classes, np.arange(pred.shape[1])]
    cand = np.flatnonzero(scores > settings.conf)
    if cand.size > MAX_NMS:
        cand = cand[np.argsort(-scores[cand], kind="stable")[:MAX_NMS]]
        cand.sort()
    cx, cy, w, h = (pred[k, cand].astype(np.float64) for k in range(4))
    boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)
    scores, classes = scores[cand], classes[cand].astype(np.int64)
    offset = 0.0 if settings.agnostic else classes[:, None] * MAX_WH
    keep = nms(boxes + offset, scores, settings.iou, settings.max_det)
    return boxes[keep], scores[keep], classes[keep], pred[4 + nc : 4 + nc + nm, cand[keep]].T


def _end2end_candidates(pred: np.ndarray, nm: int, settings: DecodeSettings) -> tuple[np.ndarray, ...]:
    """The same from an end-to-end (max_det, 6 + nm) output (already suppressed by the model)."""
    pred = np.asarray(pred, dtype=np.float32)
    keep = np.flatnonzero(pred[:, 4] > settings.conf)
    keep = keep[np.argsort(-pred[keep, 4], kind="stable")][: settings.max_det]
    return (
        pred[keep, :4].astype(np.float64),
        pred[keep, 4],
        pred[keep, 5].round().astype(np.int64),
        pred[keep, 6 : 6 + nm],
    )


def output_layout(output0_shape: tuple[int, ...], nc: int, nm: int) -> str:
    """'raw' or 'end2end' for an `output0` of this shape (batch first), or ValueError."""
    if len(output0_shape) == 3 and output0_shape[1] == 4 + nc + nm:
        return "raw"
    if len(output0_shape) == 3 and output0_shape[2] == 6 + nm:
        return "end2end"
    raise ValueError(
        f"output0 has shape {tuple(output0_shape)}; an ultralytics segmentation export with {nc} classes and {nm} "
        f"mask coefficients gives (1, {4 + nc + nm}, anchors) or (1, max_det, {6 + nm})"
    )


def decode(output0: np.ndarray, protos: np.ndarray, nc: int, box: Letterbox, settings: DecodeSettings) -> Detections:
    """Detections on the original image from one image's outputs: output0 (1, ...) and protos
    (1, nm, mh, mw), for a model with `nc` classes run on an input letterboxed by `box`."""
    protos = np.asarray(protos, dtype=np.float32)[0]
    nm = protos.shape[0]
    layout = output_layout(tuple(np.shape(output0)), nc, nm)
    if layout == "raw":
        boxes, scores, classes, coeffs = _raw_candidates(np.asarray(output0)[0], nc, nm, settings)
    else:
        boxes, scores, classes, coeffs = _end2end_candidates(np.asarray(output0)[0], nm, settings)
    boxes = box.boxes_to_image(boxes)
    logit = math.log(settings.mask_threshold / (1.0 - settings.mask_threshold))
    mask_boxes, crops, kept = [], [], []
    for i in range(boxes.shape[0]):
        found = _mask_in_box(protos, coeffs[i], boxes[i], box, logit)
        if found is None or int(np.count_nonzero(found[1])) < settings.min_pixels:
            continue
        mask_boxes.append(found[0])
        crops.append(found[1])
        kept.append(i)
    kept_idx = np.asarray(kept, dtype=np.int64)
    return Detections(
        shape=box.image_shape,
        boxes=boxes[kept_idx].reshape(-1, 4),
        scores=np.asarray(scores, np.float32)[kept_idx],
        classes=np.asarray(classes, np.int64)[kept_idx],
        mask_boxes=np.asarray(mask_boxes, dtype=np.int64).reshape(-1, 4),
        mask_crops=crops,
    )


def _axis_samples(coord: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bilinear sampling along one prototype axis of `size` cells at continuous `coord` (cell centres at
    integers, clamped at the borders as align_corners=False does): (lower cell, upper cell, weight)."""
    coord = np.clip(coord, 0.0, size - 1.0)
    lower = np.floor(coord).astype(np.int64)
    upper = np.minimum(lower + 1, size - 1)
    return lower, upper, coord - lower


def _mask_in_box(
    protos: np.ndarray, coeff: np.ndarray, box_xyxy: np.ndarray, box: Letterbox, logit: float
) -> tuple[tuple[int, int, int, int], np.ndarray] | None:
    """(tight row0, col0, row1, col1; boolean crop) of one detection's mask, or None when empty."""
    h, w = box.image_shape
    x1, y1, x2, y2 = box_xyxy
    c0, c1 = max(math.ceil(x1), 0), min(math.ceil(x2), w)
    r0, r1 = max(math.ceil(y1), 0), min(math.ceil(y2), h)
    if c1 <= c0 or r1 <= r0:
        return None
    _, mh, mw = protos.shape
    stride_y, stride_x = box.input_shape[0] / mh, box.input_shape[1] / mw
    u0, u1, wu = _axis_samples((box.input_x(np.arange(c0, c1)) + 0.5) / stride_x - 0.5, mw)
    v0, v1, wv = _axis_samples((box.input_y(np.arange(r0, r1)) + 0.5) / stride_y - 0.5, mh)
    # Mask logits only on the prototype cells the box samples.
    rs, re_, cs, ce = int(v0.min()), int(v1.max()) + 1, int(u0.min()), int(u1.max()) + 1
    logits = np.tensordot(coeff.astype(np.float32), protos[:, rs:re_, cs:ce], axes=1)
    rows = logits[v0 - rs] * (1.0 - wv)[:, None] + logits[v1 - rs] * wv[:, None]
    values = rows[:, u0 - cs] * (1.0 - wu)[None, :] + rows[:, u1 - cs] * wu[None, :]
    crop = values > logit
    any_rows, any_cols = np.flatnonzero(crop.any(axis=1)), np.flatnonzero(crop.any(axis=0))
    if any_rows.size == 0:
        return None
    a, b, c, d = any_rows[0], any_rows[-1] + 1, any_cols[0], any_cols[-1] + 1
    return (r0 + int(a), c0 + int(c), r0 + int(b), c0 + int(d)), crop[a:b, c:d].copy()
