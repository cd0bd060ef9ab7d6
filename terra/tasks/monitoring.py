"""Region monitoring (paper, Phase 3, "Region Monitoring"): which places a task asks to watch.

Methods, for one query with unit embedding q:
- "mix" (the paper's): the top-k regions over all levels (from `min_level` up), then their places
  whose cosine with q exceeds alpha.
- "max": the top-k regions, all their places.
- "thresh": every region above alpha, then their places above alpha.
- "aib": Clio's information-bottleneck clustering of the places for this task
  (terra.tasks.aib); every member place of the clusters relevant to the query.

The query's vector is the embedding of its whole text (the paper's) or, with
`tasks.monitoring.query`, the mean over its parts (terra.tasks.queries.embed_query), for every
method alike.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from terra.errors import TerraError
from terra.graph.scene_graph import SceneGraph
from terra.perception.text import TextEmbedder, check_embedder, resolve_embedder
from terra.tasks.aib import aib_clusters, task_relevance
from terra.tasks.config import MONITOR_METHODS, MonitoringConfig, TasksConfig, alpha_for
from terra.tasks.hierarchy import (
    check_has_regions,
    place_similarities,
    places_of_regions,
    ranked_regions,
    region_similarities,
)
from terra.tasks.queries import clean_queries, embed_query

METHODS = MONITOR_METHODS


def places_in_polygon(xy: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Indices of the points (P, >=2) whose x, y (metres, map frame) lie inside or on the boundary
    of `polygon` (K, 2): the places of a named region (terra.eval.metrics.regions says why the
    boundary counts)."""
    import shapely  # only the evaluation and the figures ask; a monitor query does not

    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) == 0:
        return np.zeros(0, dtype=np.int64)
    inside = shapely.intersects_xy(shapely.Polygon(np.asarray(polygon, float)), xy[:, 0], xy[:, 1])
    return np.flatnonzero(inside)


@dataclass
class MonitorResult:
    """regions: chosen (level, index) pairs, best first (empty for "aib"); region_scores: their
    cosines. places: sorted indices of the chosen places; place_scores: their cosines.
    clusters: for "aib", the chosen clusters' member places. cluster_seconds: for "aib", the time
    its task-driven clustering took (the regions Terra builds once, AIB builds per query)."""

    query: str
    method: str
    regions: list[tuple[int, int]]
    region_scores: list[float]
    places: np.ndarray
    place_scores: np.ndarray
    clusters: list[np.ndarray] = field(default_factory=list)
    cluster_seconds: float = 0.0

    def to_json(self, graph: SceneGraph) -> dict[str, Any]:
        """JSON-ready dict with region and place positions (metres, map frame)."""
        regions = [
            {
                "level": level,
                "index": index,
                "score": round(float(score), 6),
                "position": [round(float(v), 4) for v in graph.regions[level - 1].position[index]],
                "place_count": int(len(places_of_regions(graph, [(level, index)]))),
            }
            for (level, index), score in zip(self.regions, self.region_scores)
        ]
        places = [
            {
                "place": int(p),
                "score": round(float(s), 6),
                "terrain": graph.terrain_classes[int(graph.places.terrain[p])],
                "position": [round(float(v), 4) for v in graph.places.position[p]],
            }
            for p, s in zip(self.places, self.place_scores)
        ]
        out: dict[str, Any] = {"query": self.query, "method": self.method, "regions": regions, "places": places}
        if self.method == "aib":
            out["clusters"] = [[int(p) for p in c] for c in self.clusters]
        return out


def _monitoring_config(config: TasksConfig | MonitoringConfig | None) -> MonitoringConfig:
    if config is None:
        return MonitoringConfig()
    return config.monitoring if isinstance(config, TasksConfig) else config


def monitor_region(
    graph: SceneGraph,
    query: str,
    method: str = "mix",
    k: int | None = None,
    alpha: float | None = None,
    embedder: TextEmbedder | None = None,
    config: TasksConfig | MonitoringConfig | None = None,
    min_level: int | None = None,
) -> MonitorResult:
    """The regions and places to monitor for `query` (see the module docstring).

    k, alpha, min_level: None takes the configured defaults (alpha per the graph's embedder). embedder:
    defaults to the graph's; one with another name or dimension is refused.
    """
    cfg = _monitoring_config(config)
    (query,) = clean_queries([query])
    if method not in METHODS:
        raise TerraError(f"unknown monitoring method {method!r}; expected one of: {', '.join(METHODS)}")
    k = cfg.k if k is None else int(k)
    if k < 1:
        raise TerraError(f"k must be >= 1, got {k}")
    if embedder is None:
        embedder = resolve_embedder(graph.embedder, int(graph.places.embedding.shape[1]), source="scene graph")
    check_embedder(embedder, graph.embedder, int(graph.places.embedding.shape[1]), source="scene graph")
    if alpha is None:
        alpha = alpha_for(cfg.alpha, cfg.default_alpha, embedder.name)
    q = embed_query(embedder, query, cfg.query)
    place_scores = place_similarities(graph, q)

    if method == "aib":
        null = alpha_for(cfg.aib.null_score, cfg.aib.default_null_score, embedder.name)
        start = time.perf_counter()
        pyx = task_relevance(graph.places.embedding, q[None], null, cfg.aib.top_k, cfg.aib.cumulative)
        labels, relevant = aib_clusters(pyx, graph.place_edges, cfg.aib.delta)
        seconds = time.perf_counter() - start
        places = np.flatnonzero(relevant == 1)
        roots = np.unique(labels[places])
        clusters = [np.flatnonzero(labels == r) for r in roots]
        return MonitorResult(query, method, [], [], places, place_scores[places], clusters, seconds)

    check_has_regions(graph, f"--method {method}")
    min_level = cfg.min_level if min_level is None else int(min_level)
    ranked = [
        r for r in ranked_regions(graph, region_similarities(graph, q)) if r[0] >= min(min_level, len(graph.regions))
    ]
    chosen = [r for r in ranked if r[2] > alpha] if method == "thresh" else ranked[:k]
    regions = [(level, index) for level, index, _ in chosen]
    places = places_of_regions(graph, regions)
    if method in ("mix", "thresh"):
        places = places[place_scores[places] > alpha]
    return MonitorResult(query, method, regions, [s for _, _, s in chosen], places, place_scores[places])
