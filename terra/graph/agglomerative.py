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

Cuts, three ways:
- Adaptive (the default, `cuts=None`): the cut heights come from the tree's own merge heights, so
  every level carries information on any map. Level 1 has about P / `first_size` regions, the top
  level `top` regions, the levels between a geometric progression; each level cuts the tree at
  the merge height that leaves that many regions, moved within `snap` times that count to the
  largest relative gap between successive merge heights (a natural break). Counts strictly
  decrease upward whenever the map has places enough.
- Fixed heights (`cuts=(50, 100, 200, 400)`, the paper's, in metres plus gamma times a cosine
  distance). They do not scale with the scene: on a map smaller than about twice the largest cut,
  the upper levels are one region each.
- `gap_levels=n`: just below the n largest gaps between successive merge heights (the reference
  code's integer `agg_params` option).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.sparse.csgraph import connected_components
from scipy.spatial.distance import cdist, pdist

from terra.perception.text import normalize_rows


@dataclass(frozen=True)
class AdaptiveCuts:
    """How adaptive cuts are chosen (see the module docstring): `levels` region levels, about
    `first_size` places per level-1 region, `top` regions at the top level, and natural breaks
    searched within counts between c / snap and c * snap (snap 1 = exact counts)."""

    levels: int = 4
    first_size: float = 8.0
    top: int = 3
    snap: float = 1.25


def agglomerative_assignments(
    position: np.ndarray,
    embedding: np.ndarray,
    terrain: np.ndarray,
    gamma: float = 100.0,
    cuts: tuple[float, ...] | None = (50.0, 100.0, 200.0, 400.0),
    dense_max: int = 5000,
    micro_max: int = 5000,
    gap_levels: int | None = None,
    adaptive: AdaptiveCuts | None = None,
) -> list[np.ndarray]:
    """Per level, (P,) cluster label of every place (labels nest from level to level). Levels come
    from `cuts` (fixed heights), or with `gap_levels` from the largest merge-height gaps, or with
    `cuts=None` adaptively (`adaptive`, default AdaptiveCuts()); see the module docstring."""
    position = np.asarray(position, dtype=np.float64)
    unit = normalize_rows(embedding).astype(np.float64)
    adaptive = adaptive or AdaptiveCuts()
    n_levels = gap_levels or (len(cuts) if cuts is not None else adaptive.levels)
    P = len(position)
    if P <= 1:
        return [np.zeros(P, np.int64) for _ in range(n_levels)]
    if dense_max >= P:
        # For unit vectors 1 - cos = |e_i - e_j|^2 / 2.
        w = pdist(position)
        w += (0.5 * gamma) * condensed_sqeuclidean(unit)
        Z = linkage(w, method="average")
        heights = _level_heights(Z[:, 2], P, P, cuts, gap_levels, adaptive)
        return [fcluster(Z, t, criterion="distance").astype(np.int64) - 1 for t in heights]
    first_cut = cuts[0] if cuts is not None else 50.0
    group = micro_clusters(position, terrain, cell=first_cut / 10.0, max_groups=micro_max)
    G = int(group.max()) + 1
    size = np.bincount(group, minlength=G).astype(np.float64)
    centroid = (
        np.stack([np.bincount(group, weights=position[:, d], minlength=G) for d in range(3)], axis=1) / size[:, None]
    )
    emb_sum = np.zeros((G, unit.shape[1]))
    np.add.at(emb_sum, group, unit)
    D = cdist(centroid, centroid)
    for lo in range(0, G, 1024):  # row blocks keep the temporaries small
        hi = min(lo + 1024, G)
        D[lo:hi] += gamma * (1.0 - (emb_sum[lo:hi] @ emb_sum.T) / np.outer(size[lo:hi], size))
    merges = weighted_average_linkage(D, size)
    heights = _level_heights(merges[:, 2], G, P, cuts, gap_levels, adaptive)
    return [group_labels(merges, G, t)[group] for t in heights]


def condensed_sqeuclidean(x: np.ndarray, block: int = 256) -> np.ndarray:
    """pdist(x, "sqeuclidean") from matrix products: |x_i|^2 + |x_j|^2 - 2 x_i . x_j, row blocks of
    `block` at a time (a 1,600 x 384 embedding takes a third of pdist's loop; no P x P matrix).
    Values agree with pdist's to about 1e-14 (clipped at 0)."""
    x = np.asarray(x, dtype=np.float64)
    P = len(x)
    norms = np.einsum("ij,ij->i", x, x)
    out = np.empty(P * (P - 1) // 2)
    at = 0
    for lo in range(0, P, block):
        hi = min(lo + block, P)
        gram = x[lo:hi] @ x[lo:].T
        for i in range(lo, hi):  # condensed order: row i's pairs (i, j > i) in turn
            width = P - i - 1
            out[at : at + width] = norms[i] + norms[i + 1 :] - 2.0 * gram[i - lo, i - lo + 1 :]
            at += width
    return np.maximum(out, 0.0, out=out)


def _level_heights(
    heights: np.ndarray,
    items: int,
    places: int,
    cuts: tuple[float, ...] | None,
    gap_levels: int | None,
    adaptive: AdaptiveCuts,
) -> tuple[float, ...]:
    """Cut heights of the levels: fixed `cuts`, gap cuts, or adaptive ones for a tree over `items`
    leaves (places, or micro-clusters standing for `places` places)."""
    if gap_levels:
        return gap_cuts(heights, gap_levels)
    if cuts is not None:
        return tuple(cuts)
    counts = level_counts(places, adaptive.levels, adaptive.first_size, adaptive.top, max_count=items)
    return count_cuts(heights, items, counts, adaptive.snap)


def level_counts(places: int, levels: int, first_size: float, top: int, max_count: int | None = None) -> list[int]:
    """Region counts per level, fine to coarse: about places / first_size at level 1 (at most
    max_count), `top` at the top, a geometric progression between, strictly decreasing while
    counts above 1 allow it."""
    n1 = int(np.clip(round(places / first_size), 1, max_count or places))
    top = int(np.clip(top, 1, n1))
    if levels == 1:
        return [n1]
    counts = [int(round(n1 * (top / n1) ** (k / (levels - 1)))) for k in range(levels)]
    for k in range(1, levels):
        counts[k] = max(1, min(counts[k], counts[k - 1] - 1))
    return counts


def count_cuts(heights: np.ndarray, items: int, counts: list[int], snap: float = 1.0) -> tuple[float, ...]:
    """Increasing cut heights giving about `counts` clusters (decreasing) from a tree over `items`
    leaves with merge heights `heights` (items - 1 values; cutting at h applies every merge <= h).

    Each cut sits at a merge height: for c clusters, the (items - c)-th smallest. With snap > 1, the
    count may move within [c / snap, c * snap] (and strictly between the neighbouring levels'
    counts) to where the next merge height is relatively furthest above: a natural break.
    """
    h = np.sort(np.asarray(heights, dtype=np.float64))
    if len(h) == 0:
        return tuple(0.0 for _ in counts)
    # cut_after[m] = cutting after the m smallest merges (m = 1..items-1) leaves items - m clusters.
    gap = np.append((h[1:] - h[:-1]) / np.maximum(h[1:], 1e-12), np.inf)  # above merge m (1-based: gap[m-1])
    out: list[float] = []
    upper = items + 1  # the level below has fewer than this many clusters
    for c in counts:
        c = int(np.clip(c, 1, items))
        lo = max(1, int(np.ceil(c / snap)))
        hi = min(items, int(np.floor(c * snap)), upper - 1)
        options = np.arange(max(lo, 1), max(hi, lo) + 1)
        options = options[(options >= 1) & (options <= items) & (options < upper)]
        if options.size == 0:
            options = np.array([max(1, min(c, upper - 1))])
        merges = items - options  # merges applied for each option
        score = np.where(merges >= 1, gap[np.maximum(merges - 1, 0)], -np.inf)
        best = int(options[np.lexsort((np.abs(options - c), -score))[0]])
        m = items - best
        out.append(float(h[m - 1]) if m >= 1 else float(h[0]) - 1.0)
        upper = best
    return tuple(out)


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
