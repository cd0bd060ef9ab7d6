"""The robot's route: shortest walkway paths through the layout's waypoints (map frame, metres).

Walkways are polylines; they are sampled every metre and points closer than `snap` metres are merged,
so walkways that touch or cross form junctions without any bookkeeping in the layout code.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module


def sample_polyline(points: np.ndarray, step: float) -> np.ndarray:
    """Points along a polyline at most `step` metres apart, keeping every vertex."""
    out = [points[:1]]
    for a, b in zip(points[:-1], points[1:]):
        n = max(int(np.ceil(np.linalg.norm(b - a) / step)), 1)
        out.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
    return np.concatenate(out)


def walkway_graph(walkways: list[np.ndarray], step: float = 1.0, snap: float = 0.6) -> tuple[np.ndarray, sp.csr_matrix]:
    """Nodes (V, 2) and a symmetric sparse graph of walkway segments weighted by length."""
    samples = [sample_polyline(w, step) for w in walkways]
    pts = np.concatenate(samples)
    pairs = cKDTree(pts).query_pairs(snap, output_type="ndarray")
    n = pts.shape[0]
    link = (
        sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        if len(pairs)
        else sp.coo_matrix((n, n))
    )
    _, label = connected_components(link, directed=False)
    # Each merged node sits at the first sample of its group.
    _, first = np.unique(label, return_index=True)
    nodes = pts[first]
    starts = np.cumsum([0] + [len(s) for s in samples])
    a = np.concatenate([np.arange(s, e - 1) for s, e in zip(starts[:-1], starts[1:])])
    u, v = label[a], label[a + 1]
    keep = u != v
    u, v = u[keep], v[keep]
    w = np.linalg.norm(nodes[u] - nodes[v], axis=1)
    graph = sp.coo_matrix(
        (np.concatenate([w, w]), (np.concatenate([u, v]), np.concatenate([v, u]))), shape=(len(nodes),) * 2
    ).tocsr()
    return nodes, graph  # pyright: ignore[reportReturnType]  # scipy infers csr_array for coo_matrix.tocsr()


def plan_route(
    walkways: list[np.ndarray], waypoints: list[tuple[float, float]], max_length: float | None = None
) -> np.ndarray:
    """Polyline (K, 2) through `waypoints` in order along shortest walkway paths, cut at `max_length`."""
    if not walkways or len(waypoints) < 2:
        raise ValueError("a route needs walkways and at least two waypoints")
    nodes, graph = walkway_graph(walkways)
    _, snapped = cKDTree(nodes).query(np.asarray(waypoints, float))
    path = [int(snapped[0])]
    for src, dst in zip(snapped[:-1], snapped[1:]):
        if src == dst:
            continue
        dist, pred = dijkstra(graph, indices=int(src), return_predecessors=True)
        if not np.isfinite(dist[dst]):
            raise ValueError(f"waypoint at {nodes[dst]} is not reachable from {nodes[src]} along walkways")
        leg = [int(dst)]
        while leg[-1] != src:
            leg.append(int(pred[leg[-1]]))
        path.extend(leg[::-1][1:])
    route = nodes[path]
    if max_length is not None:
        route = cut_polyline(route, max_length)
    return route


def cut_polyline(points: np.ndarray, length: float) -> np.ndarray:
    """The first `length` metres of a polyline."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    if cum[-1] <= length:
        return points
    k = int(np.searchsorted(cum, length))
    frac = (length - cum[k - 1]) / max(seg[k - 1], 1e-12)
    return np.concatenate([points[:k], [points[k - 1] + frac * (points[k] - points[k - 1])]])
