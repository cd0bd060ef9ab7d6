"""A* shortest paths over a graph stored as CSR arrays, with the straight-line heuristic.

The heuristic h(v) = scale x ||position[v] - position[goal]|| is admissible and consistent when
every edge costs at least `scale` times the straight-line distance between its endpoints, so each
node is settled at most once and the first time the goal is popped its cost is optimal.
"""

from __future__ import annotations

import heapq
import math

import numpy as np


def astar(
    indptr: np.ndarray,
    indices: np.ndarray,
    cost: np.ndarray,
    position: np.ndarray,
    start: int,
    goal: int,
    heuristic_scale: float = 1.0,
) -> tuple[list[int], float] | None:
    """The cheapest path from `start` to `goal` as (node list, total cost), or None if unreachable.

    indptr, indices, cost: a directed graph in CSR form (edges of node u are
    indices[indptr[u]:indptr[u + 1]] with their costs); cost[e] >= the straight-line distance
    between the edge's endpoints. position: (n, 2 or 3) node positions in metres.
    heuristic_scale: h = scale x straight-line distance; admissible while every edge costs at
    least `scale` times its straight-line length (e.g. 1 + the smallest terrain penalty).
    Ties between equal f-values go to the larger cost-so-far, then the lower node index.
    """
    n = len(indptr) - 1
    if start == goal:
        return [start], 0.0
    offset = np.asarray(position, dtype=np.float64) - np.asarray(position[goal], dtype=np.float64)
    h = (heuristic_scale * np.linalg.norm(offset, axis=1)).tolist()
    # Plain lists: element access and slicing on them are several times faster than on arrays.
    ptr, nbr, w = indptr.tolist(), indices.tolist(), cost.tolist()
    g = [math.inf] * n
    parent = [-1] * n
    closed = bytearray(n)
    g[start] = 0.0
    heap = [(h[start], -0.0, start)]
    pop, push = heapq.heappop, heapq.heappush
    while heap:
        _, neg_g, u = pop(heap)
        if closed[u]:
            continue
        if u == goal:
            break
        closed[u] = 1
        gu = -neg_g
        lo, hi = ptr[u], ptr[u + 1]
        for v, c in zip(nbr[lo:hi], w[lo:hi]):
            gv = gu + c
            if gv < g[v] and not closed[v]:
                g[v] = gv
                parent[v] = u
                push(heap, (gv + h[v], -gv, v))
    if g[goal] == math.inf:
        return None
    path = [goal]
    while path[-1] != start:
        path.append(parent[path[-1]])
    path.reverse()
    return path, g[goal]
