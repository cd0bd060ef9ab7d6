"""A* shortest paths over a graph stored as CSR arrays, with the straight-line heuristic.

The heuristic h(v) = scale x ||position[v] - position[goal]|| is admissible and consistent when
every edge costs at least `scale` times the straight-line distance between its endpoints, so each
node is settled at most once and the first time the goal is popped its cost is optimal.
"""

from __future__ import annotations

import heapq
import math
import threading
import weakref

import numpy as np

# Adjacency lists of graphs searched many times (a long-lived process keeps its cost graphs):
# id(indptr) -> (weak reference to indptr, id(indices), id(cost), per-node [(neighbour, cost)]).
# CSR arrays handed to astar are never changed in place, so their identity names their content.
_ADJACENCY: dict[int, tuple[weakref.ref, int, int, list]] = {}
_ADJACENCY_LOCK = threading.Lock()


def prepare_adjacency(indptr: np.ndarray, indices: np.ndarray, cost: np.ndarray) -> None:
    """Remember per-node (neighbour, cost) lists for this CSR graph, so later astar calls on the
    same arrays skip the list conversions and slicing (about twice as fast on 20,000 places).
    Worth it for a graph searched repeatedly; the memo goes when `indptr` is garbage-collected."""
    ptr, nbr, w = indptr.tolist(), indices.tolist(), cost.tolist()
    adjacency = [list(zip(nbr[ptr[u] : ptr[u + 1]], w[ptr[u] : ptr[u + 1]])) for u in range(len(ptr) - 1)]
    key = id(indptr)

    def forget(_ref: weakref.ref, key: int = key) -> None:
        with _ADJACENCY_LOCK:
            _ADJACENCY.pop(key, None)

    with _ADJACENCY_LOCK:
        _ADJACENCY[key] = (weakref.ref(indptr, forget), id(indices), id(cost), adjacency)


def _prepared(indptr: np.ndarray, indices: np.ndarray, cost: np.ndarray) -> list | None:
    with _ADJACENCY_LOCK:
        entry = _ADJACENCY.get(id(indptr))
    if entry is not None and entry[0]() is indptr and entry[1:3] == (id(indices), id(cost)):
        return entry[3]
    return None


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
    adjacency = _prepared(indptr, indices, cost)
    if adjacency is None:
        # Plain lists: element access and slicing on them are several times faster than on arrays.
        ptr, nbr, w = indptr.tolist(), indices.tolist(), cost.tolist()
        adjacency = _LazyAdjacency(ptr, nbr, w)
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
        for v, c in adjacency[u]:
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


class _LazyAdjacency:
    """adjacency[u] as zip slices of the CSR lists (a one-off search builds no per-node lists)."""

    __slots__ = ("ptr", "nbr", "w")

    def __init__(self, ptr: list, nbr: list, w: list):
        self.ptr, self.nbr, self.w = ptr, nbr, w

    def __getitem__(self, u: int):  # noqa: ANN204
        lo, hi = self.ptr[u], self.ptr[u + 1]
        return zip(self.nbr[lo:hi], self.w[lo:hi])
