"""DBSCAN on SciPy alone, with scikit-learn's labels, for the query path and Phase 1's masks.

Importing scikit-learn's cluster package takes about a second, most of a cold query's budget, and
its radius search dominated a warm object query; with sample weights (Phase 1's voxel-merged mask
points) it sums each neighbourhood's weights in a Python loop, a third of a frame's fusion. This
is the same algorithm on neighbour pairs (terra.neighbours: direct for small sets, SciPy's k-d
tree for large ones): a point is core when the points within `eps` (inclusive), itself included,
weigh at least `min_samples` (each weighs 1 without weights); clusters are the connected
components of core points; a border point joins the cluster found first.
scikit-learn expands clusters in order of their lowest-index core point and a border point takes
the first cluster that reaches it, so "first" is the adjacent cluster with the lowest first core
index, and the labels below equal `DBSCAN(eps, min_samples).fit_predict` (tests compare them on
random and gridded point sets, with and without weights).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from terra.neighbours import pairs_within


def dbscan_labels(
    points: np.ndarray, eps: float, min_samples: float, sample_weight: np.ndarray | None = None
) -> np.ndarray:
    """(n,) int64 cluster labels 0..C-1 (numbered by lowest core index), -1 for noise.

    points: (n, d) coordinates (metres for map points); eps: neighbourhood radius, same unit;
    min_samples: weight of the neighbourhood (the point included) that makes a point core;
    sample_weight: (n,) weight of each point (default 1), as scikit-learn's `sample_weight`.
    """
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    labels = np.full(n, -1, dtype=np.int64)
    if n == 0:
        return labels
    pairs = pairs_within(points, eps)
    i, j = pairs[:, 0], pairs[:, 1]
    if sample_weight is None:
        degree = np.bincount(i, minlength=n) + np.bincount(j, minlength=n) + 1
    else:
        weight = np.asarray(sample_weight, dtype=np.float64)
        degree = (
            np.bincount(i, weights=weight[j], minlength=n) + np.bincount(j, weights=weight[i], minlength=n) + weight
        )
    core = degree >= min_samples
    cores = np.flatnonzero(core)
    if cores.size == 0:
        return labels
    # Components of the core points; renumber them by their lowest core index.
    both = core[i] & core[j]
    position = np.full(n, -1, dtype=np.int64)
    position[cores] = np.arange(cores.size)
    graph = sp.coo_matrix(
        (np.ones(int(both.sum()), dtype=np.int8), (position[i[both]], position[j[both]])),
        shape=(cores.size, cores.size),
    )
    _, component = connected_components(graph, directed=False)
    first_core = np.full(component.max() + 1, n, dtype=np.int64)
    np.minimum.at(first_core, component, cores)
    rank = np.empty_like(first_core)
    rank[np.argsort(first_core, kind="stable")] = np.arange(first_core.size)
    labels[cores] = rank[component]
    # Border points: the lowest-numbered cluster among their core neighbours.
    src = np.concatenate([i, j])
    dst = np.concatenate([j, i])
    border = ~core[src] & core[dst]
    if border.any():
        best = np.full(n, np.iinfo(np.int64).max, dtype=np.int64)
        np.minimum.at(best, src[border], labels[dst[border]])
        touched = np.flatnonzero(best != np.iinfo(np.int64).max)
        labels[touched] = best[touched]
    return labels
