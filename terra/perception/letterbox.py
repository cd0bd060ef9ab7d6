"""The letterbox of ultralytics YOLO models: an image scaled to fit the network input, centred, padded.

An (H, W) image is scaled by r = min(in_h / H, in_w / W) to (new_h, new_w) = (round(H r), round(W r))
pixels, then padded with grey (114) to the input size, `top` rows above and `left` columns to the
left (round(pad / 2 - 0.1), as ultralytics' LetterBox does). A point at image pixel coordinates
(x, y) sits at input coordinates (left + x gain_x, top + y gain_y) with gain_x = new_w / W and
gain_y = new_h / H; model outputs (boxes, mask prototypes) are in input coordinates and come back
through the inverse. The reference ignored this step, so its masks were shifted and stretched.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PAD_VALUE = 114  # ultralytics' letterbox grey


@dataclass(frozen=True)
class Letterbox:
    """Placement of an image of `image_shape` (H, W) in a network input of `input_shape` (in_h, in_w)."""

    image_shape: tuple[int, int]
    input_shape: tuple[int, int]
    new_shape: tuple[int, int]
    top: int
    left: int

    @classmethod
    def fit(cls, image_shape: tuple[int, int], input_shape: tuple[int, int]) -> Letterbox:
        """The letterbox of an (H, W) image in an (in_h, in_w) input (scaling up allowed, as ultralytics)."""
        h, w = int(image_shape[0]), int(image_shape[1])
        in_h, in_w = int(input_shape[0]), int(input_shape[1])
        r = min(in_h / h, in_w / w)
        new_h, new_w = max(round(h * r), 1), max(round(w * r), 1)
        top = round((in_h - new_h) / 2 - 0.1)
        left = round((in_w - new_w) / 2 - 0.1)
        return cls((h, w), (in_h, in_w), (new_h, new_w), int(top), int(left))

    @property
    def gain_x(self) -> float:
        return self.new_shape[1] / self.image_shape[1]

    @property
    def gain_y(self) -> float:
        return self.new_shape[0] / self.image_shape[0]

    def boxes_to_image(self, boxes: np.ndarray) -> np.ndarray:
        """(n, 4) x1, y1, x2, y2 boxes from input pixels to image pixels, clipped to the image."""
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4).copy()
        boxes[:, [0, 2]] = (boxes[:, [0, 2]] - self.left) / self.gain_x
        boxes[:, [1, 3]] = (boxes[:, [1, 3]] - self.top) / self.gain_y
        h, w = self.image_shape
        boxes[:, [0, 2]] = boxes[:, [0, 2]].clip(0, w)
        boxes[:, [1, 3]] = boxes[:, [1, 3]].clip(0, h)
        return boxes

    def input_x(self, cols: np.ndarray) -> np.ndarray:
        """Input x coordinate (pixels, continuous) of the centres of image columns `cols`, minus 0.5: the
        coordinate a bilinear resize (align_corners=False) samples for them."""
        return self.left + (np.asarray(cols, np.float64) + 0.5) * self.gain_x - 0.5

    def input_y(self, rows: np.ndarray) -> np.ndarray:
        """As `input_x`, for image rows."""
        return self.top + (np.asarray(rows, np.float64) + 0.5) * self.gain_y - 0.5

    def apply(self, image: np.ndarray) -> np.ndarray:
        """(1, 3, in_h, in_w) float32 network input in 0..1, RGB, from an (H, W, 3) uint8 RGB image.

        Resizing is bilinear without antialiasing (OpenCV's INTER_LINEAR, which ultralytics uses),
        rounded back to 8-bit levels as OpenCV's uint8 resize does."""
        import torch
        import torch.nn.functional as F

        image = np.asarray(image)
        if image.shape[:2] != self.image_shape:
            raise ValueError(f"image is {image.shape[:2]}, letterbox was fitted for {self.image_shape}")
        chw = torch.from_numpy(np.ascontiguousarray(image[..., :3].transpose(2, 0, 1))).float()[None]
        if self.new_shape != self.image_shape:
            chw = F.interpolate(chw, size=self.new_shape, mode="bilinear", align_corners=False, antialias=False)
            chw = chw.round().clamp(0, 255)
        out = np.full((1, 3, *self.input_shape), PAD_VALUE, dtype=np.float32)
        new_h, new_w = self.new_shape
        out[:, :, self.top : self.top + new_h, self.left : self.left + new_w] = chw.numpy()
        return out / np.float32(255.0)
