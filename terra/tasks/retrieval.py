"""Open-vocabulary object retrieval: Terra-MS and Terra-3DSG (paper, Phase 3, "Object Retrieval").

A map point matches a query when, among the terrain class names (distractors) and all queries of
the call, its best cosine is that query's and exceeds alpha. Matched points are clustered with
DBSCAN per query into objects; with a scene graph, clusters lying flat on the ground are dropped
and floating parts join the object below them (terra.tasks.standing). Each object gets a
gravity-aligned oriented box, a score per query (the mean cosine of its points) and the nearest
place node (in 2-D).

- "ms-avg" / "ms-max": every observed map point, with its MS-Avg / MS-Max feature.
- "3dsg": regions first. The best-scoring region fixes a level; the regions of that level above
  alpha (all of them when none is) give their places; the places above alpha (all of those
  places when none is) give the points within `place_radius` metres (2-D) that are searched.
  A query that finds no object there is searched again over the places above alpha of the whole
  level, then near every place (`sg_widen`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from terra.dbscan import dbscan_labels
from terra.errors import TerraError
from terra.graph.scene_graph import Objects, SceneGraph
from terra.mapping.semantic_map import MetricSemanticMap
from terra.neighbours import nearest
from terra.perception.text import TextEmbedder, check_embedder, resolve_embedder
from terra.tasks.boxes import fit_object_boxes
from terra.tasks.config import RETRIEVAL_METHODS, RetrievalConfig, TasksConfig, alpha_for
from terra.tasks.hierarchy import (
    check_has_regions,
    place_similarities,
    places_of_regions,
    ranked_regions,
    region_similarities,
)
from terra.tasks.instances import split_instances
from terra.tasks.object_context import ground_under, strip_directions
from terra.tasks.queries import clean_queries, embed_queries
from terra.tasks.scoring import Feature, PointScorer
from terra.tasks.standing import standing_groups

METHODS = RETRIEVAL_METHODS


@dataclass
class FoundObject:
    """One retrieved object. center, size: (3,) metres, map frame (size along the box axes);
    yaw: radians about +z. query: index into the call's queries, label: that query's text.
    scores: (Q,) mean cosine of the object's points with every query; score = scores[query].
    place: nearest place index (2-D), -1 without a scene graph. point_indices: map point rows."""

    center: np.ndarray
    size: np.ndarray
    yaw: float
    query: int
    label: str
    score: float
    scores: np.ndarray
    point_count: int
    place: int
    point_indices: np.ndarray = field(repr=False)

    def to_json(self) -> dict[str, Any]:
        return {
            "query": self.query,
            "label": self.label,
            "score": round(float(self.score), 6),
            "scores": [round(float(s), 6) for s in self.scores],
            "center": [round(float(v), 4) for v in self.center],
            "size": [round(float(v), 4) for v in self.size],
            "yaw": round(float(self.yaw), 6),
            "point_count": int(self.point_count),
            "place": int(self.place),
        }


def _retrieval_config(config: TasksConfig | RetrievalConfig | None) -> RetrievalConfig:
    if config is None:
        return RetrievalConfig()
    return config.retrieval if isinstance(config, TasksConfig) else config


def point_matches(similarity: np.ndarray, n_terrain: int, alpha: float) -> np.ndarray:
    """(n,) index of the query each row matches, -1 for none.

    similarity: (n, T + Q) cosines with [terrain names..., queries...]. A row matches query q when
    column T + q is its maximum (first maximum on ties, so terrain wins a tie) and exceeds alpha.
    """
    n = similarity.shape[0]
    if n == 0 or similarity.shape[1] == n_terrain:
        return np.full(n, -1, dtype=np.int64)
    best = similarity.argmax(axis=1)
    best_score = similarity[np.arange(n), best]
    query = best.astype(np.int64) - n_terrain
    return np.where((query >= 0) & (best_score > alpha), query, -1)


def points_near(points_xy: np.ndarray, centres_xy: np.ndarray, radius: float) -> np.ndarray:
    """Sorted indices of the points within `radius` metres (2-D) of any centre.

    A hash of radius-sized cells keeps the exact distance test to points in the 3 x 3 cells
    around each centre's cell, so the cost stays linear in the number of points.
    """
    points_xy = np.asarray(points_xy, dtype=np.float64)
    centres_xy = np.asarray(centres_xy, dtype=np.float64)
    if len(points_xy) == 0 or len(centres_xy) == 0:
        return np.zeros(0, dtype=np.int64)
    origin = np.minimum(points_xy.min(axis=0), centres_xy.min(axis=0)) - 2 * radius

    def cells(xy: np.ndarray) -> np.ndarray:  # (n, 2) non-negative cell coordinates
        return np.floor((xy - origin) / radius).astype(np.int64)

    def packed(c: np.ndarray) -> np.ndarray:  # one int64 key per cell
        return (c[:, 0] << 32) | c[:, 1]

    offsets = np.array([(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)], dtype=np.int64)
    near_keys = np.unique(packed((cells(centres_xy)[:, None, :] + offsets[None]).reshape(-1, 2)))
    point_keys = packed(cells(points_xy))
    candidates = np.flatnonzero(np.isin(point_keys, near_keys))
    dist, _ = nearest(centres_xy, points_xy[candidates], radius)
    return candidates[dist <= radius]


def select_places_3dsg(graph: SceneGraph, query: np.ndarray, alpha: float, widen: int = 0) -> np.ndarray:
    """Places searched by Terra-3DSG for one unit query (D,): see the module docstring. `widen`
    1: every region of the best level, as when none is above alpha; 2: every place."""
    check_has_regions(graph, "--method 3dsg")
    if widen >= 2:
        return np.arange(len(graph.places))
    scores = region_similarities(graph, query)
    best_level = ranked_regions(graph, scores)[0][0]
    level_scores = scores[best_level - 1]
    chosen = np.flatnonzero(level_scores > alpha)
    if chosen.size == 0 or widen:
        chosen = np.arange(len(level_scores))
    places = places_of_regions(graph, [(best_level, int(i)) for i in chosen])
    above = places[place_similarities(graph, query)[places] > alpha]
    return above if above.size else places


def cluster_matches(points: np.ndarray, eps: float, min_samples: int, min_points: int) -> list[np.ndarray]:
    """DBSCAN clusters of (n, 3) points as arrays of row indices, largest first (ties: lowest row)."""
    if len(points) < max(min_samples, min_points):
        return []
    # scikit-learn's labels without importing it (about a second of a cold query): terra.dbscan.
    labels = dbscan_labels(points, eps, min_samples)
    keep = labels >= 0
    rows = np.flatnonzero(keep)
    order = np.argsort(labels[keep], kind="stable")
    groups = np.split(rows[order], np.flatnonzero(np.diff(labels[keep][order])) + 1)
    groups = [g for g in groups if len(g) >= min_points]
    groups.sort(key=lambda g: (-len(g), int(g[0])))
    return groups


def instance_groups(
    points: np.ndarray,
    groups: list[np.ndarray],
    cfg: RetrievalConfig,
    graph: SceneGraph | None = None,
    voxel: float = 0.0,
) -> list[np.ndarray]:
    """DBSCAN clusters (row arrays into `points`) with adjacent instances cut apart
    (terra.tasks.instances) at gaps among their points standing above the ground under the
    nearest place (`graph`; without one, above each cluster's lowest point), measured against
    the map's voxel size `voxel` (metres); pieces with fewer than `min_points` points are dropped."""
    ground: list[float | None] = [None] * len(groups)
    if graph is not None and len(graph.places) and groups:
        centre = np.array([points[g, :2].mean(axis=0) for g in groups])
        ground = [float(z) if np.isfinite(z) else None for z in ground_under(graph, centre)]
    out = []
    for rows, below in zip(groups, ground):
        pieces = split_instances(
            points[rows],
            min_length=cfg.instance_min_length,
            gap_factor=cfg.instance_gap_factor,
            ground=below,
            lift=cfg.ground_lift,
            min_spacing=voxel,
        )
        out += [rows[p] for p in pieces if len(p) >= cfg.min_points]
    return out


def grounded_groups(
    points: np.ndarray, groups: list[np.ndarray], graph: SceneGraph, cfg: RetrievalConfig, keep_flat: bool = True
) -> list[np.ndarray]:
    """The clusters (row arrays into `points`) that stand on the ground under their nearest place,
    floating parts attached; all of them when every one is flat and `keep_flat` (terra.tasks.standing)."""
    centre = np.array([points[g, :2].mean(axis=0) for g in groups])
    ground = ground_under(graph, centre)
    return standing_groups(points, groups, ground, cfg.ground_lift, cfg.float_height, cfg.attach_gap, keep_flat)


def object_boxes(points: np.ndarray, owner: np.ndarray, graph: SceneGraph | None, cfg: RetrievalConfig) -> list:
    """Boxes of the clusters (owner ids 0..G-1 of points (n, 3)), standing on the ground under the
    nearest place and square to the terrain strips around them when the graph gives them."""
    if graph is None or len(graph.places) == 0:
        return fit_object_boxes(points, owner, padding=cfg.box_padding, min_size=cfg.box_min_size)
    count = np.bincount(owner).astype(np.float64)
    centre = np.column_stack([np.bincount(owner, weights=points[:, d]) / count for d in range(2)])
    ground = ground_under(graph, centre)
    context = strip_directions(graph, centre, cfg.context_radius) if cfg.context_radius is not None else None
    return fit_object_boxes(
        points, owner, ground, context, cfg.box_padding, cfg.box_min_size, cfg.ground_lift, cfg.prefer_context
    )


def _match_clusters(
    msm: MetricSemanticMap,
    graph: SceneGraph | None,
    scorer: PointScorer,
    query_vectors: np.ndarray,
    terrain_vectors: np.ndarray,
    alpha: float,
    cfg: RetrievalConfig,
    feature: Feature,
    allowed: list[np.ndarray] | None,
    keep_flat: bool = True,
) -> tuple[list[tuple[int, np.ndarray]], np.ndarray, np.ndarray]:
    """Matched points clustered into objects per query: (query, rows into the candidate rows)
    pairs, the candidate map rows, and their (n, T + Q) similarities. `allowed`: per query, the
    map rows searched (None = every observed point). `keep_flat`: this search is the last one, so
    a query whose every cluster lies flat names a flat thing and keeps them (terra.tasks.standing)."""
    n_terrain = len(terrain_vectors)
    rows = None if allowed is None else np.unique(np.concatenate(allowed))
    # Query columns over every searched point first; the terrain columns (distractors) are only
    # needed where some query clears alpha.
    query_sim = scorer.similarity(query_vectors, feature, rows)
    above = np.flatnonzero((query_sim > alpha).any(axis=1))
    cand_rows = above if rows is None else rows[above]
    similarity = np.hstack([scorer.similarity(terrain_vectors, feature, cand_rows), query_sim[above]])
    matched = point_matches(similarity, n_terrain, alpha)
    clusters: list[tuple[int, np.ndarray]] = []
    for q in range(len(query_vectors)):
        mask = matched == q
        if allowed is not None:
            mask &= np.isin(cand_rows, allowed[q])
        local = np.flatnonzero(mask)
        groups = cluster_matches(msm.points[cand_rows[local]], cfg.dbscan_eps, cfg.dbscan_min_samples, cfg.min_points)
        if cfg.standing_only and graph is not None and len(graph.places) and groups:
            groups = grounded_groups(msm.points[cand_rows[local]], groups, graph, cfg, keep_flat)
        if cfg.split_instances:
            groups = instance_groups(msm.points[cand_rows[local]], groups, cfg, graph, msm.voxel_size)
        clusters += [(q, local[g]) for g in groups]
    return clusters, cand_rows, similarity


def find_objects(
    msm: MetricSemanticMap,
    graph: SceneGraph | None,
    queries: list[str],
    method: str = "ms-avg",
    alpha: float | None = None,
    config: TasksConfig | RetrievalConfig | None = None,
    embedder: TextEmbedder | None = None,
    scorer: PointScorer | None = None,
) -> list[FoundObject]:
    """Objects matching any of `queries` (one embedding batch), sorted by query, then best score.

    alpha: cosine threshold; None takes the configured default for the map's embedder.
    graph: needed by "3dsg" and to link objects to places (place = -1 without it).
    embedder: defaults to the map's; one with another name or dimension is refused.
    scorer: a PointScorer of `msm`, to reuse across calls on the same map.
    """
    cfg = _retrieval_config(config)
    queries = clean_queries(queries)
    if method not in METHODS:
        raise TerraError(f"unknown retrieval method {method!r}; expected one of: {', '.join(METHODS)}")
    embedder = _checked_embedder(msm, graph, embedder)
    if alpha is None:
        alpha = alpha_for(cfg.alpha, cfg.default_alpha, msm.embedder)
    query_vectors = embed_queries(embedder, queries)
    terrain_vectors = np.asarray(msm.terrain_embeddings, dtype=np.float32).reshape(-1, query_vectors.shape[1])
    scorer = scorer or PointScorer(msm)
    if method == "3dsg":
        clusters, cand_rows, similarity = _match_3dsg(msm, graph, scorer, query_vectors, terrain_vectors, alpha, cfg)
    else:
        clusters, cand_rows, similarity = _match_clusters(
            msm, graph, scorer, query_vectors, terrain_vectors, alpha, cfg, _POINT_FEATURE[method], None
        )
    if not clusters:
        return []
    return _found_objects(msm, graph, queries, clusters, cand_rows, similarity, len(terrain_vectors), cfg)


_POINT_FEATURE: dict[str, Feature] = {"ms-avg": "avg", "ms-max": "max"}


def _checked_embedder(msm: MetricSemanticMap, graph: SceneGraph | None, embedder: TextEmbedder | None) -> TextEmbedder:
    """`embedder`, or the map's by default; TerraError when it or the graph's embedder is not the map's."""
    if embedder is None:
        embedder = resolve_embedder(msm.embedder, msm.dim)
    check_embedder(embedder, msm.embedder, msm.dim)
    if graph is not None and graph.embedder and graph.embedder != msm.embedder:
        raise TerraError(
            f"scene graph embedder {graph.embedder!r} differs from the map's {msm.embedder!r}; rebuild the graph"
        )
    return embedder


def _match_3dsg(
    msm: MetricSemanticMap,
    graph: SceneGraph | None,
    scorer: PointScorer,
    query_vectors: np.ndarray,
    terrain_vectors: np.ndarray,
    alpha: float,
    cfg: RetrievalConfig,
) -> tuple[list[tuple[int, np.ndarray]], np.ndarray, np.ndarray]:
    """_match_clusters over the points near the places of each query's regions above alpha
    (terra.tasks.hierarchy.select_places_3dsg), widened for the queries that found nothing."""
    if graph is None:
        raise TerraError("--method 3dsg needs a scene graph in the bundle; build one with `terra build`")
    observed = scorer.observed()

    def searched(places: np.ndarray) -> np.ndarray:  # observed map rows within place_radius of the places
        return observed[points_near(msm.points[observed, :2], graph.places.position[places, :2], cfg.place_radius)]

    def match(allowed: list[np.ndarray], keep_flat: bool):
        return _match_clusters(
            msm,
            graph,
            scorer,
            query_vectors,
            terrain_vectors,
            alpha,
            cfg,
            cfg.sg_point_feature,
            allowed,
            keep_flat=keep_flat,
        )

    every = range(len(query_vectors))
    allowed = [searched(select_places_3dsg(graph, query_vectors[q], alpha)) for q in every]
    clusters, cand_rows, similarity = match(allowed, keep_flat=not cfg.sg_widen)
    # The regions above alpha narrow the search; when they hold no standing object for a
    # query, the answer comes from its places above alpha anywhere, then from every place,
    # rather than from nothing (a region scoring just above alpha can leave out every
    # instance). Only that last search keeps a query's flat-only clusters (a crosswalk).
    for widen in (1, 2) if cfg.sg_widen else ():
        empty = sorted(set(every) - {q for q, _ in clusters})
        if not empty:
            break
        for q in empty:
            allowed[q] = searched(select_places_3dsg(graph, query_vectors[q], alpha, widen))
        clusters, cand_rows, similarity = match(allowed, keep_flat=widen == 2)
    return clusters, cand_rows, similarity


def _found_objects(
    msm: MetricSemanticMap,
    graph: SceneGraph | None,
    queries: list[str],
    clusters: list[tuple[int, np.ndarray]],
    cand_rows: np.ndarray,
    similarity: np.ndarray,
    n_terrain: int,
    cfg: RetrievalConfig,
) -> list[FoundObject]:
    """One FoundObject per (query, rows into `cand_rows`) cluster: its box, its mean cosine with
    every query (`similarity` (n, T + Q) over the candidate rows, terrain columns first), its
    nearest place; sorted by query, then best score, then more points."""
    members = np.concatenate([m for _, m in clusters])
    owner = np.repeat(np.arange(len(clusters)), [len(m) for _, m in clusters])
    boxes = object_boxes(msm.points[cand_rows[members]], owner, graph, cfg)
    centres = np.array([b.center for b in boxes])
    if graph is not None and len(graph.places):
        places = nearest(graph.places.position[:, :2], centres[:, :2])[1]
    else:
        places = np.full(len(boxes), -1)
    found: list[FoundObject] = []
    for (q, local), box, place in zip(clusters, boxes, places):
        scores = similarity[local, n_terrain:].mean(axis=0)
        found.append(
            FoundObject(
                box.center,
                box.size,
                box.yaw,
                q,
                queries[q],
                float(scores[q]),
                scores,
                len(local),
                int(place),
                np.sort(cand_rows[local]),
            )
        )
    found.sort(key=lambda o: (o.query, -o.score, -o.point_count))
    return found


def best_object(found: list[FoundObject], query: int = 0) -> FoundObject | None:
    """The highest-scoring object of one query (ties: more points), or None."""
    mine = [o for o in found if o.query == query]
    return min(mine, key=lambda o: (-o.score, -o.point_count)) if mine else None


def with_objects(graph: SceneGraph, found: list[FoundObject]) -> SceneGraph:
    """A copy of `graph` whose object layer holds `found`; earlier objects with the same labels are
    replaced (re-running a query refreshes its objects), others are kept. Every object keeps its
    id, a refreshed one that of the object it replaces (terra.graph.ids.carried_objects)."""
    from terra.graph.ids import carried_objects

    old = graph.objects
    labels = {o.label for o in found}
    keep = np.array([label not in labels for label in old.label], dtype=bool)
    objects = Objects(
        center=np.vstack([np.asarray(old.center).reshape(-1, 3)[keep]] + [o.center[None] for o in found]),
        size=np.vstack([np.asarray(old.size).reshape(-1, 3)[keep]] + [o.size[None] for o in found]),
        yaw=np.concatenate([np.asarray(old.yaw, dtype=np.float64)[keep], [o.yaw for o in found]]),
        label=[lb for lb, k in zip(old.label, keep) if k] + [o.label for o in found],
        score=np.concatenate(
            [np.asarray(old.score, dtype=np.float32)[keep], np.array([o.score for o in found], dtype=np.float32)]
        ),
        point_count=np.concatenate(
            [
                np.asarray(old.point_count, dtype=np.int64)[keep],
                np.array([o.point_count for o in found], dtype=np.int64),
            ]
        ),
        place=np.concatenate(
            [np.asarray(old.place, dtype=np.int64)[keep], np.array([o.place for o in found], dtype=np.int64)]
        ),
    )
    next_id = graph.next_ids()
    objects, next_id["O"] = carried_objects(objects, old, next_id["O"])
    return replace(graph, objects=objects, next_id=next_id)
