"""Spectral regions: recursive two-way splits of the places graph, cut into fixed levels.

Affinity on each place edge: exp(-w / sigma), w the paper's weight, so similar neighbours attract
(the reference fed the distance-like weight itself as the affinity). Each split is
scikit-learn's SpectralClustering(2, affinity="precomputed") with a fixed seed; a cluster whose
subgraph is disconnected is split into its largest component and the rest instead.

Stopping (the paper's rule, `stop_rule="either"`): a cluster stops splitting once its semantic
difference is below `max_semantic_diff` or its 2D bounding-box area is below `min_area` m^2. The
semantic difference is the cosine of the member most similar to the cluster's mean embedding minus
that of the least similar one. `stop_rule="both"` stops only when both hold (the reference code).

Levels: leaves are level 1. With the leaves' maximum depth d_max and L levels, level k >= 2 is
each leaf's ancestor at depth min(depth, floor(d_max (L - k + 1) / L)), so every level coarsens
the one below and all places sit in exactly one region per level.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from sklearn.cluster import SpectralClustering

from terra.graph.regions import paper_weight
from terra.perception.text import normalize_rows


def semantic_difference(embedding: np.ndarray) -> float:
    """max - min cosine of the members (n, D) to their normalised mean embedding."""
    unit = normalize_rows(embedding)
    sims = unit @ normalize_rows(unit.mean(axis=0, keepdims=True))[0]
    return float(sims.max() - sims.min()) if len(sims) else 0.0


def bbox_area(position: np.ndarray) -> float:
    """Area (m^2) of the 2D axis-aligned bounding box of (n, 3) positions."""
    if len(position) == 0:
        return 0.0
    span = position[:, :2].max(axis=0) - position[:, :2].min(axis=0)
    return float(span[0] * span[1])


def should_stop(position: np.ndarray, embedding: np.ndarray, max_semantic_diff: float, min_area: float, stop_rule: str) -> bool:
    small_diff = semantic_difference(embedding) < max_semantic_diff
    small_area = bbox_area(position) < min_area
    return (small_diff and small_area) if stop_rule == "both" else (small_diff or small_area)


def two_way_split(affinity: sp.csr_matrix, seed: int) -> np.ndarray:
    """(n,) bool side of each node: a spectral bisection of a connected affinity graph, or the
    largest component versus the rest when it is disconnected."""
    n = affinity.shape[0]
    n_comp, comp = connected_components(affinity, directed=False)
    if n_comp > 1:
        sizes = np.bincount(comp)
        largest = int(np.lexsort((np.arange(n_comp), -sizes))[0])
        return comp == largest
    model = SpectralClustering(n_clusters=2, affinity="precomputed", random_state=seed, assign_labels="cluster_qr")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # sklearn warns about graphs it considers not fully connected
        labels = model.fit_predict(affinity)
    return labels == labels[0]


def spectral_assignments(
    position: np.ndarray,
    embedding: np.ndarray,
    edges: np.ndarray,
    gamma: float = 100.0,
    levels: int = 4,
    max_semantic_diff: float = 0.45,
    min_area: float = 10000.0,
    stop_rule: str = "either",
    sigma: float | None = None,
    min_places: int = 4,
    max_depth: int = 24,
    seed: int = 0,
) -> list[np.ndarray]:
    """Per level (1 = leaves), (P,) region label of each place."""
    position = np.asarray(position, dtype=np.float64)
    embedding = np.asarray(embedding, dtype=np.float32)
    P = len(position)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    w = paper_weight(position[edges[:, 0]], position[edges[:, 1]], embedding[edges[:, 0]], embedding[edges[:, 1]], gamma)
    if sigma is None:
        sigma = float(np.median(w)) if len(w) else 1.0
    sim = np.exp(-w / max(sigma, 1e-9))
    A = sp.coo_matrix((np.concatenate([sim, sim]), (np.concatenate([edges[:, 0], edges[:, 1]]), np.concatenate([edges[:, 1], edges[:, 0]]))), shape=(P, P)).tocsr()

    # Tree nodes: (members, depth, parent); children are appended in a fixed order.
    members: list[np.ndarray] = [np.arange(P)]
    depth = [0]
    parent = [-1]
    leaf = []
    queue = [0]
    while queue:
        node = queue.pop(0)
        idx = members[node]
        stop = (
            len(idx) < min_places
            or depth[node] >= max_depth
            or should_stop(position[idx], embedding[idx], max_semantic_diff, min_area, stop_rule)
        )
        if not stop:
            side = two_way_split(A[idx][:, idx], seed)
            if side.all() or not side.any():
                stop = True
        if stop:
            leaf.append(node)
            continue
        for part in (idx[side], idx[~side]):
            members.append(part)
            depth.append(depth[node] + 1)
            parent.append(node)
            queue.append(len(members) - 1)

    leaf_of_place = np.zeros(P, dtype=np.int64)
    for node in leaf:
        leaf_of_place[members[node]] = node
    d_max = max((depth[n] for n in leaf), default=0)
    depth_arr, parent_arr = np.asarray(depth), np.asarray(parent)
    out = [leaf_of_place]
    for k in range(2, levels + 1):
        cut = (d_max * (levels - k + 1)) // levels
        node = leaf_of_place.copy()
        for _ in range(d_max):
            up = depth_arr[node] > cut
            if not up.any():
                break
            node[up] = parent_arr[node[up]]
        out.append(node)
    return out
