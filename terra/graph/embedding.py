"""The image embedding of each place (the paper's rule) and the fallback from point embeddings.

Paper rule: the mean of the whole-image embeddings of all images taken within `max_range` metres
of the place whose camera saw it; where no such image exists, the embedding of the nearest image
that saw it. (The reference instead takes the image set of one nearby map point.) Means are
normalised to unit length.

Fallback for places no image saw, or maps without images: the normalised mean of the MS-Avg
features of the observed map points within `max_range` metres (2D) of the place. Points are first
summed per 2 m cell, so the cost is places x cells in range, not places x points.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

from terra.perception.text import normalize_rows

ObservingFn = Callable[[np.ndarray, float], tuple[list[np.ndarray], np.ndarray]]
"""observing(positions (P, 3), max_range) -> (per place: indices of images within range that saw
it, (P,) nearest image that saw it or -1) -- MetricSemanticMap.images_observing."""

POINT_CELL = 2.0  # metres; cell size of the point-embedding fallback


def image_embeddings(
    positions: np.ndarray, observing: ObservingFn, images: np.ndarray, max_range: float = 20.0
) -> tuple[np.ndarray, np.ndarray]:
    """((P, D) float32 unit embeddings, (P,) bool whether an image supplied it); rows of places no
    image saw are zero."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    images = np.asarray(images, dtype=np.float32)
    P, D = len(positions), images.shape[1] if images.ndim == 2 else 0
    if P == 0 or len(images) == 0:
        return np.zeros((P, D), np.float32), np.zeros(P, dtype=bool)
    in_range, nearest = observing(positions, max_range)
    counts = np.array([len(ix) for ix in in_range], dtype=np.int64)
    cols = (
        np.concatenate([np.asarray(ix, dtype=np.int64) for ix in in_range]) if counts.sum() else np.zeros(0, np.int64)
    )
    member = sp.csr_matrix(
        (np.ones(len(cols), np.float32), (np.repeat(np.arange(P), counts), cols)), shape=(P, len(images))
    )
    out = np.asarray(member @ images, dtype=np.float32)
    fallback = (counts == 0) & (np.asarray(nearest) >= 0)
    out[fallback] = images[np.asarray(nearest)[fallback]]
    return normalize_rows(out), (counts > 0) | fallback


def unique_cells(cell: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`np.unique(cell, axis=0, return_inverse=True)` for (n, 2) int64 cells (rows sorted by the
    first column, then the second), through one int64 key per cell: the same result without the
    row-wise sort's copies of the cells."""
    if len(cell) == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    low = cell.min(axis=0)
    span = int(cell[:, 1].max() - low[1]) + 1
    key = (cell[:, 0] - low[0]) * span + (cell[:, 1] - low[1])
    unique, inverse = np.unique(key, return_inverse=True)
    return np.column_stack([unique // span + low[0], unique % span + low[1]]), inverse.ravel()


def point_embeddings(
    positions: np.ndarray,
    points: np.ndarray,
    counts: sp.csr_matrix,
    bank: np.ndarray,
    norms: np.ndarray,
    max_range: float = 20.0,
) -> np.ndarray:
    """(P, D) float32: normalised mean MS-Avg feature of the observed points (N, 3) within
    `max_range` metres (2D) of each place; zero rows where none is in range. counts: (N, K) sparse
    observation counts over the bank (K, D) of unit vectors; norms: (N,) row norms of counts @ bank
    (MetricSemanticMap.ms_avg_norms, 0 = unobserved)."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    bank = np.asarray(bank, dtype=np.float32)
    counts = sp.csr_matrix(counts)
    norms = np.asarray(norms)
    seen = np.flatnonzero(norms > 0)
    P = len(positions)
    if P == 0 or seen.size == 0:
        return np.zeros((P, bank.shape[1]), np.float32)
    # Only the observed points' x, y in float64 (not a float64 copy of the whole map).
    cell = np.floor(np.asarray(points[seen, :2], dtype=np.float64) / POINT_CELL).astype(np.int64)
    keys, cell_of = unique_cells(cell)
    del cell
    # Per cell: sum of unit MS-Avg features = (cell membership / norm) @ counts @ bank.
    inverse_norm = 1.0 / np.asarray(norms[seen], dtype=np.float64)
    member = sp.csr_matrix((inverse_norm, (cell_of, np.arange(seen.size))), shape=(len(keys), seen.size))
    cell_counts = member @ counts[seen]  # (cells, K)
    centres = (keys + 0.5) * POINT_CELL
    near = cKDTree(centres).query_ball_point(positions[:, :2], r=max_range)
    lens = np.array([len(n) for n in near], dtype=np.int64)
    cols = np.concatenate([np.asarray(n, dtype=np.int64) for n in near]) if lens.sum() else np.zeros(0, np.int64)
    reach = sp.csr_matrix((np.ones(len(cols)), (np.repeat(np.arange(P), lens), cols)), shape=(P, len(keys)))
    return normalize_rows(np.asarray((reach @ cell_counts) @ bank, dtype=np.float32))
