"""Spectral regions: recursive two-way splits of the places graph, cut into levels.

Affinity on each place edge: exp(-w / sigma), w the paper's weight, so similar neighbours attract
(the reference fed the distance-like weight itself as the affinity). Each split is
scikit-learn's SpectralClustering(2, affinity="precomputed") with a fixed seed; a cluster whose
subgraph is disconnected is split into its largest component and the rest instead. The largest
cluster (most places; ties: created first) is split next, so the order of the splits is a
divisive hierarchy.

Stopping (the paper's rule, `stop_rule="either"`): a cluster stops splitting once its semantic
difference is below `max_semantic_diff` or its 2D bounding-box area is below `min_area` m^2. The
semantic difference is the cosine of the member most similar to the cluster's mean embedding minus
that of the least similar one. `stop_rule="both"` stops only when both hold (the reference code).
The thresholds are absolute (the paper's 0.45 and 10,000 m^2, chosen for CLIP on a large campus)
or, with `relative_thresholds`, fractions of the whole map's semantic difference and area: the
same places have a semantic difference of about 0.45 with CLIP and 0.18 with a text embedder, and
a 150 m map is a quarter of 10,000 m^2 four times over.

Levels: level 1 is the leaves. Level k >= 2 is the set of clusters after the first n_k - 1 splits,
n_k falling geometrically from the number of leaves to `top` (terra.graph.agglomerative's
`level_counts` rule), so every level coarsens the one below, counts strictly decrease upward
when the tree has leaves enough, and all places sit in exactly one region per level.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

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


def should_stop(
    position: np.ndarray, embedding: np.ndarray, max_semantic_diff: float, min_area: float, stop_rule: str
) -> bool:
    small_diff = semantic_difference(embedding) < max_semantic_diff
    small_area = bbox_area(position) < min_area
    return (small_diff and small_area) if stop_rule == "both" else (small_diff or small_area)


def two_way_split(affinity: sp.csr_matrix, seed: int) -> np.ndarray:
    """(n,) bool side of each node: a spectral bisection of a connected affinity graph, or the
    largest component versus the rest when it is disconnected."""
    n_comp, comp = connected_components(affinity, directed=False)
    if n_comp > 1:
        sizes = np.bincount(comp)
        largest = int(np.lexsort((np.arange(n_comp), -sizes))[0])
        return comp == largest
    from sklearn.cluster import (
        SpectralClustering,
    )  # here: scikit-learn costs ~0.4 s to import, and only spectral needs it

    model = SpectralClustering(n_clusters=2, affinity="precomputed", random_state=seed, assign_labels="cluster_qr")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # sklearn warns about graphs it considers not fully connected
        labels = model.fit_predict(affinity)
    return labels == labels[0]


@dataclass(frozen=True)
class SpectralStop:
    """When a cluster stops splitting: semantic difference below `semantic` or 2D bounding-box
    area (m^2) below `area` ("either"), or both ("both"); `relative`: the two are fractions of the
    whole map's semantic difference and area."""

    semantic: float = 0.45
    area: float = 10000.0
    rule: str = "either"
    relative: bool = False


def spectral_assignments(
    position: np.ndarray,
    embedding: np.ndarray,
    edges: np.ndarray,
    gamma: float = 100.0,
    levels: int = 4,
    stop: SpectralStop | None = None,
    sigma: float | None = None,
    min_places: int = 4,
    max_depth: int = 24,
    seed: int = 0,
    top: int = 3,
) -> list[np.ndarray]:
    """Per level (1 = leaves), (P,) region label of each place."""
    position = np.asarray(position, dtype=np.float64)
    embedding = np.asarray(embedding, dtype=np.float32)
    stop = stop or SpectralStop()
    P = len(position)
    if P == 0:
        return [np.zeros(0, np.int64) for _ in range(levels)]
    affinity = edge_affinity(position, embedding, edges, gamma, sigma)
    semantic, area = stop.semantic, stop.area
    if stop.relative:
        semantic, area = stop.semantic * semantic_difference(embedding), stop.area * bbox_area(position)
    members, parent = split_tree(position, embedding, affinity, semantic, area, stop.rule, min_places, max_depth, seed)
    return split_levels(members, parent, P, levels, top)


def edge_affinity(
    position: np.ndarray, embedding: np.ndarray, edges: np.ndarray, gamma: float, sigma: float | None
) -> sp.csr_matrix:
    """Symmetric (P, P) affinity exp(-w / sigma) on the place edges (sigma None: median w)."""
    P = len(position)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    w = paper_weight(
        position[edges[:, 0]], position[edges[:, 1]], embedding[edges[:, 0]], embedding[edges[:, 1]], gamma
    )
    if sigma is None:
        sigma = float(np.median(w)) if len(w) else 1.0
    sim = np.exp(-w / max(sigma, 1e-9))
    rows, cols = np.concatenate([edges[:, 0], edges[:, 1]]), np.concatenate([edges[:, 1], edges[:, 0]])
    affinity = sp.coo_matrix((np.concatenate([sim, sim]), (rows, cols)), shape=(P, P)).tocsr()
    return affinity  # pyright: ignore[reportReturnType]  # scipy infers csr_array for coo_matrix.tocsr()


def split_tree(
    position: np.ndarray,
    embedding: np.ndarray,
    affinity: sp.csr_matrix,
    max_semantic_diff: float,
    min_area: float,
    stop_rule: str,
    min_places: int,
    max_depth: int,
    seed: int,
) -> tuple[list[np.ndarray], list[int]]:
    """The divisive tree: node members (node 0 = all places) and parents, nodes numbered in the
    order they were created; the largest unstopped cluster is split first."""
    import heapq

    members: list[np.ndarray] = [np.arange(len(position))]
    parent, depth = [-1], [0]
    heap = [(-len(position), 0)]
    while heap:
        _, node = heapq.heappop(heap)
        idx = members[node]
        if (
            len(idx) < min_places
            or depth[node] >= max_depth
            or should_stop(position[idx], embedding[idx], max_semantic_diff, min_area, stop_rule)
        ):
            continue
        side = two_way_split(affinity[idx][:, idx], seed)
        if side.all() or not side.any():
            continue
        for part in (idx[side], idx[~side]):
            members.append(part)
            parent.append(node)
            depth.append(depth[node] + 1)
            heapq.heappush(heap, (-len(part), len(members) - 1))
    return members, parent


def split_levels(members: list[np.ndarray], parent: list[int], P: int, levels: int, top: int) -> list[np.ndarray]:
    """Per level, (P,) cluster of each place: level 1 the leaves, level k the clusters after the
    first n_k - 1 splits (children are created in split order, two per split)."""
    from terra.graph.agglomerative import level_counts

    n_splits = (len(members) - 1) // 2
    counts = level_counts(n_splits + 1, levels, 1.0, top)  # leaves = splits + 1
    out = []
    for count in counts:
        # After s splits, the clusters are the nodes created so far that were not split within them.
        s = count - 1
        alive = 1 + 2 * s
        split_parents = {parent[c] for c in range(1, alive)}
        label = np.zeros(P, dtype=np.int64)
        for node in range(alive):
            if node not in split_parents:
                label[members[node]] = node
        out.append(label)
    return out
