"""A bundle's scene graph at a glance, for `terra info` (plain dict, JSON-ready)."""

from __future__ import annotations

from typing import Any

from terra.bundle import Bundle


def graph_summary(bundle: Bundle) -> dict[str, Any]:
    """Places, edges by kind, regions per level, objects, region method and embedding sources,
    from the manifest (no array is loaded)."""
    info = bundle.manifest.get("components", {}).get("graph")
    if info is None:
        return {}
    stats = info.get("stats", {})
    config = info.get("config", {})
    return {
        "format": info.get("format"),
        "places": info.get("places"),
        "places_per_terrain": stats.get("places_per_terrain", {}),
        "place_edges": info.get("place_edges"),
        "edges_by_kind": stats.get("edges", {}),
        "regions_per_level": info.get("regions", []),
        "region_method": config.get("regions", {}).get("method"),
        "objects": info.get("objects"),
        "embedding_source": stats.get("embedding_source", {}),
        "embedding_rule": stats.get("embedding_rule"),
    }
