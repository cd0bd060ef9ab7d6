"""Per-mask DBSCAN: keep only the largest cluster of a mask's 3D points (paper, Phase 1).

2D masks bleed onto the background through gaps and boundaries; the background points form
their own clusters away from the object. All masks of an image are clustered in one scikit-learn
DBSCAN call: each mask's points get a fourth coordinate, the mask number times 3 eps, so points of
different masks are never neighbours and the result equals one DBSCAN per mask.
"""

from __future__ import annotations

import numpy as np
from sklearn.cluster import DBSCAN


def largest_clusters(points: np.ndarray, group: np.ndarray, eps: float, min_samples: int) -> np.ndarray:
    """Boolean (n,) keep-mask: True for points in the largest DBSCAN cluster of their group.

    points: (n, 3) metres. group: (n,) non-negative group (mask) ids. Noise points and smaller
    clusters are dropped; a group with no cluster keeps nothing. Ties keep the cluster found first.
    """
    n = points.shape[0]
    keep = np.zeros(n, dtype=bool)
    if n == 0:
        return keep
    group = np.asarray(group, dtype=np.int64)
    # Compact group numbers keep the fourth coordinate small whatever the ids are.
    _, dense = np.unique(group, return_inverse=True)
    lifted = np.column_stack([np.asarray(points, dtype=np.float64), dense * (3.0 * eps)])
    labels = DBSCAN(eps=eps, min_samples=min_samples).fit_predict(lifted)
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
