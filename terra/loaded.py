"""One opened bundle shared by everything that answers questions about it: the query commands,
evaluation, the demo, `terra serve` and the web viewer take a LoadedBundle instead of a path, so a
long-lived process loads the map, the scene graph and the text model once.

Everything is loaded on first use (a plan between two place ids never loads the map or the text
model) and then kept, with the per-map query state: the point scorer (float32 counts, MS-Avg
norms, MS-Max ids) and cost graphs per set of terrain preferences. Reads are safe from many
threads: lazy loads are guarded by a lock, and the loaded data is never changed in place. Writes
(`update_graph`, used by `find --save`) are serialised by `write_lock` and atomic: the new bundle
version is written beside the old and swapped in by rename, then the new graph replaces the old
one in memory, so a concurrent query sees either the old graph or the new one.
"""

from __future__ import annotations

import contextlib
import threading
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from terra.bundle import Bundle
from terra.errors import TerraError

if TYPE_CHECKING:
    from terra.graph.scene_graph import SceneGraph
    from terra.mapping.semantic_map import MetricSemanticMap
    from terra.perception.text import TextEmbedder
    from terra.tasks.planning import CostGraph, TerrainCosts
    from terra.tasks.scoring import PointScorer

COST_GRAPHS = 16  # cost graphs kept per bundle (one per set of terrain preferences)


