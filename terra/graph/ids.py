"""Stable node ids: which node of a new build is which node of the previous one.

A node's index is its position in the graph's arrays and changes with every build; its id is the
name users and tools see (`p12`, the spark_dsg NodeSymbol 'p' << 56 | 12) and is kept across
builds where the node's ground did not change:
- a place takes the id of the old place of the same terrain within a tolerance (metres, map
  frame; half a grid cell by default), one-to-one, as many pairs as possible, then the closest;
- a region takes the id of the old region of its level it shares most places with, one-to-one,
  when their Jaccard index (shared places / places in either) is at least 0.5;
- an object takes the id of the old object of the same label whose box centre lies within a
  tolerance;
- every other node gets a fresh id above every id its layer used before: ids are never reused,
  and the graph records the next free id of each layer.

The functions take plain arrays (positions (N, 3) metres, group labels (N,), ids (N,) int64) so
they can be tested on hand-made graphs; `carry_ids` applies them to two SceneGraphs.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike

from terra.graph.scene_graph import Objects, SceneGraph

MIN_REGION_JACCARD = 0.5
OBJECT_TOLERANCE = 1.0  # metres between box centres: a re-found object moves by less than its size


def match_points(
    old_position: ArrayLike,
    old_group: ArrayLike,
    new_position: ArrayLike,
    new_group: ArrayLike,
    tolerance: float,
) -> np.ndarray:
    """(N,) index of the old point each new point is, -1 where none: pairs are of the same group
    and at most `tolerance` apart (metres, Euclidean over the given coordinates); each old point
    is taken once; the most pairs are made, and among those the smallest total distance."""
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

    old_position = np.asarray(old_position, dtype=np.float64)
    new_position = np.asarray(new_position, dtype=np.float64)
    match = np.full(len(new_position), -1, dtype=np.int64)
    if len(old_position) == 0 or len(new_position) == 0:
        return match
    pairs = cKDTree(new_position).sparse_distance_matrix(
        cKDTree(old_position), tolerance, output_type="ndarray"
    )  # rows (i new, j old, distance) within the tolerance
    rows = pairs[np.asarray(new_group)[pairs["i"]] == np.asarray(old_group)[pairs["j"]]]
    if len(rows) == 0:
        return match
    new_count = np.bincount(rows["i"], minlength=len(new_position))
    old_count = np.bincount(rows["j"], minlength=len(old_position))
    alone = (new_count[rows["i"]] == 1) & (old_count[rows["j"]] == 1)  # the usual case: one candidate each way
    match[rows["i"][alone]] = rows["j"][alone]
    rows = rows[~alone]
    if len(rows) == 0:
        return match
    for new, old, distance in _candidate_sets(rows["i"], rows["j"], rows["v"]):
        chosen_new, chosen_old = _assign(new, old, distance)
        match[chosen_new] = chosen_old
    return match


def _candidate_sets(new: np.ndarray, old: np.ndarray, distance: np.ndarray):
    """The candidate pairs split into independent sets (connected components of the bipartite
    graph of candidates), so each assignment problem stays small."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    new_nodes, new_local = np.unique(new, return_inverse=True)
    old_nodes, old_local = np.unique(old, return_inverse=True)
    n = len(new_nodes) + len(old_nodes)
    graph = sp.coo_matrix((np.ones(len(new)), (new_local, len(new_nodes) + old_local)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    pair_label = label[new_local]
    order = np.argsort(pair_label, kind="stable")
    bounds = np.flatnonzero(np.diff(pair_label[order])) + 1
    for rows in np.split(order, bounds):
        yield new[rows], old[rows], distance[rows]


def _assign(new: np.ndarray, old: np.ndarray, distance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A maximum matching of smallest total distance over the candidate pairs (new, old, distance):
    non-candidates cost more than all candidates together, so the solver uses one only when no
    more candidate pairs can be made, and those are dropped."""
    from scipy.optimize import linear_sum_assignment

    new_nodes, new_local = np.unique(new, return_inverse=True)
    old_nodes, old_local = np.unique(old, return_inverse=True)
    barrier = 1.0 + float(distance.sum()) * 2.0
    cost = np.full((len(new_nodes), len(old_nodes)), barrier)
    cost[new_local, old_local] = distance
    rows, cols = linear_sum_assignment(cost)
    real = cost[rows, cols] < barrier
    return new_nodes[rows[real]], old_nodes[cols[real]]


def match_groups(
    old_member_of: np.ndarray,
    new_member_of: np.ndarray,
    member_match: np.ndarray,
    old_count: int,
    new_count: int,
    min_jaccard: float = MIN_REGION_JACCARD,
) -> np.ndarray:
    """(new_count,) index of the old group each new group is, -1 where none.

    old_member_of: (M_old,) group of each old member (a region index per old place);
    new_member_of: (M_new,) the same for the new members; member_match: (M_new,) index of the old
    member each new member is, -1 for new members (from `match_points`). A new group is an old
    one when their Jaccard index |shared| / |either| is at least `min_jaccard`; one-to-one, the
    highest index first (ties: lower new, then lower old group)."""
    result = np.full(new_count, -1, dtype=np.int64)
    kept = member_match >= 0
    if not kept.any():
        return result
    pair_new = np.asarray(new_member_of)[kept]
    pair_old = np.asarray(old_member_of)[member_match[kept]]
    keys, shared = np.unique(pair_new.astype(np.int64) * old_count + pair_old, return_counts=True)
    pairs = np.stack([keys // old_count, keys % old_count], axis=1)
    new_size = np.bincount(new_member_of, minlength=new_count)
    old_size = np.bincount(old_member_of, minlength=old_count)
    jaccard = shared / (new_size[pairs[:, 0]] + old_size[pairs[:, 1]] - shared)
    taken_old = np.zeros(old_count, dtype=bool)
    for row in np.lexsort((pairs[:, 1], pairs[:, 0], -jaccard)):
        g_new, g_old = int(pairs[row, 0]), int(pairs[row, 1])
        if jaccard[row] >= min_jaccard and result[g_new] < 0 and not taken_old[g_old]:
            result[g_new], taken_old[g_old] = g_old, True
    return result


def carried_ids(match: np.ndarray, old_ids: np.ndarray, next_id: int) -> tuple[np.ndarray, int]:
    """(ids (N,) int64, next free id): the old node's id where `match` names one (>= 0), else
    fresh ids counted up from `next_id` in index order. `next_id` is raised above every old id
    first, so an id is never given twice."""
    old_ids = np.asarray(old_ids, dtype=np.int64)
    start = max(int(next_id), int(old_ids.max()) + 1 if len(old_ids) else 0)
    ids = np.where(match >= 0, old_ids[np.maximum(match, 0)] if len(old_ids) else -1, -1).astype(np.int64)
    fresh = np.flatnonzero(ids < 0)
    ids[fresh] = start + np.arange(len(fresh), dtype=np.int64)
    return ids, start + len(fresh)


def _group_codes(old_names: list[str], old_codes: np.ndarray, new_names: list[str]) -> np.ndarray:
    """Old group codes (indices into `old_names`) rewritten as indices into `new_names`; -2 (no
    new node has it) for a name the new list lacks."""
    lookup = np.array([new_names.index(n) if n in new_names else -2 for n in old_names] + [-2], dtype=np.int64)
    return lookup[np.asarray(old_codes, dtype=np.int64)]


def carry_ids(new: SceneGraph, old: SceneGraph, tolerance: float) -> SceneGraph:
    """`new` with the ids of `old` carried over (see the module docstring) and its next free ids.
    `tolerance`: metres between a place and its old self (half a grid cell is a good choice)."""
    next_id = old.next_ids()
    old_terrain = _group_codes(old.terrain_classes, old.places.terrain, new.terrain_classes)
    place_match = match_points(old.places.position, old_terrain, new.places.position, new.places.terrain, tolerance)
    place_ids, next_id["p"] = carried_ids(place_match, old.places.id, next_id.get("p", 0))
    regions = []
    for k, level in enumerate(new.regions, start=1):
        char = level.char
        if k <= len(old.regions):
            group_match = match_groups(
                old.place_region(k), new.place_region(k), place_match, len(old.regions[k - 1]), len(level)
            )
            old_ids = old.regions[k - 1].id
        else:
            group_match, old_ids = np.full(len(level), -1, dtype=np.int64), np.zeros(0, dtype=np.int64)
        ids, next_id[char] = carried_ids(group_match, old_ids, next_id.get(char, 0))
        regions.append(replace(level, id=ids))
    objects, next_id["O"] = carried_objects(new.objects, old.objects, next_id.get("O", 0))
    places = replace(new.places, id=place_ids)
    return replace(new, places=places, regions=regions, objects=objects, next_id=next_id)


def carried_objects(new: Objects, old: Objects, next_id: int) -> tuple[Objects, int]:
    """(`new` objects with the ids of the old objects of the same label whose centres lie within
    OBJECT_TOLERANCE, next free object id)."""
    labels = sorted(set(old.label) | set(new.label))
    match = match_points(
        old.center,
        np.array([labels.index(lb) for lb in old.label], dtype=np.int64),
        new.center,
        np.array([labels.index(lb) for lb in new.label], dtype=np.int64),
        OBJECT_TOLERANCE,
    )
    ids, next_free = carried_ids(match, old.id, next_id)
    return replace(new, id=ids), next_free
