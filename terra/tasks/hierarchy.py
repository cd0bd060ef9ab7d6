"""Query similarity over the region hierarchy and the places below it.

Regions are addressed as (level, index) pairs, level 1 being the regions that group places
directly (SceneGraph.regions[level - 1]).
"""

from __future__ import annotations

import numpy as np

from terra.errors import TerraError
from terra.graph.scene_graph import SceneGraph


def region_similarities(graph: SceneGraph, query: np.ndarray) -> list[np.ndarray]:
    """Per region level (1..L), the (R_l,) cosine of each region's embedding with a unit query (D,)."""
    q = np.asarray(query, dtype=np.float32)
    return [np.asarray(level.embedding, dtype=np.float32) @ q for level in graph.regions]


def place_similarities(graph: SceneGraph, query: np.ndarray) -> np.ndarray:
    """(P,) cosine of each place's embedding with a unit query (D,)."""
    return np.asarray(graph.places.embedding, dtype=np.float32) @ np.asarray(query, dtype=np.float32)


def ranked_regions(graph: SceneGraph, scores: list[np.ndarray]) -> list[tuple[int, int, float]]:
    """All regions as (level, index, score), best first; ties broken by level then index."""
    if not scores or sum(len(s) for s in scores) == 0:
        return []
    level = np.concatenate([np.full(len(s), lv + 1) for lv, s in enumerate(scores)])
    index = np.concatenate([np.arange(len(s)) for s in scores])
    score = np.concatenate(scores)
    order = np.lexsort((index, level, -score))
    return [(int(level[i]), int(index[i]), float(score[i])) for i in order]


def places_of_regions(graph: SceneGraph, regions: list[tuple[int, int]]) -> np.ndarray:
    """Sorted indices of the places that descend from any of the (level, index) regions."""
    chosen = np.zeros(len(graph.places), dtype=bool)
    by_level: dict[int, list[int]] = {}
    for level, index in regions:
        by_level.setdefault(level, []).append(index)
    for level, indices in by_level.items():
        chosen |= np.isin(graph.place_region(level), indices)
    return np.flatnonzero(chosen)


def check_has_regions(graph: SceneGraph, what: str) -> None:
    """TerraError when the graph has no region layer (`what` names the task that needs it)."""
    if not graph.regions or all(len(level) == 0 for level in graph.regions):
        raise TerraError(f"the scene graph has no regions, which {what} needs; rebuild it with `terra build`")