class LoadedBundle:
    """A bundle opened for queries. `embedder_name`: a configured text embedder (e.g.
    tasks.embedder), refused when it is not the map's; `embedder`: an already loaded one to use
    (checked against the map's name and dimension)."""

    def __init__(self, path: str | Path, embedder_name: str | None = None, embedder: TextEmbedder | None = None):
        from terra.tasks.queries import check_configured_embedder, check_embedder

        self.bundle = Bundle(path)
        recorded = self.bundle.model.embedder
        if recorded is None:
            raise TerraError(
                f"{self.bundle.path / 'manifest.json'}: field 'embedder' is missing; "
                "rebuild the bundle with `terra map`"
            )
        self.embedder_name: str = recorded.name
        self.embedder_dim: int | None = recorded.dim
        check_configured_embedder(self.embedder_name, embedder_name, source=str(self.path))
        if embedder is not None:
            check_embedder(embedder, self.embedder_name, self.embedder_dim, source=str(self.path))
        self._embedder = embedder
        self._msm: MetricSemanticMap | None = None
        self._graph: SceneGraph | None = None
        self._graph_loaded = False
        self._scorer: PointScorer | None = None
        self._cost_graphs: OrderedDict[tuple, CostGraph] = OrderedDict()
        self._searched: set[tuple] = set()  # cost graphs fetched more than once (see cost_graph)
        self._lock = threading.RLock()  # the cost-graph cache and graph swaps
        self._load_locks = {name: threading.Lock() for name in ("_msm", "_graph", "_embedder", "_scorer")}
        self.write_lock = threading.Lock()  # one writer at a time (update_graph)

    @property
    def path(self) -> Path:
        return self.bundle.path

    @property
    def has_map(self) -> bool:
        return self.bundle.has_component("map")

    @property
    def has_graph(self) -> bool:
        return self.bundle.has_component("graph")

    def _load_once(self, attribute: str, load: Callable[[], Any]) -> Any:
        value = getattr(self, attribute)
        if value is None:
            with self._load_locks[attribute]:  # one lock per part: parts load in parallel
                value = getattr(self, attribute)
                if value is None:
                    value = load()
                    setattr(self, attribute, value)
        return value

    @property
    def msm(self) -> MetricSemanticMap:
        """The metric-semantic map (TerraError when the bundle has none)."""
        return self.require_map()

    def require_map(self, what: str = "this query") -> MetricSemanticMap:
        if not self.has_map:
            raise TerraError(f"{self.path}: the bundle has no map, which {what} needs; build one with `terra map`")
        from terra.mapping.storage import load_map

        return self._load_once("_msm", lambda: load_map(self.bundle))

    @property
    def graph(self) -> SceneGraph | None:
        """The scene graph, None when the bundle has none."""
        if not self._graph_loaded:
            with self._load_locks["_graph"]:
                if not self._graph_loaded:
                    if self.has_graph:
                        from terra.graph.storage import load_scene_graph

                        self._graph = load_scene_graph(self.bundle)
                    self._graph_loaded = True
        return self._graph

    def require_graph(self, what: str) -> SceneGraph:
        """The scene graph; TerraError naming `what` needs it when the bundle has none."""
        graph = self.graph
        if graph is None:
            raise TerraError(
                f"{self.path}: the bundle has no scene graph, which {what} needs; "
                f"build one with `terra build {self.path}`"
            )
        return graph

    @property
    def embedder(self) -> TextEmbedder:
        """The map's text embedder, loaded on first use (warm afterwards, with its text cache)."""
        from terra.tasks.queries import resolve_embedder

        return self._load_once(
            "_embedder", lambda: resolve_embedder(self.embedder_name, self.embedder_dim, source=str(self.path))
        )

    @property
    def scorer(self) -> PointScorer:
        """Per-point cosine scoring of the map, built once."""
        from terra.tasks.scoring import PointScorer

        return self._load_once("_scorer", lambda: PointScorer(self.msm))

    def cost_graph(self, costs: TerrainCosts) -> CostGraph:
        """The places graph under `costs`, built once per set of preferences (and graph version)."""
        from terra.tasks.planning import CostGraph

        graph = self.require_graph("planning")
        key = (id(graph), costs.penalty.tobytes(), costs.forbidden.tobytes())
        with self._lock:
            cached = self._cost_graphs.get(key)
            if cached is not None:
                self._cost_graphs.move_to_end(key)
                reused = key in self._searched
                self._searched.add(key)
        if cached is not None:
            if not reused:  # asked for twice: worth A*'s adjacency lists from now on
                from terra.tasks.astar import prepare_adjacency

                prepare_adjacency(cached.indptr, cached.indices, cached.cost)
            return cached
        built = CostGraph.build(graph, costs)
        with self._lock:
            self._cost_graphs[key] = built
            while len(self._cost_graphs) > COST_GRAPHS:
                self._searched.discard(self._cost_graphs.popitem(last=False)[0])
        return built

    def prefetch(self, texts: list[str]) -> None:
        """Start embedding `texts` in a background thread, so a cold query overlaps the text
        runtime's start (onnxruntime releases the GIL) with its imports and the map load; the
        vectors then come from the embedder's cache. A failure there is simply met again, and
        raised, where the query embeds them."""
        texts = [str(t).strip() for t in texts if str(t).strip()]
        if texts:
            threading.Thread(
                target=_quietly, args=(lambda: self.embedder.embed_text(texts),), name="terra-embed", daemon=True
            ).start()

    def warm(self) -> None:
        """Load everything a query may need now (a service does this before it listens)."""
        if self.has_map:
            self.scorer.max_ids  # noqa: B018 (loads the map and its per-point data)
        self.graph  # noqa: B018
        load = getattr(self.embedder, "load", None)
        if load is not None:
            load()  # the text runtime's session, which a stored vector would otherwise skip
        self.embedder.embed_text(["warm up"])

    def update_graph(self, change: Callable[[SceneGraph], SceneGraph]) -> SceneGraph:
        """Apply `change` to the current scene graph and store the result in the bundle, atomically
        and one writer at a time; returns the new graph, which later queries see."""
        from terra.bundle import BundleWriter
        from terra.graph.storage import write_scene_graph

        with self.write_lock:
            graph = change(self.require_graph("saving objects"))
            with BundleWriter(self.path, base=self.bundle) as writer:
                write_scene_graph(writer, graph)
            with self._lock:
                self.bundle = Bundle(self.path)
                self._graph = graph
                self._cost_graphs.clear()
                self._searched.clear()
        return graph


def _quietly(load: Callable[[], Any]) -> None:
    with contextlib.suppress(Exception):  # re-raised by the caller's own access
        load()
