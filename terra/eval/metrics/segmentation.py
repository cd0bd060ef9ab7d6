"""Terrain segmentation metrics on labelled images (the paper's Table I).

Labels are terrain indices 0..T-1 plus one extra label T for "not terrain" (objects, buildings,
sky). From the confusion matrix M ((T+1) x (T+1), rows = ground truth, columns = prediction),
for each terrain class c:

- IoU_c = M[c,c] / (row_c + col_c - M[c,c]); F1_c = 2 M[c,c] / (row_c + col_c).
- mIoU and F1 are the means of IoU_c and F1_c over terrain classes that occur in the ground truth
  or the prediction (a class absent from both has no defined IoU and is skipped).
- F-mIoU (frequency-weighted mIoU) = sum_c f_c IoU_c with f_c = row_c / sum of rows over terrain
  classes: each class weighs as much as its share of ground-truth terrain pixels.
- FPS = images segmented per second of segmenter wall time (None for a label lookup, which is not a
  segmenter whose speed means anything).

"Not terrain" is a label so that terrain predicted on a car counts as a false positive, but it
is not itself averaged in: the table is about terrain.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


def confusion_matrix(truth: np.ndarray, predicted: np.ndarray, num_labels: int) -> np.ndarray:
    """(L, L) int64 counts of (truth, predicted) label pairs; pixels with a label outside
    [0, num_labels) in either array are ignored."""
    truth = np.asarray(truth).ravel().astype(np.int64)
    predicted = np.asarray(predicted).ravel().astype(np.int64)
    if truth.shape != predicted.shape:
        raise ValueError(f"truth and prediction differ in size: {truth.size} vs {predicted.size}")
    ok = (truth >= 0) & (truth < num_labels) & (predicted >= 0) & (predicted < num_labels)
    flat = np.bincount(truth[ok] * num_labels + predicted[ok], minlength=num_labels * num_labels)
    return flat.reshape(num_labels, num_labels)


@dataclass
class SegmentationScores:
    """Table I figures for one segmenter. Per-class lists follow `classes` (NaN = class absent)."""

    classes: list[str]
    iou: list[float]
    f1_per_class: list[float]
    miou: float
    fw_miou: float
    f1: float
    fps: float | None
    images: int

    def to_json(self) -> dict:
        out = asdict(self)
        out["iou"] = [None if np.isnan(v) else v for v in self.iou]
        out["f1_per_class"] = [None if np.isnan(v) else v for v in self.f1_per_class]
        return out


def segmentation_scores(
    confusion: np.ndarray, classes: list[str], seconds: float = 0.0, images: int = 0, timed: bool = True
) -> SegmentationScores:
    """Scores from a confusion matrix over len(classes) terrain labels plus a last 'not terrain'
    label (shape (T+1, T+1)); `seconds` of segmenter time over `images` images give the FPS (None
    when not `timed`)."""
    confusion = np.asarray(confusion, dtype=np.float64)
    t = len(classes)
    if confusion.shape != (t + 1, t + 1):
        raise ValueError(f"confusion matrix is {confusion.shape}, expected {(t + 1, t + 1)} for {t} terrain classes")
    tp = np.diag(confusion)[:t]
    rows = confusion.sum(axis=1)[:t]
    cols = confusion.sum(axis=0)[:t]
    union = rows + cols - tp
    present = union > 0
    iou = np.where(present, tp / np.where(present, union, 1), np.nan)
    f1 = np.where(present, 2 * tp / np.where(present, rows + cols, 1), np.nan)
    weights = rows / rows.sum() if rows.sum() > 0 else np.zeros(t)
    return SegmentationScores(
        classes=list(classes),
        iou=[float(v) for v in iou],
        f1_per_class=[float(v) for v in f1],
        miou=float(np.mean(iou[present])) if present.any() else 0.0,
        fw_miou=float(np.sum(weights[present] * iou[present])),
        f1=float(np.mean(f1[present])) if present.any() else 0.0,
        fps=(images / seconds if seconds > 0 else 0.0) if timed else None,
        images=int(images),
    )
