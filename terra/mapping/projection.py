"""Which LiDAR points a camera sees, and at which pixel: projection with a z-buffer.

A scan point is visible in an image when it is in front of the camera (depth > min_depth), lands
inside the image after the calibration's lens distortion, and is the nearest point to the camera
in its z-buffer cell (one pixel by default). The z-buffer matters because the camera sits apart
from the LiDAR: a point the LiDAR sees behind an object's edge can be hidden from the camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terra.geometry import CameraCalibration, project_points, transform_points


@dataclass
class VisiblePoints:
    """Visible scan points of one image, in scan order.

    index: (n,) int64 indices into the scan. rows, cols: (n,) int64 pixel of each (row = v,
    col = u). distance: (n,) float64 metres from the camera centre.
    """

    index: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    distance: np.ndarray

    def __len__(self) -> int:
        return int(self.index.shape[0])


def visible_points(
    points_lidar: np.ndarray,
    camera: CameraCalibration,
    min_depth: float = 0.1,
    zbuffer_px: int = 1,
) -> VisiblePoints:
    """Project a scan (N, 3, metres, LiDAR frame) into `camera` and keep the nearest point per
    z-buffer cell of `zbuffer_px` x `zbuffer_px` pixels (ties: lowest scan index)."""
    points_cam = transform_points(camera.T_cam_lidar, np.asarray(points_lidar, dtype=np.float64))
    uv, valid = project_points(points_cam, camera, min_depth=min_depth)
    index = np.flatnonzero(valid)
    # Pixel (0, 0) is centred at uv (0, 0), so a pixel spans [-0.5, 0.5).
    cols = np.floor(uv[index, 0] + 0.5).astype(np.int64)
    rows = np.floor(uv[index, 1] + 0.5).astype(np.int64)
    distance = np.linalg.norm(points_cam[index], axis=1)
    cells_per_row = -(-camera.width // zbuffer_px)
    cell = (rows // zbuffer_px) * cells_per_row + cols // zbuffer_px
    order = np.lexsort((index, distance, cell))
    first = np.ones(order.size, dtype=bool)
    first[1:] = cell[order[1:]] != cell[order[:-1]]
    keep = np.sort(order[first])
    return VisiblePoints(index[keep], rows[keep], cols[keep], distance[keep])
