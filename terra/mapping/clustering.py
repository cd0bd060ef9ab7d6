"""Per-mask DBSCAN: keep only the largest cluster of a mask's 3D points (paper, Phase 1).

2D masks bleed onto the background through gaps and boundaries; the background points form
their own clusters away from the object. All masks of an image are clustered in one DBSCAN call
(terra.dbscan: scikit-learn's labels, weights summed in one vectorised step): each mask's points
get a fourth coordinate, the mask number times 3 eps, so points of different masks are never
neighbours and the result equals one DBSCAN per mask.

With `voxel` > 0 a mask's points are first merged per voxel (edge `voxel` metres) into weighted
samples (DBSCAN's sample_weight), which gives the same clusters up to the voxel size at a
fraction of the cost: a close building wall puts thousands of points in one mask. A mask with more
than MAX_SAMPLES samples is merged on wider voxels again (so a facade's clusters are found to about
half a metre instead of a fifth).
"""

from __future__ import annotations

import numpy as np

from terra.dbscan import dbscan_labels
from terra.geometry import voxel_keys

MAX_SAMPLES = 1500  # weighted samples per mask before its voxels widen (_voxel_samples)


def largest_clusters(
    points: np.ndarray, group: np.ndarray, eps: float, min_samples: int, voxel: float = 0.0
) -> np.ndarray:
    """Boolean (n,) keep-mask: True for points in the largest DBSCAN cluster of their group.

    points: (n, 3) metres. group: (n,) non-negative group (mask) ids. eps: metres. min_samples
    counts points (the point itself included). Noise points and smaller clusters are dropped; a
    group with no cluster keeps nothing; ties keep the cluster found first.
    """
    n = points.shape[0]
    keep = np.zeros(n, dtype=bool)
    if n == 0:
        return keep
    points = np.asarray(points, dtype=np.float64)
    group = np.asarray(group, dtype=np.int64)
    # Compact group numbers keep the fourth coordinate small whatever the ids are.
    _, dense = np.unique(group, return_inverse=True)
    if voxel > 0:
        sample, weight = _voxel_samples(points, dense, voxel)
        centres = np.stack([np.bincount(sample, weights=points[:, a]) for a in range(3)], axis=1) / weight[:, None]
        sample_group = np.zeros(weight.size, dtype=np.int64)
        sample_group[sample] = dense
    else:
        sample, weight, centres, sample_group = np.arange(n), np.ones(n), points, dense
    lifted = np.column_stack([centres, sample_group * (3.0 * eps)])
    labels = dbscan_labels(lifted, eps, min_samples, sample_weight=weight)[sample]
    clustered = np.flatnonzero(labels >= 0)
    if clustered.size == 0:
        return keep
    sizes = np.bincount(labels[clustered])
    # Each cluster lies in one group; pick per group the largest (then lowest-numbered) cluster.
    cluster_group = np.zeros(sizes.size, dtype=np.int64)
    cluster_group[labels[clustered]] = dense[clustered]
    cluster_ids = np.arange(sizes.size)
    order = np.lexsort((cluster_ids, -sizes, cluster_group))
    first = np.ones(order.size, dtype=bool)
    first[1:] = cluster_group[order[1:]] != cluster_group[order[:-1]]
    winners = np.zeros(sizes.size, dtype=bool)
    winners[order[first]] = True
    keep[clustered] = winners[labels[clustered]]
    return keep


def _voxel_samples(
    points: np.ndarray, group: np.ndarray, voxel: float, max_samples: int = MAX_SAMPLES
) -> tuple[np.ndarray, np.ndarray]:
    """Sample number (n,) of each point, one sample per (group, voxel), and each sample's weight. A group
    with more than `max_samples` samples is merged again on voxels wider by the square root of its excess
    (its samples lie on surfaces): DBSCAN's pairs grow with samples times neighbours, and one close
    facade with thousands of samples cost most of a frame's fusion."""
    sample, new = _samples_of(voxel_keys(points, voxel), group)
    per_group = np.bincount(group[new], minlength=int(group.max()) + 1)
    excess = per_group / max(max_samples, 1)
    if max_samples > 0 and (excess > 1.0).any():
        widen = np.where(excess > 1.0, np.ceil(np.sqrt(excess)), 1.0)
        sample, _ = _samples_of(voxel_keys(points, (voxel * widen[group])[:, None]), group)
    return sample, np.bincount(sample).astype(np.float64)


def _samples_of(keys: np.ndarray, group: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sample number (n,) per point, one per (group, key); (n,) mask of the points that start a sample)."""
    order = np.lexsort((keys, group))
    new = np.ones(order.size, dtype=bool)
    new[1:] = (keys[order[1:]] != keys[order[:-1]]) | (group[order[1:]] != group[order[:-1]])
    sample = np.empty(order.size, dtype=np.int64)
    sample[order] = np.cumsum(new) - 1
    first = np.zeros(order.size, dtype=bool)
    first[order[new]] = True
    return sample, first
