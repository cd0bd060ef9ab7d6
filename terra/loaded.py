"""One opened bundle shared by everything that answers questions about it: the query commands,
evaluation, the demo, `terra serve` and the web viewer take a LoadedBundle instead of a path, so a
long-lived process loads the map, the scene graph and the text model once.

Everything is loaded on first use (a plan between two place ids never loads the map or the text
model) and then kept, with what the stages above derive from it (`derived`: the tasks' point
scorer and cost graphs per set of terrain preferences, which terra.tasks builds and keeps here, so
this module needs nothing of terra.tasks). Reads are safe from many threads: lazy loads are guarded
by a lock, and the loaded data is never changed in place. Writes
(`update_graph`, used by `find --save`) are serialised by `write_lock` and atomic: the new bundle
version is written beside the old and swapped in by rename, then the new graph replaces the old
one in memory, so a concurrent query sees either the old graph or the new one.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from terra.bundle import Bundle
from terra.errors import TerraError

if TYPE_CHECKING:
    from terra.graph.scene_graph import SceneGraph
    from terra.mapping.semantic_map import MetricSemanticMap
    from terra.perception.text import TextEmbedder

T = TypeVar("T")


class LoadedBundle:
    """A bundle opened for queries. `embedder_name`: a configured text embedder (e.g.
    tasks.embedder), refused when it is not the map's; `embedder`: an already loaded one to use
    (checked against the map's name and dimension)."""

    def __init__(
        self, path: str | Path | Bundle, embedder_name: str | None = None, embedder: TextEmbedder | None = None
    ):
        from terra.perception.text import check_configured_embedder, check_embedder

        self.bundle = path if isinstance(path, Bundle) else Bundle(path)  # a version just opened is not read again
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
        self._derived: dict[str, Any] = {}  # see `derived`
        self._of_graph: set[str] = set()  # the derived values dropped when the graph changes
        self._lock = threading.RLock()  # the derived values and graph swaps
        self._load_locks = {name: threading.Lock() for name in ("_msm", "_graph", "_embedder")}
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
        from terra.perception.text import resolve_embedder

        return self._load_once(
            "_embedder", lambda: resolve_embedder(self.embedder_name, self.embedder_dim, source=str(self.path))
        )

    def derived(self, key: str, build: Callable[[], T], of_graph: bool = False) -> T:
        """The value `key` derived from this bundle by a stage above (e.g. the tasks' point scorer),
        built by `build` on first use and kept; `of_graph`: derived from the scene graph, so dropped
        when `update_graph` replaces it. Values are built outside the lock (a slow build does not
        stall other queries): two threads may both build one, and the first stored is kept."""
        with self._lock:
            if key in self._derived:
                return self._derived[key]
        value = build()
        with self._lock:
            if of_graph:
                self._of_graph.add(key)
            return self._derived.setdefault(key, value)

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
        """Load the map, the scene graph and the text model now (terra.tasks.commands.warm also
        builds the query state a service needs before it listens)."""
        if self.has_map:
            self.require_map()
        _ = self.graph
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
                for key in self._of_graph:
                    self._derived.pop(key, None)
                self._of_graph.clear()
        return graph


def _quietly(load: Callable[[], Any]) -> None:
    with contextlib.suppress(Exception):  # re-raised by the caller's own access
        load()
