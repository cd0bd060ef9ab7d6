"""Navigation metrics: path length and the length of it on each terrain.

The path is the polyline through its waypoints (metres, map frame). The terrain under it is read
from the ground-truth raster, independently of the planner's own bookkeeping: each segment is
cut into pieces no longer than `step` metres and each piece takes the class at its midpoint.
"""

from __future__ import annotations

import numpy as np

from terra.datasets.ground_truth import TerrainRaster


def path_length(waypoints: np.ndarray) -> float:
    """Length (metres) of the polyline through waypoints (n, 3)."""
    waypoints = np.asarray(waypoints, dtype=np.float64)
    if len(waypoints) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(waypoints, axis=0), axis=1).sum())


def path_terrain_lengths(waypoints: np.ndarray, raster: TerrainRaster, step: float = 0.1) -> dict[str, float]:
    """Metres of the path over each ground-truth class (names from the raster legend; 'outside'
    for pieces off the raster), by midpoint sampling of pieces at most `step` metres long."""
    waypoints = np.asarray(waypoints, dtype=np.float64)
    if len(waypoints) < 2:
        return {}
    seg = np.diff(waypoints, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    pieces = np.maximum(1, np.ceil(seg_len / step).astype(np.int64))
    seg_of = np.repeat(np.arange(len(seg)), pieces)
    # Fraction along the segment of each piece's midpoint: (k + 0.5) / pieces.
    k = np.arange(seg_of.size) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    frac = (k + 0.5) / pieces[seg_of]
    mid = waypoints[seg_of, :2] + frac[:, None] * seg[seg_of, :2]
    piece_len = seg_len[seg_of] / pieces[seg_of]
    cls = raster.class_at(mid)
    ids, inverse = np.unique(cls, return_inverse=True)
    sums = np.bincount(inverse, weights=piece_len)
    return {("outside" if i < 0 else raster.legend.get(int(i), str(int(i)))): float(v) for i, v in zip(ids, sums)}


def terrain_shares(lengths: dict[str, float]) -> dict[str, float]:
    """Each terrain's share of the total length (0..1)."""
    total = sum(lengths.values())
    return {k: (v / total if total > 0 else 0.0) for k, v in lengths.items()}
