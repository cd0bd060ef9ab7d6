"""MaskSet: the class-agnostic masks of one image, stored as boolean crops.

Masks may overlap (FastSAM does; dilated masks do). Each mask is a bounding box (row0, col0,
row1, col1; end exclusive, pixels) and a boolean crop of that box, so a small object in a large
image costs only its box.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage


@dataclass
class MaskSet:
    """M masks on an image of `shape` (H, W).

    boxes: (M, 4) int64 (row0, col0, row1, col1). crops: M boolean arrays of the box sizes.
    class_ids: (M,) source class ids when the masks come from labels (the `labels` embedder uses
    them; model backends leave it None).
    """

    shape: tuple[int, int]
    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), dtype=np.int64))
    crops: list[np.ndarray] = field(default_factory=list)
    class_ids: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.crops)

    @classmethod
    def from_label_image(cls, labels: np.ndarray, class_ids: np.ndarray | None = None) -> MaskSet:
        """Masks from an (H, W) image of mask numbers 1..M (0 = no mask); mask m-1 is number m."""
        labels = np.asarray(labels)
        slices = ndimage.find_objects(labels)
        boxes, crops = [], []
        for number, slc in enumerate(slices, start=1):
            if slc is None:
                boxes.append((0, 0, 0, 0))
                crops.append(np.zeros((0, 0), dtype=bool))
                continue
            boxes.append((slc[0].start, slc[1].start, slc[0].stop, slc[1].stop))
            crops.append(labels[slc] == number)
        return cls(labels.shape[:2], np.asarray(boxes, dtype=np.int64).reshape(-1, 4), crops, class_ids)

    @classmethod
    def from_stack(cls, stack: np.ndarray, class_ids: np.ndarray | None = None) -> MaskSet:
        """Masks from an (M, H, W) boolean stack (e.g. a model's output), cropped to their boxes."""
        stack = np.asarray(stack, dtype=bool)
        boxes, crops = [], []
        for mask in stack:
            rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
            if rows.size == 0:
                boxes.append((0, 0, 0, 0))
                crops.append(np.zeros((0, 0), dtype=bool))
                continue
            r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
            boxes.append((r0, c0, r1, c1))
            crops.append(mask[r0:r1, c0:c1].copy())
        return cls(stack.shape[1:3], np.asarray(boxes, dtype=np.int64).reshape(-1, 4), crops, class_ids)

    def to_stack(self) -> np.ndarray:
        """(M, H, W) boolean stack (for tests and small images)."""
        out = np.zeros((len(self), *self.shape), dtype=bool)
        for m, ((r0, c0, r1, c1), crop) in enumerate(zip(self.boxes, self.crops)):
            out[m, r0:r1, c0:c1] = crop
        return out

    def pixel_counts(self) -> np.ndarray:
        """(M,) number of pixels in each mask."""
        return np.array([int(c.sum()) for c in self.crops], dtype=np.int64)

    def overlap_counts(self, other: np.ndarray) -> np.ndarray:
        """(M,) pixels of each mask that are also set in the (H, W) boolean image `other`."""
        return np.array(
            [
                int(np.count_nonzero(crop & other[r0:r1, c0:c1]))
                for (r0, c0, r1, c1), crop in zip(self.boxes, self.crops)
            ],
            dtype=np.int64,
        )

    def members(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Which of the pixels (rows, cols) (n,) lie in which mask.

        Returns (pixel index, mask index) pairs, ordered by mask then pixel.
        """
        pix_out, mask_out = [], []
        for m, ((r0, c0, r1, c1), crop) in enumerate(zip(self.boxes, self.crops)):
            inside = np.flatnonzero((rows >= r0) & (rows < r1) & (cols >= c0) & (cols < c1))
            hit = inside[crop[rows[inside] - r0, cols[inside] - c0]]
            pix_out.append(hit)
            mask_out.append(np.full(hit.size, m, dtype=np.int64))
        if not pix_out:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        return np.concatenate(pix_out).astype(np.int64), np.concatenate(mask_out)

    def subset(self, keep: np.ndarray) -> MaskSet:
        """The masks at indices `keep` (in that order)."""
        keep = np.asarray(keep, dtype=np.int64)
        return MaskSet(
            self.shape,
            self.boxes[keep].reshape(-1, 4),
            [self.crops[i] for i in keep],
            None if self.class_ids is None else self.class_ids[keep],
        )

    def dilated(self, pixels: int) -> MaskSet:
        """Every mask grown by `pixels` (square structuring element), clipped to the image."""
        if pixels <= 0 or len(self) == 0:
            return self
        H, W = self.shape
        boxes, crops = [], []
        structure = np.ones((2 * pixels + 1, 2 * pixels + 1), dtype=bool)
        for (r0, c0, r1, c1), crop in zip(self.boxes, self.crops):
            if crop.size == 0:
                boxes.append((r0, c0, r1, c1))
                crops.append(crop)
                continue
            n0, m0, n1, m1 = max(r0 - pixels, 0), max(c0 - pixels, 0), min(r1 + pixels, H), min(c1 + pixels, W)
            canvas = np.zeros((n1 - n0, m1 - m0), dtype=bool)
            canvas[r0 - n0 : r1 - n0, c0 - m0 : c1 - m0] = crop
            boxes.append((n0, m0, n1, m1))
            crops.append(ndimage.binary_dilation(canvas, structure=structure))
        return MaskSet(self.shape, np.asarray(boxes, dtype=np.int64).reshape(-1, 4), crops, self.class_ids)
