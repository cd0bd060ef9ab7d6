"""A one-cell-thin skeleton (the GVD) as a graph: nodes at junctions and dead ends, edges along it.

Cells are joined by m-adjacency (4-neighbours, and diagonal neighbours only where no shared
4-neighbour is on the skeleton), so every cell inside a path has exactly two neighbours. Nodes are
clusters of cells whose degree is not 2; a loop without any such cell gets a node at its first
cell. Each remaining run of degree-2 cells is one edge, ordered from one end to the other by its
geodesic distance (scipy.sparse.csgraph), so no step walks the grid cell by cell in Python.

Cells are (row, col) integer pairs of the grid; lengths are in cells.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra

from terra.graph.cell_index import CellIndex

_OFFSETS = ((0, 1, 1.0), (1, 0, 1.0), (1, 1, np.sqrt(2.0)), (1, -1, np.sqrt(2.0)))


@dataclass
class SkeletonGraph:
    """node_cell: (n, 2) row/col of each node. edges: (e, 2) node pairs (a loop has u == v).
    path_cells: all edge polylines concatenated, each from its u cell to its v cell inclusive;
    path_start: (e + 1,) offsets into path_cells. cell_node: the cells of every node cluster and
    their node, used to remove a pruned tip with its whole cluster."""

    node_cell: np.ndarray
    edges: np.ndarray
    path_cells: np.ndarray
    path_start: np.ndarray
    cell_node: NodeCells

    def path(self, e: int) -> np.ndarray:
        return self.path_cells[self.path_start[e] : self.path_start[e + 1]]

    def edge_length(self) -> np.ndarray:
        """(e,) polyline length of each edge, cells."""
        steps = np.linalg.norm(np.diff(self.path_cells, axis=0).astype(np.float64), axis=1)
        csum = np.concatenate([[0.0], np.cumsum(steps)])
        return csum[self.path_start[1:] - 1] - csum[self.path_start[:-1]]

    def degree(self) -> np.ndarray:
        """(n,) number of edge ends at each node (a loop counts twice)."""
        return np.bincount(self.edges.ravel(), minlength=len(self.node_cell))


@dataclass
class NodeCells:
    """The cells of a skeleton graph's node clusters: cells (m, 2) row/col in raster order and
    node (m,) the node each belongs to. A list, not an (H, W) array: memory for the skeleton's
    node cells, not for the grid."""

    cells: np.ndarray
    node: np.ndarray

    def renumbered(self, new_id: np.ndarray) -> NodeCells:
        """Each cell's node renumbered by `new_id` (-1 drops the cell), raster order kept."""
        node = np.asarray(new_id)[self.node]
        keep = node >= 0
        return NodeCells(self.cells[keep], node[keep].astype(np.int64))


