"""Neighbour searches of the query path: pairs within a radius, nearest reference point.

Small inputs (the usual object query: a few hundred matched points, a few objects against the
places) are answered by direct distance computation, so a cold `terra find` does not import
scipy.spatial (about 0.2 s); larger ones use SciPy's k-d tree. Both give the same answers:
distances are compared squared, summed over the axes in order, against the squared radius.
"""

from __future__ import annotations

import numpy as np

# Largest point-pair count computed directly; above it the k-d tree is faster even counting its
# import (a few hundred matched points, or a few objects against a campus's places, stay below).
DIRECT_LIMIT = 250_000


def pairs_within(points: np.ndarray, radius: float) -> np.ndarray:
    """(k, 2) int64 index pairs i < j of the points (n, d) at most `radius` apart (inclusive)."""
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    if n * n <= DIRECT_LIMIT:
        i, j = np.triu_indices(n, k=1)
        d2 = ((points[i] - points[j]) ** 2).sum(axis=1)
        keep = d2 <= radius * radius
        return np.column_stack([i[keep], j[keep]]).astype(np.int64)
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  (compiled, no stub)

    return cKDTree(points).query_pairs(radius, output_type="ndarray").astype(np.int64)


def nearest(reference: np.ndarray, queries: np.ndarray, max_distance: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """For each query point (n, d): the distance to the nearest reference point (m, d) and its
    index; (inf, m) when none lies within max_distance (SciPy's convention)."""
    reference = np.asarray(reference, dtype=np.float64)
    queries = np.asarray(queries, dtype=np.float64)
    m = len(reference)
    if len(queries) * m <= DIRECT_LIMIT and m > 0:
        d2 = ((queries[:, None, :] - reference[None, :, :]) ** 2).sum(axis=2) if len(queries) else np.zeros((0, m))
        index = d2.argmin(axis=1) if len(queries) else np.zeros(0, dtype=np.int64)
        dist = np.sqrt(d2[np.arange(len(queries)), index])
        far = dist > max_distance
        return np.where(far, np.inf, dist), np.where(far, m, index).astype(np.int64)
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  (compiled, no stub)

    dist, index = cKDTree(reference).query(queries, k=1, distance_upper_bound=max_distance)
    return np.asarray(dist, dtype=np.float64), np.asarray(index, dtype=np.int64)
