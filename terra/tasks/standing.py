"""Objects stand on the ground: clusters that do not are mask bleed or parts of an object.

Two kinds of cluster of matched points are not objects by themselves:

- Flat: fewer than three points at least `lift` metres above the ground, while the same query
  has clusters that do rise off it. A mask that bleeds past an object's outline labels the
  pavement or lawn around it with the object's class; those points lie on the ground and form a
  thin slab that no object is (the same `lift` keeps such points out of box footprints,
  terra.tasks.boxes). When every cluster of a query is flat over the whole search, the query
  names a flat thing (a crosswalk, a painted marking, a manhole cover) and its clusters are all
  kept (`keep_flat`; a narrowed search that may still widen passes False).
- Floating: the lowest point more than `float_height` metres above the ground. Outdoor objects
  rest on the ground, so a cluster hanging in the air is a part whose support the matched points
  missed: a lamp head on its arm more than DBSCAN's eps from the pole's top, a signal head, a
  sign plate. It joins the nearest standing cluster of the same query when one comes within
  `attach_gap` metres (its box then covers the whole object), else it is dropped.

Points are (n, 3) metres in the map frame; ground heights are metres (NaN = unknown: the cluster
is kept as it is).
"""

from __future__ import annotations

import numpy as np


def standing_groups(
    points: np.ndarray,
    groups: list[np.ndarray],
    ground_z: np.ndarray,
    lift: float = 0.15,
    float_height: float | None = 1.0,
    attach_gap: float = 2.0,
    keep_flat: bool = True,
) -> list[np.ndarray]:
    """The clusters (row arrays into `points` (n, 3)) that stand on the ground, each with the
    floating parts attached to it; `ground_z` (G,) is the ground height under each cluster.
    Order follows `groups` (attached parts are appended to their cluster's rows). `keep_flat`:
    when every cluster is flat they are all returned (the query names a flat thing)."""
    points = np.asarray(points, dtype=np.float64)
    ground = np.asarray(ground_z, dtype=np.float64).reshape(len(groups))
    known = np.isfinite(ground)
    high = np.array([np.count_nonzero(points[g, 2] >= ground[i] + lift) for i, g in enumerate(groups)], dtype=np.int64)
    bottom = np.array([points[g, 2].min() - ground[i] if known[i] else -np.inf for i, g in enumerate(groups)])
    flat = known & (high < 3)
    if keep_flat and flat.all():  # only flat things match: the query names one (module docstring)
        return list(groups)
    floating = known & ~flat & (bottom > float_height) if float_height is not None else np.zeros(len(groups), bool)
    standing = [i for i in range(len(groups)) if not flat[i] and not floating[i]]
    out = {i: [groups[i]] for i in standing}
    if standing and floating.any():
        # Only when a cluster floats (cKDTree: compiled, no stub for pyright).
        from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]

        rows = np.concatenate([groups[i] for i in standing])
        owner = np.repeat(standing, [len(groups[i]) for i in standing])
        tree = cKDTree(points[rows])
        for i in np.flatnonzero(floating):
            dist, nearest = tree.query(points[groups[i]])
            k = int(np.argmin(dist))
            if dist[k] <= attach_gap:
                out[int(owner[nearest[k]])].append(groups[i])
    return [np.concatenate(out[i]) for i in standing]
