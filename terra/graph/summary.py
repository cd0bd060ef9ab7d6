"""A bundle's scene graph at a glance, for `terra info` (plain dict, JSON-ready)."""

from __future__ import annotations

from typing import Any

from terra.bundle import Bundle


def graph_summary(bundle: Bundle) -> dict[str, Any]:
    """Places, edges by kind, regions per level, objects, region method and embedding sources,
    from the manifest (no array is loaded; its types were checked when the bundle was opened)."""
    info = bundle.model.components.graph
    if info is None:
        return {}
    stats = info.stats
    method = info.config.get("regions", {}).get("method") if isinstance(info.config.get("regions"), dict) else None
    return {
        "format": info.format,
        "places": info.places,
        "places_per_terrain": dict(stats.places_per_terrain),
        "place_edges": info.place_edges,
        "edges_by_kind": dict(stats.edges),
        "regions_per_level": list(info.regions or []),
        "region_method": method if isinstance(method, str) else None,
        "objects": info.objects,
        "embedding_source": dict(stats.embedding_source),
        "embedding_rule": stats.embedding_rule,
        "map_version": info.map_version,
        "stale": _stale(bundle),
    }


def _stale(bundle: Bundle) -> bool:
    """Whether the map changed (e.g. `terra map --append`) after the graph was built on it."""
    graph, fused = bundle.model.components.graph, bundle.model.components.map
    if graph is None or fused is None or fused.version is None:
        return False
    return (graph.map_version or 0) < fused.version