def skeleton_adjacency(skeleton: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
    """Skeleton cells (K, 2) in raster order and their symmetric m-adjacency (K, K), weights 1 or
    sqrt(2) cells."""
    return cell_adjacency(skeleton, m_adjacency=True)


def cell_adjacency(mask: np.ndarray, m_adjacency: bool = False) -> tuple[np.ndarray, sp.csr_matrix]:
    """Cells (K, 2) of a bool grid in raster order and their symmetric 8-adjacency (K, K), weights
    1 (4-neighbours) or sqrt(2) (diagonal), in cells. With `m_adjacency`, a diagonal pair is joined
    only where neither shared 4-neighbour is in the mask (a thin skeleton's own steps)."""
    mask = np.asarray(mask, dtype=bool)
    cells = np.argwhere(mask)
    find = CellIndex(cells, mask.shape).find  # no (H, W) index: memory for the cells, not the grid
    # int32 positions (scipy's own index type for fewer than 2**31 cells): memory per cell matters
    # on the large patches of the place joins.
    index = np.int32 if len(cells) < np.iinfo(np.int32).max else np.int64
    rows, cols, weights = [], [], []
    r, c = cells[:, 0], cells[:, 1]
    for dr, dc, w in _OFFSETS:
        other = find(r + dr, c + dc)
        keep = other >= 0
        if m_adjacency and dr and dc:
            keep &= (find(r + dr, c) < 0) & (find(r, c + dc) < 0)
        rows.append(np.flatnonzero(keep).astype(index))
        cols.append(other[keep].astype(index))
        weights.append(np.full(int(keep.sum()), w))
        del other, keep
    i, j, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
    del rows, cols, weights
    adjacency = sp.coo_matrix(
        (np.concatenate([w, w]), (np.concatenate([i, j]), np.concatenate([j, i]))), shape=(len(cells), len(cells))
    )
    del i, j, w
    return cells, adjacency.tocsr()  # pyright: ignore[reportReturnType]  # scipy infers csr_array for coo_matrix.tocsr()


def skeleton_graph(skeleton: np.ndarray, distance: np.ndarray) -> SkeletonGraph:
    """Nodes and edges of a thin skeleton. `distance` (H, W) picks each node cluster's cell: the
    one with the largest clearance (ties: first in raster order)."""
    cells, adjacency = skeleton_adjacency(skeleton)
    if len(cells) == 0:
        return SkeletonGraph(
            np.zeros((0, 2), np.int64),
            np.zeros((0, 2), np.int64),
            np.zeros((0, 2), np.int64),
            np.zeros(1, np.int64),
            NodeCells(np.zeros((0, 2), np.int64), np.zeros(0, np.int64)),
        )
    is_node = _node_cells(cells, adjacency, np.shape(skeleton))
    node_idx = np.flatnonzero(is_node)
    node_cell, cluster = _node_clusters(cells, adjacency, node_idx, distance)
    cell_node = NodeCells(cells[node_idx].astype(np.int64), cluster.astype(np.int64))  # node_idx ascends: raster order
    if is_node.all():
        return _assemble(node_cell, [], [], cell_node)
    runs = _find_runs(adjacency, np.flatnonzero(~is_node), node_idx, cluster)
    edges, path_cells, path_start = _run_edges(runs, cells, node_cell)
    edges, path_cells, path_start = _join_inner_attachments(runs, cells, node_cell, edges, path_cells, path_start)
    return SkeletonGraph(
        node_cell, edges.astype(np.int64), path_cells.astype(np.int64), path_start.astype(np.int64), cell_node
    )


def _node_cells(cells: np.ndarray, adjacency: sp.csr_matrix, shape: tuple[int, ...]) -> np.ndarray:
    """(K,) whether each skeleton cell belongs to a node: its degree is not 2, it lies in a 2x2
    block, or it is the first cell of a loop that has no other node."""
    n_cells = len(cells)
    degree = np.diff(adjacency.indptr)
    is_node = degree != 2
    # Cells of a 2x2 block (thinning can leave one where branches meet) form one node.
    is_node |= _in_block(cells, (shape[0], shape[1]))
    # A loop with no junction or end gets a node at its first cell.
    _, comp = connected_components(adjacency, directed=False)
    has_node = np.bincount(comp, weights=is_node, minlength=comp.max() + 1) > 0
    first_cell = np.full(comp.max() + 1, n_cells)
    np.minimum.at(first_cell, comp, np.arange(n_cells))
    is_node[first_cell[~has_node]] = True
    return is_node


def _node_clusters(
    cells: np.ndarray, adjacency: sp.csr_matrix, node_idx: np.ndarray, distance: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The node clusters (connected node cells `node_idx`): each node's cell (n, 2), the one of
    largest clearance in `distance` (ties: first in raster order), and each node cell's node."""
    _, cluster = connected_components(adjacency[node_idx][:, node_idx], directed=False)
    clearance = distance[cells[node_idx, 0], cells[node_idx, 1]]
    order = np.lexsort((node_idx, -clearance, cluster))  # per cluster: best clearance first
    first = np.ones(len(order), dtype=bool)
    first[1:] = cluster[order][1:] != cluster[order][:-1]
    n_nodes = int(cluster.max()) + 1 if len(cluster) else 0
    node_cell = np.zeros((n_nodes, 2), dtype=np.int64)
    node_cell[cluster[order][first]] = cells[node_idx[order][first]]
    return node_cell, cluster


@dataclass
class _Runs:
    """The runs of degree-2 cells between the nodes. cells: (s,) indices of the run cells among the
    skeleton's cells; run: (s,) the run of each; along: (s,) its geodesic distance (cells) from
    its run's start; count: the number of runs. attach: (a, 2) attachments (run cell, node),
    sorted along each run; bounds: (count + 1,) offsets of each run's attachments in attach."""

    cells: np.ndarray
    run: np.ndarray
    along: np.ndarray
    count: int
    attach: np.ndarray
    bounds: np.ndarray


def _find_runs(adjacency: sp.csr_matrix, seg_idx: np.ndarray, node_idx: np.ndarray, cluster: np.ndarray) -> _Runs:
    """The runs of the run cells `seg_idx`, each ordered from one end, and the nodes they touch."""
    S = adjacency[seg_idx][:, seg_idx]
    n_seg, seg = connected_components(S, directed=False)
    # Start of each run: its first end cell (degree <= 1 inside the run) in raster order; a run
    # without ends cannot occur (loops got a node), but fall back to its first cell.
    start = np.full(n_seg, len(seg_idx))
    np.minimum.at(start, seg[np.diff(S.indptr) <= 1], np.flatnonzero(np.diff(S.indptr) <= 1))
    fallback = np.full(n_seg, len(seg_idx))
    np.minimum.at(fallback, seg, np.arange(len(seg_idx)))
    start = np.where(start == len(seg_idx), fallback, start)
    along = dijkstra(S, directed=False, indices=start, min_only=True)
    # Attachments (run cell, node) sorted along each run: the first names u, the last v.
    run_node = adjacency[seg_idx][:, node_idx].tocoo()
    att = np.unique(np.stack([run_node.row, cluster[run_node.col]], axis=1), axis=0)
    att_seg = seg[att[:, 0]]
    order = np.lexsort((att[:, 1], along[att[:, 0]], att_seg))
    att, att_seg = att[order], att_seg[order]
    bounds = np.searchsorted(att_seg, np.arange(n_seg + 1))
    return _Runs(seg_idx, seg, along, n_seg, att, bounds)


def _run_edges(runs: _Runs, cells: np.ndarray, node_cell: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One edge per run that touches a node, from its first attachment's node u to its last one's
    v: edges (e, 2), path cells (u's cell, the run's cells in order, v's cell) and path starts."""
    att, bounds, seg = runs.attach, runs.bounds, runs.run
    has = bounds[1:] > bounds[:-1]
    u = att[bounds[:-1][has], 1]
    v = att[bounds[1:][has] - 1, 1]
    # Paths: u's cell, the run's cells in order, v's cell.
    cell_order = np.lexsort((runs.along, seg))
    cell_order = cell_order[has[seg[cell_order]]]
    run_len = np.bincount(seg[cell_order], minlength=runs.count)[has]
    run_start = np.concatenate([[0], np.cumsum(run_len)[:-1]])
    run_cells = cells[runs.cells[cell_order]]
    at = np.stack([run_start, run_start + run_len], axis=1).ravel()
    ends = np.stack([node_cell[u], node_cell[v]], axis=1).reshape(-1, 2)
    path_cells = np.insert(run_cells, at, ends, axis=0)
    path_start = np.concatenate([[0], np.cumsum(run_len + 2)])
    return np.stack([u, v], axis=1), path_cells, path_start


def _join_inner_attachments(
    runs: _Runs,
    cells: np.ndarray,
    node_cell: np.ndarray,
    edges: np.ndarray,
    path_cells: np.ndarray,
    path_start: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`_run_edges`' edges and paths, plus an edge for every further node a run touches between
    its two ends (rare pixel configurations), joined to the nearer end's node."""
    att, bounds, along = runs.attach, runs.bounds, runs.along
    extra_edges, extra_paths = [], []
    for s in np.flatnonzero(bounds[1:] - bounds[:-1] > 2):
        uu, vv = att[bounds[s], 1], att[bounds[s + 1] - 1, 1]
        half = along[att[bounds[s] : bounds[s + 1], 0]].max() / 2
        for k in range(bounds[s] + 1, bounds[s + 1] - 1):
            w, x = att[k, 1], (uu if along[att[k, 0]] <= half else vv)
            if w != x:
                extra_edges.append((x, w))
                extra_paths.append(np.vstack([node_cell[x], cells[runs.cells[att[k, 0]]], node_cell[w]]))
    if extra_edges:
        edges = np.vstack([edges, np.asarray(extra_edges)])
        path_start = np.concatenate([path_start, path_start[-1] + 3 * np.arange(1, len(extra_edges) + 1)])
        path_cells = np.vstack([path_cells] + extra_paths)
    return edges, path_cells, path_start


def _in_block(cells: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(K,) whether each cell (raster order) belongs to a 2x2 block of cells of the set."""
    find = CellIndex(cells, shape).find
    on = {(dr, dc): find(cells[:, 0] + dr, cells[:, 1] + dc) >= 0 for dr in (-1, 0, 1) for dc in (-1, 0, 1)}
    inside = np.zeros(len(cells), dtype=bool)
    for top, left in ((0, 0), (-1, 0), (0, -1), (-1, -1)):  # the four blocks holding a cell, by their top-left corner
        inside |= on[top, left] & on[top + 1, left] & on[top, left + 1] & on[top + 1, left + 1]
    return inside


def _assemble(node_cell: np.ndarray, edges: list, paths: list, cell_node: NodeCells) -> SkeletonGraph:
    edges_arr = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    lengths = np.array([len(p) for p in paths], dtype=np.int64)
    path_start = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    path_cells = np.vstack(paths).astype(np.int64) if paths else np.zeros((0, 2), np.int64)
    return SkeletonGraph(node_cell, edges_arr, path_cells, path_start, cell_node)


def _path_rows(g: SkeletonGraph, edge_ids: np.ndarray, drop_ends: bool = False) -> np.ndarray:
    """Rows of g.path_cells belonging to the given edges (without each path's two end cells)."""
    lo = g.path_start[edge_ids] + (1 if drop_ends else 0)
    hi = g.path_start[edge_ids + 1] - (1 if drop_ends else 0)
    n = np.maximum(hi - lo, 0)
    return np.repeat(lo - np.concatenate([[0], np.cumsum(n)[:-1]]), n) + np.arange(n.sum())


def _drop_stubs(skeleton: np.ndarray) -> np.ndarray:
    """Remove one-cell spurs: end cells whose only neighbour is a junction cell. (They would join
    the junction's node cluster and hide the spur from the pruning rule.)"""
    cells, A = skeleton_adjacency(skeleton)
    if len(cells) == 0:
        return skeleton
    degree = np.diff(A.indptr)
    ends = np.flatnonzero(degree == 1)
    neighbour = A.indices[A.indptr[ends]]
    stub = ends[degree[neighbour] >= 3]
    out = skeleton.copy()
    out[cells[stub, 0], cells[stub, 1]] = False
    return out


def prune_spurs(
    skeleton: np.ndarray, distance: np.ndarray, ratio: float, min_length: float, max_rounds: int = 8
) -> np.ndarray:
    """Remove dead-end branches shorter than ratio * (junction clearance) + min_length cells.

    A 90-degree corner of the free space puts a branch of about sqrt(2) times the clearance into
    the corner; real ends (a path that leaves the junction) are longer. Repeats until nothing
    changes, so spurs left behind by a removal go too. Returns the pruned skeleton.
    """
    skeleton = np.array(skeleton, dtype=bool)
    for _ in range(max_rounds):
        skeleton = _drop_stubs(skeleton)
        g = skeleton_graph(skeleton, distance)
        if len(g.edges) == 0:
            break
        deg = g.degree()
        u, v = g.edges[:, 0], g.edges[:, 1]
        tip_u = (deg[u] == 1) & (deg[v] >= 3)
        tip_v = (deg[v] == 1) & (deg[u] >= 3)
        junction = np.where(tip_u, v, u)
        limit = ratio * distance[g.node_cell[junction, 0], g.node_cell[junction, 1]] + min_length
        spur = (tip_u | tip_v) & (g.edge_length() < limit)
        if not spur.any():
            break
        spur_idx = np.flatnonzero(spur)
        inner = _path_rows(g, spur_idx, drop_ends=True)
        skeleton[g.path_cells[inner, 0], g.path_cells[inner, 1]] = False
        tips = np.where(tip_u, u, v)[spur_idx]
        drop = np.isin(g.cell_node.node, tips)
        skeleton[g.cell_node.cells[drop, 0], g.cell_node.cells[drop, 1]] = False
    return skeleton


def simplify(g: SkeletonGraph, distance: np.ndarray, junction_merge: float) -> SkeletonGraph:
    """Contract junction-to-junction edges shorter than `junction_merge` times the smaller
    junction clearance (one crossing drawn as two nearby junctions; each junction merges at most
    once), then dissolve nodes left with exactly two edges by joining those edges' paths."""
    if len(g.edges) == 0:
        return g
    clear = distance[g.node_cell[:, 0], g.node_cell[:, 1]]
    short = _junction_pairs(g, clear, junction_merge)
    node_cell, cell_node = g.node_cell, g.cell_node
    edges, paths = g.edges.copy(), [g.path(e) for e in range(len(g.edges))]
    if short.any():
        node_cell, cell_node, edges, paths = _contract(g, clear, short, edges, paths)
    kept_edges, kept_paths, removed = _dissolve_degree_two(edges, paths, len(node_cell))
    # Renumber the surviving nodes in their old order.
    new_index = np.where(removed, -1, np.cumsum(~removed) - 1)
    cell_node = cell_node.renumbered(new_index)
    remapped = [(int(new_index[a]), int(new_index[b])) for a, b in kept_edges]
    return _assemble(node_cell[~removed], remapped, kept_paths, cell_node)


def _junction_pairs(g: SkeletonGraph, clear: np.ndarray, junction_merge: float) -> np.ndarray:
    """(e,) bool: the junction-to-junction edges to contract, shorter than `junction_merge` times
    the smaller clearance `clear` of their junctions, taken shortest first while both ends are
    still free."""
    length = g.edge_length()
    deg = g.degree()
    u, v = g.edges[:, 0], g.edges[:, 1]
    short = (u != v) & (deg[u] >= 3) & (deg[v] >= 3) & (length < junction_merge * np.minimum(clear[u], clear[v]))
    if short.any():
        # Pairs only, shortest first (a matching): chains of merges would pull whole networks
        # of nearby junctions, e.g. the loops around a row of trees, into one node.
        taken = np.zeros(len(g.node_cell), dtype=bool)
        for e in np.flatnonzero(short)[np.argsort(length[short], kind="stable")]:
            if taken[u[e]] or taken[v[e]]:
                short[e] = False
            else:
                taken[u[e]] = taken[v[e]] = True
    return short


def _contract(
    g: SkeletonGraph, clear: np.ndarray, short: np.ndarray, edges: np.ndarray, paths: list[np.ndarray]
) -> tuple[np.ndarray, NodeCells, np.ndarray, list[np.ndarray]]:
    """Merge the two junctions of each `short` edge into one node at the cell of the larger
    clearance, dropping those edges: the node cells, node clusters, edges and paths after it."""
    n = len(g.node_cell)
    u, v = g.edges[:, 0], g.edges[:, 1]
    merge = sp.coo_matrix((np.ones(int(short.sum())), (u[short], v[short])), shape=(n, n))
    n_new, new_id = connected_components(merge, directed=False)
    order = np.lexsort((np.arange(n), -clear, new_id))
    first = np.ones(n, dtype=bool)
    first[1:] = new_id[order][1:] != new_id[order][:-1]
    rep = np.zeros(n_new, dtype=np.int64)
    rep[new_id[order][first]] = order[first]
    node_cell = g.node_cell[rep]
    keep = ~short
    edges = new_id[edges[keep]]
    paths = [p.copy() for p, k in zip(paths, keep) if k]
    for p, (a, b) in zip(paths, edges):
        p[0], p[-1] = node_cell[a], node_cell[b]
    return node_cell, g.cell_node.renumbered(new_id), edges, paths


def _dissolve_degree_two(
    edges: np.ndarray, paths: list[np.ndarray], n: int
) -> tuple[list[tuple[int, int]], list[np.ndarray], np.ndarray]:
    """Join the two paths of every node with exactly two edges (not on a loop edge), in node order:
    the surviving edges, their paths, and which of the `n` nodes were removed."""
    edge_list = [tuple(e) for e in edges]
    alive = [True] * len(edge_list)
    ends: dict[int, list[int]] = {}
    for i, (a, b) in enumerate(edge_list):
        ends.setdefault(int(a), []).append(i)
        if b != a:
            ends.setdefault(int(b), []).append(i)
    removed = np.zeros(n, dtype=bool)
    for node in sorted(ends):
        live = [i for i in ends[node] if alive[i]]
        if len(live) != 2 or any(edge_list[i][0] == edge_list[i][1] for i in live):
            continue
        i, j = live
        pi = paths[i] if edge_list[i][1] == node else paths[i][::-1]
        pj = paths[j] if edge_list[j][0] == node else paths[j][::-1]
        a = edge_list[i][0] if edge_list[i][1] == node else edge_list[i][1]
        b = edge_list[j][1] if edge_list[j][0] == node else edge_list[j][0]
        alive[i] = alive[j] = False
        edge_list.append((a, b))
        paths.append(np.vstack([pi, pj[1:]]))
        alive.append(True)
        new = len(edge_list) - 1
        for x in {int(a), int(b)}:
            ends[x] = [k for k in ends[x] if k not in (i, j)] + [new]
        removed[node] = True
    kept_edges = [e for e, a in zip(edge_list, alive) if a]
    kept_paths = [p for p, a in zip(paths, alive) if a]
    return kept_edges, kept_paths, removed
