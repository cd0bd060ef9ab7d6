"""What the places layer says about where an object stands: the ground height under it and the
direction of the terrain strips around it.

Places sit on the ground (their z is the local ground height), and the GVD edges between places
of one terrain run along the centre lines of its strips, so around an object they give the
directions of the sidewalks, roads and lawns it stands beside. Outdoor objects (benches, cars in
their stalls, racks, bins) mostly stand square to those: the dominant edge direction, modulo a
quarter turn, is a prior for the object's yaw where its points (often one or two faces seen from
one side) leave the yaw open.

Positions are metres in the map frame; angles are radians about +z.
"""

from __future__ import annotations

import numpy as np

from terra.graph.scene_graph import EDGE_GVD, SceneGraph
from terra.neighbours import nearest as nearest_points


def ground_under(graph: SceneGraph, xy: np.ndarray) -> np.ndarray:
    """(n,) ground height (metres) at xy (n, 2): the z of the nearest place (2-D)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(graph.places) == 0 or len(xy) == 0:
        return np.full(len(xy), np.nan)
    _, nearest = nearest_points(graph.places.position[:, :2], xy)
    return np.asarray(graph.places.position[nearest, 2], dtype=np.float64)


def strip_directions(graph: SceneGraph, xy: np.ndarray, radius: float = 8.0, min_agreement: float = 0.5) -> np.ndarray:
    """(n,) dominant direction (radians, modulo pi/2, in [-pi/4, pi/4)) of the GVD place edges
    whose midpoint lies within `radius` metres of each xy (n, 2), weighted by edge length; NaN where
    there is none or where they disagree (the length-weighted mean resultant of 4 x angle is below
    `min_agreement`)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    out = np.full(len(xy), np.nan)
    edges = np.asarray(graph.place_edges, dtype=np.int64).reshape(-1, 2)[np.asarray(graph.place_edge_kind) == EDGE_GVD]
    if len(edges) == 0 or len(xy) == 0:
        return out
    a, b = graph.places.position[edges[:, 0], :2], graph.places.position[edges[:, 1], :2]
    d = b - a
    length = np.hypot(d[:, 0], d[:, 1])
    phase = np.exp(4j * np.arctan2(d[:, 1], d[:, 0])) * length
    # Imported here: a cold query without boxes never needs it. SciPy re-exports cKDTree from a
    # compiled module that has no stub, so pyright cannot see it.
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]

    near = cKDTree((a + b) / 2).query_ball_point(xy, r=radius)
    for i, rows in enumerate(near):
        if not rows:
            continue
        total = phase[rows].sum()
        weight = length[rows].sum()
        if weight > 0 and abs(total) >= min_agreement * weight:
            out[i] = (np.angle(total) / 4 + np.pi / 4) % (np.pi / 2) - np.pi / 4
    return out
