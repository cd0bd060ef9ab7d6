"""Clio's agglomerative information bottleneck (AIB) on the places layer: the region-monitoring
baseline the paper compares against (Maggio et al., "Clio", 2024; batch variant).

Task relevance p(y|x) of each place x over y in [null, task_1..task_m]:
- scores: the null task gets `null_score`; task t gets max(cos(place, task_t), 0).
- The top-k scores of each place are added to a 1e-12 floor; with `cumulative`, the rank-r score
  (r = 0 is the best) is added k - r times. A place whose best score is the null task becomes
  one-hot on null. Columns are then normalised. p(x) and p(y) are uniform, as in Clio.
Greedy merging: among adjacent clusters, merge the pair that loses the least information,
(p_i + p_j) JS_pi(p(y|i), p(y|j)); stop before a merge whose loss exceeds `delta` I(X;Y).

Unlike the reference's port, the result lists every member place of each cluster (not one
representative), and the scene graph is never written to: all state lives in local arrays.
"""

from __future__ import annotations

import heapq

import numpy as np

FLOOR = 1e-12


def task_relevance(
    place_embeddings: np.ndarray,
    task_embeddings: np.ndarray,
    null_score: float,
    top_k: int = 2,
    cumulative: bool = True,
) -> np.ndarray:
    """(m + 1, n) p(y|x): row 0 the null task, rows 1..m the tasks; columns sum to 1."""
    cos = np.asarray(task_embeddings, dtype=np.float64) @ np.asarray(place_embeddings, dtype=np.float64).T
    scores = np.vstack([np.full((1, cos.shape[1]), float(null_score)), np.clip(cos, 0.0, None)])
    m1, n = scores.shape
    k = min(m1, int(top_k))
    rank = np.empty_like(scores, dtype=np.int64)
    order = np.argsort(-scores, axis=0, kind="stable")  # ties: the null task (row 0) first
    rank[order, np.arange(n)[None, :]] = np.arange(m1)[:, None]
    times = np.where(rank < k, (k - rank) if cumulative else 1, 0)
    pyx = FLOOR + times * scores
    null_top = order[0] == 0
    pyx[:, null_top] = FLOOR
    pyx[0, null_top] = 1.0
    return pyx / pyx.sum(axis=0, keepdims=True)


def _plogp(p: np.ndarray) -> np.ndarray:
    return p * np.log2(p)


def _merge_loss(pc_i: np.ndarray, pc_j: np.ndarray, py_i: np.ndarray, py_j: np.ndarray) -> np.ndarray:
    """Information lost by merging clusters i and j: (p_i + p_j) JS divergence with weights
    p_i / (p_i + p_j), p_j / (p_i + p_j). pc_*: (E,), py_*: (Y, E)."""
    total = pc_i + pc_j
    wi, wj = pc_i / total, pc_j / total
    mixed = wi * py_i + wj * py_j
    js = -_plogp(mixed).sum(axis=0) + wi * _plogp(py_i).sum(axis=0) + wj * _plogp(py_j).sum(axis=0)
    return total * np.maximum(js, 0.0)


def mutual_information(px: np.ndarray, pyx: np.ndarray, py: np.ndarray) -> float:
    """sum_x p(x) sum_y p(y|x) log2(p(y|x) / p(y)) in bits."""
    return float(np.sum(px[None, :] * pyx * np.log2(pyx / py[:, None])))


def aib_clusters(pyx: np.ndarray, edges: np.ndarray, delta: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """Greedy AIB over a graph. pyx: (Y, n) p(y|x) with row 0 the null task; edges: (E, 2) node
    pairs. Returns (labels (n,) cluster id = smallest member index, relevant (n,) the argmax row of
    each node's cluster p(y|c), 0 = null)."""
    pyx = np.asarray(pyx, dtype=np.float64)
    n_y, n = pyx.shape
    pc = np.full(n, 1.0 / n)
    pyc = pyx.copy()
    info = mutual_information(pc, pyx, np.full(n_y, 1.0 / n_y))
    neighbours: list[set[int]] = [set() for _ in range(n)]
    for a, b in np.asarray(edges, dtype=np.int64).reshape(-1, 2).tolist():
        if a != b:
            neighbours[a].add(b)
            neighbours[b].add(a)
    version = np.zeros(n, dtype=np.int64)
    alive = np.ones(n, dtype=bool)
    parent = np.arange(n)

    def push_edges(i: int, others: list[int]) -> None:
        if not others:
            return
        j = np.asarray(others, dtype=np.int64)
        loss = _merge_loss(np.full(len(j), pc[i]), pc[j], np.repeat(pyc[:, [i]], len(j), axis=1), pyc[:, j])
        for jj, w in zip(j.tolist(), loss.tolist()):
            a, b = min(i, jj), max(i, jj)
            heapq.heappush(heap, (w, a, b, int(version[a]), int(version[b])))

    heap: list[tuple[float, int, int, int, int]] = []
    for i in range(n):
        push_edges(i, sorted(j for j in neighbours[i] if j > i))
    while heap:
        w, a, b, va, vb = heapq.heappop(heap)
        if not (alive[a] and alive[b]) or version[a] != va or version[b] != vb:
            continue  # stale: one side changed since this loss was computed
        if w / info > delta:
            break
        # Merge b into a (a < b keeps the smallest member index as the cluster id).
        total = pc[a] + pc[b]
        pyc[:, a] = (pc[a] * pyc[:, a] + pc[b] * pyc[:, b]) / total
        pc[a], pc[b] = total, 0.0
        alive[b] = False
        parent[b] = a
        for c in neighbours[b]:
            neighbours[c].discard(b)
            if c != a:
                neighbours[c].add(a)
                neighbours[a].add(c)
        neighbours[a].discard(b)
        neighbours[b] = set()
        version[a] += 1
        push_edges(a, sorted(neighbours[a]))
    labels = parent.copy()
    while True:  # path compression to the surviving root
        nxt = parent[labels]
        if np.array_equal(nxt, labels):
            break
        labels = nxt
    return labels, np.argmax(pyc[:, labels], axis=0)
