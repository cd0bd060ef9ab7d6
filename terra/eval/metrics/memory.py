"""Memory of the saved map and graph against the mapped area (the paper's memory figure).

Bytes are the on-disk sizes of the bundle's components (`Bundle.component_bytes`). The mapped
area is the number of occupied `cell` x `cell` cells of the map points' x, y times the cell area,
as in the authors' evaluation (0.4 m cells).
"""

from __future__ import annotations

import numpy as np

from terra.bundle import Bundle


def mapped_area(points: np.ndarray, cell: float = 0.4) -> float:
    """Square metres covered by map points (N, >=2, metres): occupied xy cells times cell^2."""
    points = np.asarray(points)
    if len(points) == 0:
        return 0.0
    cells = np.floor(points[:, :2] / cell).astype(np.int64)
    return float(np.unique(cells, axis=0).shape[0] * cell * cell)


# What each file of a bundle holds, by path prefix (first match wins), for the memory breakdown.
PARTS = (
    ("map/points", "map: points"),
    ("map/terrain_votes", "map: terrain votes"),
    ("map/counts_", "map: observation counts"),
    ("map/ms_", "map: query caches"),
    ("map/bank", "map: embedding bank"),
    ("map/terrain_embeddings", "map: embedding bank"),
    ("map/images/", "map: images"),
    ("map/visibility/", "map: visibility"),
    ("graph/scene_graph", "graph: nodes and edges"),
    ("graph/place_embedding", "graph: place embeddings"),
    ("graph/", "graph: region and terrain embeddings"),
)


def part_of(file_name: str) -> str:
    """The part of the map a bundle file belongs to ("map: points", ...; "other" for metadata)."""
    return next((part for prefix, part in PARTS if file_name.startswith(prefix)), "other")


def memory_summary(bundle: Bundle, area_m2: float) -> dict:
    """Bytes per component and per part (PARTS), their total, and bytes per square metre of
    mapped area."""
    components = dict(sorted(bundle.component_bytes().items()))
    total = int(sum(components.values()))
    parts: dict[str, int] = {}
    for name, entry in bundle.files.items():
        parts[part_of(name)] = parts.get(part_of(name), 0) + entry.bytes
    parts["other"] = parts.get("other", 0) + max(total - sum(parts.values()), 0)  # the manifest itself
    return {
        "components_bytes": components,
        "parts_bytes": dict(sorted(parts.items(), key=lambda kv: (-kv[1], kv[0]))),
        "total_bytes": total,
        "area_m2": float(area_m2),
        "bytes_per_m2": total / area_m2 if area_m2 > 0 else 0.0,
    }
