"""What the task commands load from a bundle: its map, its scene graph and the query embedder.

One load serves every query of a command. The embedder is the one the bundle's manifest records
("embedder": {"name", "dim"}); a configured embedder with another name is refused.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from terra.bundle import Bundle
from terra.errors import TerraError
from terra.graph.scene_graph import SceneGraph
from terra.mapping.semantic_map import MetricSemanticMap
from terra.perception.text import TextEmbedder
from terra.tasks.config import TasksConfig
from terra.tasks.queries import check_configured_embedder, check_embedder, resolve_embedder


@dataclass
class TaskContext:
    """A loaded bundle for Phase 3: msm is None unless asked for, graph None when absent,
    embedder None when no text is to be embedded."""

    bundle: Bundle
    embedder: TextEmbedder | None
    msm: MetricSemanticMap | None
    graph: SceneGraph | None

    @property
    def path(self) -> Path:
        return self.bundle.path

    def require_graph(self, what: str) -> SceneGraph:
        if self.graph is None:
            raise TerraError(f"{self.path}: the bundle has no scene graph, which {what} needs; build one with `terra build {self.path}`")
        return self.graph


def has_component(bundle: Bundle, name: str) -> bool:
    """Whether the manifest lists component `name` (e.g. "map", "graph") with files present."""
    listed = name in bundle.manifest.get("components", {})
    return listed and any(f.startswith(f"{name}/") for f in bundle.files)


def open_for_tasks(path: str | Path, config: TasksConfig, need_map: bool = True, need_graph: bool = True,
                   embedder: TextEmbedder | None = None, need_embedder: bool = True) -> TaskContext:
    """Load a bundle for the task commands.

    need_map / need_graph: TerraError when that component is missing (a graph that is not needed
    is still loaded when present, to link objects to places). embedder: the query embedder,
    default resolved from the manifest (and config.embedder); not loaded (it takes seconds)
    without need_embedder, though a configured name that differs is still refused.
    """
    bundle = Bundle(path)
    recorded = bundle.manifest.get("embedder") or {}
    if not recorded.get("name"):
        raise TerraError(f"{bundle.path / 'manifest.json'}: field 'embedder' is missing; rebuild the bundle with `terra map`")
    if need_map and not has_component(bundle, "map"):
        raise TerraError(f"{bundle.path}: the bundle has no map; build one with `terra map`")
    with_graph = has_component(bundle, "graph")
    if need_graph and not with_graph:
        raise TerraError(f"{bundle.path}: the bundle has no scene graph; build one with `terra build {bundle.path}`")
    check_configured_embedder(recorded["name"], config.embedder, source=str(bundle.path))
    if embedder is None and need_embedder:
        embedder = resolve_embedder(recorded["name"], recorded.get("dim"), config.embedder, source=str(bundle.path))
    if embedder is not None:
        check_embedder(embedder, recorded["name"], recorded.get("dim"), source=str(bundle.path))
    msm = None
    if need_map:
        from terra.mapping.storage import load_map

        msm = load_map(bundle)
    graph = None
    if with_graph:
        from terra.graph.storage import load_scene_graph

        graph = load_scene_graph(bundle)
    return TaskContext(bundle=bundle, embedder=embedder, msm=msm, graph=graph)
