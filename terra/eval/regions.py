"""Table III: region monitoring of the simulator's named regions, one query per region (its
one-sentence description), scored over place sets (terra.eval.metrics.regions).

Terra's methods query a region hierarchy (spectral or agglomerative, built on the bundle's
places); AIB clusters the places layer per query. Timing is like the paper's, on the same places:
`regions_ms` is the time to build the regions (Terra's hierarchy once; AIB's task-driven
clustering, which it redoes for every query, as its mean over the queries), `query_ms` the mean
time to answer one query on them, and `runtime_ms` their sum.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from terra.datasets.ground_truth import NamedRegion
from terra.eval.metrics.regions import SetScores, micro_scores, places_in_polygon, set_scores
from terra.graph.scene_graph import SceneGraph
from terra.perception.text import TextEmbedder


def region_truth(graph: SceneGraph, regions: list[NamedRegion]) -> list[np.ndarray]:
    """Per named region, the places whose xy lies inside its polygon."""
    return [places_in_polygon(graph.places.position, r.polygon) for r in regions]


@dataclass
class MonitoringRun:
    """One method over every region query: predicted places, scores and timing (`seconds`: all
    queries; `cluster_seconds`: the part of it AIB spent clustering; `build_seconds`: building a
    hierarchy once)."""

    predicted: list[np.ndarray]
    scores: list[SetScores]
    seconds: float
    build_seconds: float | None = None
    parameters: dict = field(default_factory=dict)
    cluster_seconds: float = 0.0
    regions: list[NamedRegion] = field(default_factory=list)  # the regions queried, in the order of `predicted`

    def timing_ms(self) -> dict[str, float]:
        """regions_ms, query_ms and runtime_ms (see the module docstring)."""
        n = max(len(self.scores), 1)
        regions = 1000.0 * (self.build_seconds if self.build_seconds is not None else self.cluster_seconds / n)
        query = 1000.0 * (self.seconds - self.cluster_seconds) / n
        return {"regions_ms": regions, "query_ms": query, "runtime_ms": regions + query}

    @property
    def total(self) -> SetScores:
        return micro_scores(self.scores)

    def to_json(self, label: str) -> dict:
        total = self.total
        return {
            "label": label,
            **total.to_json(),
            **self.timing_ms(),
            "parameters": ", ".join(
                f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in self.parameters.items()
            ),
            "per_query": [s.to_json() for s in self.scores],
        }


@dataclass(frozen=True)
class MonitorParams:
    """Parameters of one monitoring method. alpha: place cosine threshold ("mix"/"thresh"), or the
    null-task score for "aib"; k: regions kept; levels: only region levels 1..levels are ranked
    (None = all), so the coarse top levels, which often span the whole map, can be left out;
    min_level: nor those below it (None = from level 1), so can the smallest regions."""

    alpha: float | None = None
    k: int | None = None
    levels: int | None = None
    min_level: int | None = None

    def to_json(self) -> dict:
        items = (("alpha", self.alpha), ("k", self.k), ("levels", self.levels), ("min_level", self.min_level))
        return {k: v for k, v in items if v is not None}


def up_to_level(graph: SceneGraph, levels: int | None) -> SceneGraph:
    """`graph` with only its region levels 1..levels (all when None)."""
    from dataclasses import replace

    if levels is None or levels >= len(graph.regions):
        return graph
    return replace(graph, regions=graph.regions[:levels])


def aib_config(tasks_config, embedder: str, null_score: float):
    """The tasks configuration with AIB's null-task score set to `null_score` for `embedder`
    (monitor_region reads AIB's threshold from the configuration, not from alpha)."""
    from terra.tasks.config import TasksConfig

    cfg = tasks_config or TasksConfig()
    aib = cfg.monitoring.aib.model_copy(
        update={"null_score": {**cfg.monitoring.aib.null_score, embedder: float(null_score)}}
    )
    return cfg.model_copy(update={"monitoring": cfg.monitoring.model_copy(update={"aib": aib})})


def run_monitoring(
    graph: SceneGraph,
    regions: list[NamedRegion],
    truth: list[np.ndarray],
    method: str,
    params: MonitorParams,
    embedder: TextEmbedder,
    tasks_config=None,
) -> MonitoringRun:
    """Monitor every region's description with `method` ("mix", "max", "thresh" or "aib")."""
    from terra.tasks.monitoring import monitor_region

    if method == "aib":
        if params.alpha is not None:
            tasks_config = aib_config(tasks_config, embedder.name, params.alpha)
        params = MonitorParams(params.alpha)
    else:
        graph = up_to_level(graph, params.levels)
    predicted = []
    cluster_seconds = 0.0
    start = time.perf_counter()
    for region in regions:
        result = monitor_region(
            graph,
            region.description,
            method=method,
            k=params.k,
            alpha=params.alpha,
            embedder=embedder,
            config=tasks_config,
            min_level=params.min_level,
        )
        predicted.append(np.asarray(result.places, dtype=np.int64))
        cluster_seconds += result.cluster_seconds
    seconds = time.perf_counter() - start
    scores = [set_scores(p, t) for p, t in zip(predicted, truth)]
    return MonitoringRun(
        predicted, scores, seconds, parameters=params.to_json(), cluster_seconds=cluster_seconds, regions=list(regions)
    )


def rebuild_regions(bundle, graph: SceneGraph, method: str) -> tuple[SceneGraph, float]:
    """`graph` with its region levels rebuilt by `method` ("spectral" or "agglomerative") on the
    same places, using the bundle's recorded build configuration otherwise; returns the graph and
    the seconds the region construction took."""
    from dataclasses import replace

    from terra.graph.config import BuildConfig
    from terra.graph.pipeline import region_assignments
    from terra.graph.regions import build_levels

    recorded = bundle.component_config("graph")
    config = BuildConfig.model_validate(recorded)
    config = config.model_copy(update={"regions": config.regions.model_copy(update={"method": method})})
    places = graph.places
    start = time.perf_counter()
    assignments = region_assignments(places.position, places.embedding, places.terrain, graph.place_edges, config)
    levels = build_levels(assignments, places.position, places.embedding)
    seconds = time.perf_counter() - start
    return replace(graph, regions=levels, region_method=method), seconds


def best_region_scores(graph: SceneGraph, truth: list[np.ndarray]) -> list[SetScores]:
    """Per query, the scores of the single region (any level) whose places match its true places
    best (highest F1; ties: lowest level, then lowest index; none when no region overlaps them):
    what monitoring that picks one region per query would reach with a perfect ranking. A ceiling
    of the hierarchy's regions, not a method: it reads the labels."""
    P = len(graph.places)
    out = []
    for places in truth:
        places = np.unique(np.asarray(places, dtype=np.int64))
        best, best_f1 = SetScores(0, 0, int(places.size)), 0.0  # no region overlapping: none
        for level in range(1, len(graph.regions) + 1):
            label = graph.place_region(level)
            n = len(graph.regions[level - 1])
            size = np.bincount(label, minlength=n)
            tp = np.bincount(label[places], minlength=n) if P else np.zeros(n, np.int64)
            f1 = np.divide(2.0 * tp, size + places.size, out=np.zeros(n), where=(size + places.size) > 0)
            i = int(np.argmax(f1)) if n else 0
            if n and f1[i] > best_f1 + 1e-12:
                best, best_f1 = SetScores(int(tp[i]), int(size[i] - tp[i]), int(places.size - tp[i])), float(f1[i])
        out.append(best)
    return out
