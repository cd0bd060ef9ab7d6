"""Agglomerative regions: average linkage on the paper's weight, cut at fixed heights.

Up to `dense_max` places the tree is exact: scipy's average linkage on the condensed matrix of
w_ij = |p_i - p_j| + gamma (1 - cos(e_i, e_j)), P (P - 1) / 2 float64 values (5,000 places:
100 MB, times about three while it is built).

Above that no P x P matrix is formed. Places are first grouped into micro-clusters: one per
(terrain, square grid cell), the cell side doubling from cuts[0] / 10 until at most `micro_max`
groups remain. Average linkage then runs over the micro-clusters, weighted by their sizes (UPGMA
with initial weights, by the nearest-neighbour chain on an M x M matrix), with the between-group
average of w taken as |centroid_a - centroid_b| + gamma (1 - s_a . s_b / (n_a n_b)), where s is
the sum of the group's unit embeddings: the semantic part is the exact pairwise average, the
metric part the centroid distance, which differs from the mean pairwise distance by at most
about the cell size. All places of a micro-cluster share their regions.

Cuts: by default the paper's fixed heights (50/100/200/400, metres plus gamma times a cosine
distance). They do not scale with the scene: on a map smaller than about twice the largest cut,
the upper levels are one region each. `gap_levels=n` instead cuts just below the n largest gaps
between successive merge heights (the reference code's integer `agg_params` option; not the paper's
default, and only used when configured).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.sparse.csgraph import connected_components
from scipy.spatial.distance import cdist, pdist

from terra.perception.text import normalize_rows


def agglomerative_assignments(
    position: np.ndarray,
    embedding: np.ndarray,
    terrain: np.ndarray,
    gamma: float = 100.0,
    cuts: tuple[float, ...] = (50.0, 100.0, 200.0, 400.0),
    dense_max: int = 5000,
    micro_max: int = 5000,
    gap_levels: int | None = None,
) -> list[np.ndarray]:
    """Per cut height, (P,) cluster label of every place (labels nest from cut to cut). With
    `gap_levels`, the cuts are the heights just below the largest merge-height gaps (see module)."""
    position = np.asarray(position, dtype=np.float64)
    unit = normalize_rows(embedding).astype(np.float64)
    P = len(position)
    if P == 0:
        return [np.zeros(0, np.int64) for _ in range(gap_levels or len(cuts))]
    if P == 1:
        return [np.zeros(1, np.int64) for _ in range(gap_levels or len(cuts))]
    if P <= dense_max:
        # For unit vectors 1 - cos = |e_i - e_j|^2 / 2.
        w = pdist(position)
        w += (0.5 * gamma) * pdist(unit, "sqeuclidean")
        Z = linkage(w, method="average")
        if gap_levels:
            cuts = gap_cuts(Z[:, 2], gap_levels)
        return [fcluster(Z, t, criterion="distance").astype(np.int64) - 1 for t in cuts]
    group = micro_clusters(position, terrain, cell=cuts[0] / 10.0, max_groups=micro_max)
    G = int(group.max()) + 1
    size = np.bincount(group, minlength=G).astype(np.float64)
    centroid = np.stack([np.bincount(group, weights=position[:, d], minlength=G) for d in range(3)], axis=1) / size[:, None]
    emb_sum = np.zeros((G, unit.shape[1]))
    np.add.at(emb_sum, group, unit)
    D = cdist(centroid, centroid)
    for lo in range(0, G, 1024):  # row blocks keep the temporaries small
        hi = min(lo + 1024, G)
        D[lo:hi] += gamma * (1.0 - (emb_sum[lo:hi] @ emb_sum.T) / np.outer(size[lo:hi], size))
    merges = weighted_average_linkage(D, size)
    if gap_levels:
        cuts = gap_cuts(merges[:, 2], gap_levels)
    return [group_labels(merges, G, t)[group] for t in cuts]


def gap_cuts(heights: np.ndarray, n: int) -> tuple[float, ...]:
    """n increasing cut heights, each the lower end of one of the n largest gaps between
    successive merge heights (fewer merges than n: the last cut repeats)."""
    h = np.sort(np.asarray(heights, dtype=np.float64))
    if len(h) < 2:
        return tuple([float(h[-1]) if len(h) else 0.0] * n)
    gaps = np.diff(h)
    top = np.sort(np.argsort(-gaps, kind="stable")[:n])
    cuts = [float(h[i]) for i in top]
    return tuple(cuts + [cuts[-1]] * (n - len(cuts)))


def micro_clusters(position: np.ndarray, terrain: np.ndarray, cell: float, max_groups: int) -> np.ndarray:
    """(P,) group index: places sharing terrain and square grid cell (side `cell` metres, doubled
    until there are at most `max_groups` groups)."""
    terrain = np.asarray(terrain, dtype=np.int64)
    while True:
        key = np.column_stack([terrain, np.floor(position[:, :2] / cell).astype(np.int64)])
        _, group = np.unique(key, axis=0, return_inverse=True)
        group = group.ravel()
        if group.max() + 1 <= max_groups:
            return group
        cell *= 2.0


def weighted_average_linkage(D: np.ndarray, size: np.ndarray) -> np.ndarray:
    """Average linkage (UPGMA) of M clusters with initial sizes, by the nearest-neighbour chain.

    D: (M, M) symmetric average distances between the initial clusters (overwritten). Returns
    (M - 1, 3) merges [a, b, height], a and b being any member index of each merged side.
    Lance-Williams: d(k, a+b) = (n_a d(k, a) + n_b d(k, b)) / (n_a + n_b). Ties go to the lower index.
    """
    M = len(D)
    np.fill_diagonal(D, np.inf)
    size = np.asarray(size, dtype=np.float64).copy()
    alive = np.ones(M, dtype=bool)
    merges = np.zeros((max(M - 1, 0), 3))
    chain: list[int] = []
    done = 0
    while done < M - 1:
        if not chain:
            chain.append(int(np.flatnonzero(alive)[0]))
        a = chain[-1]
        row = D[a]
        b = int(np.argmin(row))
        if len(chain) > 1 and row[chain[-2]] <= row[b]:
            b = chain[-2]
        if len(chain) > 1 and b == chain[-2]:
            chain.pop()
            chain.pop()
            merges[done] = (a, b, row[b])
            done += 1
            new = (size[a] * D[a] + size[b] * D[b]) / (size[a] + size[b])
            keep, gone = min(a, b), max(a, b)
            D[keep, :] = new
            D[:, keep] = new
            D[gone, :] = np.inf
            D[:, gone] = np.inf
            D[keep, keep] = np.inf
            size[keep] += size[gone]
            alive[gone] = False
        else:
            chain.append(b)
    return merges


def group_labels(merges: np.ndarray, M: int, height: float) -> np.ndarray:
    """(M,) cluster labels after applying every merge at or below `height` (0-based, in order of
    each cluster's lowest member)."""
    take = merges[:, 2] <= height
    a, b = merges[take, 0].astype(np.int64), merges[take, 1].astype(np.int64)
    graph = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(M, M))
    _, labels = connected_components(graph, directed=False)
    return labels.astype(np.int64)
