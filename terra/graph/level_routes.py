"""Level routes: pieces of the places graph that no level edge joins, joined along a path over
level ground, with a place at each bend.

Why: places stand on the GVD of each terrain (and on gaps in curbs), and their edges are straight
lines. A robot that cannot climb a curb reaches the other side only where the graph has an edge
through a curb cut, along a walk that bends to it, or over ground no terrain class covers (the
ground a forward camera never labelled). The ground layers (terra.graph.ground) know where the
ground is level; where two pieces of the graph meet on it, a path over it links them, and a
place at each bend makes every edge of the path a straight line over level ground, which each
robot's profile judges as it judges any edge (the graph stays the same for every robot).

Rule (`level_routes`):
- Pieces: connected components of the graph restricted to level edges (step at most `max_step`
  metres, rise and fall at most `max_slope` degrees, at most `max_unobserved` metres of unobserved
  ground in one stretch) between places with at least `clearance` metres of room (terra.graph.room:
  the distance to the nearest obstacle, which a hole in the scan beside a place does not bound).
- Level cells: observed cells of the ground layers, not blocked, whose slope is at most
  `max_slope` and whose step is at most `max_step` or unknown. A step is unknown where no ground
  lies within the step layer's reach on either side along both axes: ground far from the sensor,
  scanned in sparse rings. Such a cell is no evidence of a step, and the legs over it are judged
  on the heights across the gaps between rings, as any leg over ground without points. (Read as
  bad, these cells closed the open ground between rings on the LiDAR-only campus.) Bad cells:
  blocked cells, and observed cells whose step or slope is known and above the limit. Cells
  without ground are neither: a curb hidden in a LiDAR shadow reads on the cells beside the
  shadow (the step layer reads across it), which are bad. Nor are cells whose slope is unknown
  (single cells far out, without the neighbours a plane needs) and step is not above the limit:
  read as bad, 120 such cells, within millimetres of the true ground, closed a plaza of the
  LiDAR-only campus; a leg over them is judged on their heights, as every leg is.
- Routes run on blocks of BLOCK x BLOCK cells (the search costs a quarter of what cells would): a
  block is open when it holds a level cell, or lies in a run of at most 2 x HOLE blocks without
  level ground between blocks that do (ground scanned in rings), and no bad cell lies within
  `clearance` metres of its centre (in whole cells: at the defaults, the block and the ring of
  cells around it). From each place, through the open block it stands in (else the
  nearest open block within SNAP metres whose line from it is level), the cheapest 8-connected
  path over open blocks (a diagonal move needs both blocks beside it open) reaches every block
  within `max_length` metres; where two neighbouring blocks are reached from places of different
  pieces, those two places could be joined by a route of that length. The cheapest route per pair
  of pieces (before them, a straight edge from each place to the place of another piece that
  entered its block first), cheapest first, is kept while it joins pieces not yet joined (Kruskal) and every
  straight edge of it is level (terra.graph.ground.edge_geometry); where the route crosses more
  than UNSEEN_CELLS cells without ground in one stretch (measured along the whole route, bends
  included), more than the step layer reads a curb across, it also needs the step hidden there
  (the heights on the stretch's two sides, less what the slope both sides share explains) within
  `max_step`, and the stretch at most `max_unobserved` long (`level_along`).
- A route's blocks become a polyline: from each vertex, the farthest later block whose straight
  line from it crosses only open cells (those of open blocks); each interior vertex is a new
  place (the terrain of its cell, else of the route's nearer end; the ground height there; its
  distance to the nearest bad cell as clearance). A route with a leg that is not level is judged
  again with that leg replaced by the same polyline over its own blocks with legs of at most half
  as many blocks, up to REFINE times (`_refined`): open cells say nothing of a step read across a
  gap on the line, and a straight leg 14 m along a walk scanned in rings read 7.9 cm there, where
  the path's own blocks bend round it on level ground (a piece of five places of the LiDAR-only
  campus was cut off).

Only the neighbourhood of the pieces other than the largest is searched (blocks within
`max_length` of their places): the largest piece is reached there or not at all.

Frames and units: the grid's (terra.graph.grid); positions in the map frame, metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage
from scipy import sparse as sp
from scipy.cluster.hierarchy import DisjointSet
from scipy.sparse.csgraph import connected_components, dijkstra

from terra.graph import raster
from terra.graph.ground import BRIDGE, edge_geometry
from terra.graph.gvd import EIGHT
from terra.graph.scene_graph import EDGE_GEOMETRY_COLUMNS, EDGE_GEOMETRY_REVERSED

if TYPE_CHECKING:
    from terra.graph.grid import TerrainGrid
    from terra.graph.ground import GroundLayers

MAX_UNOBSERVED = 5.0  # metres of unobserved ground a level edge crosses in one stretch (the built-in robots')
BLOCK = 2  # cells per side of a route's block (0.8 m at the default 0.4 m cells)
# Blocks: runs of up to twice this blocks without ground (3.2 m at the defaults), among level ones,
# count as level. Rings of a LiDAR 15-20 m away lay 4.8 m apart on a sidewalk of the LiDAR-only
# campus, 3.2 m without ground between them; the legs over such runs are judged (`_judge`).
HOLE = 2
# Cells without ground a leg of a route crosses in one stretch: the step layer reads a curb across
# a stretch of up to BRIDGE - 1 cells (terra.graph.ground), not across a longer one (a 1.6 m
# stretch in a curb's LiDAR shadow on the simulated campus read level on both sides).
UNSEEN_CELLS = BRIDGE - 1
ROOM = 5.0  # metres: the largest clearance a route's place reads (a passage wider than 10 m is wide)
CANDIDATES = 3  # routes tried per pair of pieces, cheapest first, each between another pair of places
# Times a route with a leg that is not level is judged again with that leg split (`_refined`): a leg
# spans at most half its points after each, so 4 bring a 20 m route's 25 blocks down to 2 a leg.
REFINE = 4
SNAP = 1.2  # metres from a place to the open block it enters by (a place beside a curb or a wall)
_NEIGHBOURS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))  # increasing flat offset


@dataclass(frozen=True)
class RouteRule:
    """What counts as level and how far a route runs (module docstring): max_step metres,
    max_slope degrees, max_unobserved metres, clearance metres, max_length metres."""

    max_step: float
    max_slope: float
    max_unobserved: float
    clearance: float
    max_length: float


@dataclass
class LevelRoutes:
    """New places at the bends of the routes: position (k, 3) metres, terrain (k,), clearance (k,)
    metres; the routes' edges (m, 2) (i < j) between old (index < P) and new (P + i) places, their
    lengths (m,) metres (3-D) and ground geometry (m, 5) (terra.graph.ground.edge_geometry)."""

    position: np.ndarray
    terrain: np.ndarray
    clearance: np.ndarray
    edges: np.ndarray
    length: np.ndarray
    geometry: np.ndarray

    @classmethod
    def none(cls) -> LevelRoutes:
        z = np.zeros(0)
        geometry = np.zeros((0, len(EDGE_GEOMETRY_COLUMNS)), np.float32)
        return cls(np.zeros((0, 3)), z.astype(np.int64), z, np.zeros((0, 2), np.int64), z, geometry)


def level_routes(
    position: np.ndarray,
    terrain: np.ndarray,
    room: np.ndarray,
    edges: np.ndarray,
    geometry: np.ndarray,
    grid: TerrainGrid,
    layers: GroundLayers,
    rule: RouteRule,
) -> LevelRoutes:
    """The routes that join the pieces of the graph of places (`position` (P, 3) metres, `terrain`
    (P,), `room` (P,) metres, terra.graph.room) and `edges` (E, 2) with their ground `geometry` (E, 5)
    (terra.graph.ground.edge_geometry) over the level ground of `layers` (module docstring)."""
    position = np.asarray(position, dtype=np.float64)
    piece = _pieces(len(position), edges, geometry, room, rule)
    blocks = RouteBlocks.of(grid, layers, rule)
    entry = blocks.entries(position, layers, rule)
    source = np.flatnonzero((entry >= 0) & (room >= rule.clearance))
    if len(np.unique(piece[source])) < 2:
        return LevelRoutes.none()
    largest = np.bincount(piece[source]).argmax()
    graph, node, block_of = blocks.graph(entry[source[piece[source] != largest]], rule.max_length)
    entered, first = np.unique(entry[source], return_index=True)  # one place per block: the first
    inside = node[entered] >= 0
    owner_place = np.full(len(block_of), -1, dtype=np.int64)
    owner_place[node[entered[inside]]] = source[first[inside]]
    dist, pred, origin = dijkstra(
        graph, indices=node[entered[inside]], min_only=True, return_predecessors=True, limit=rule.max_length
    )
    owner = np.where(origin >= 0, owner_place[np.maximum(origin, 0)], -1)
    # A place whose block another place of another piece entered first: a straight edge to it.
    holder = source[first][np.searchsorted(entered, entry[source])]
    shared = (holder != source) & (piece[holder] != piece[source])
    routes = [
        Route((int(a), int(b)), np.zeros((0, 3)), np.zeros(0, np.int64), 2)
        for a, b in zip(holder[shared], source[shared])
    ]
    pairs = _candidates(graph, dist, owner, piece, rule.max_length)
    routes += [
        route_through(blocks, layers, position, block_of[_route_nodes(pred, u, v)], (int(owner[u]), int(owner[v])))
        for u, v in pairs.tolist()
    ]
    level = _judged(routes, blocks, position, layers, rule)
    built = RouteBuilder(position, terrain, blocks)
    joined = DisjointSet(range(int(piece.max()) + 1))
    for route, ok in zip(routes, level, strict=True):  # cheapest first, while it joins new pieces
        if ok and joined.merge(int(piece[route.ends[0]]), int(piece[route.ends[1]])):
            built.add(route)
    return built.result()


def _level(geometry: np.ndarray, rule: RouteRule) -> np.ndarray:
    """(E,) bool: edges whose ground geometry (E, 5) is level under `rule` both ways and across."""
    g = np.asarray(geometry, dtype=np.float64).reshape(-1, len(EDGE_GEOMETRY_COLUMNS))
    level = (g[:, 0] <= rule.max_step) & (g[:, 1] <= rule.max_slope) & (g[:, 2] <= rule.max_slope)
    return level & ~(g[:, 3] > rule.max_unobserved) & ~(g[:, 4] > rule.max_slope)


def _pieces(n: int, edges: np.ndarray, geometry: np.ndarray, room: np.ndarray, rule: RouteRule) -> np.ndarray:
    """(P,) piece of every place: components of the graph over level edges between places with room."""
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    level = _level(geometry, rule)
    level &= (room[edges[:, 0]] >= rule.clearance) & (room[edges[:, 1]] >= rule.clearance)
    kept = edges[level]
    graph = sp.coo_matrix((np.ones(len(kept)), (kept[:, 0], kept[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


@dataclass
class RouteBlocks:
    """The blocks routes run on (module docstring): open (h, w) bool blocks of BLOCK x BLOCK cells
    of `grid` (block (R, C) holds cells rows BLOCK R .. BLOCK R + BLOCK - 1, likewise columns);
    bad (H, W) bool cells."""

    grid: TerrainGrid
    open: np.ndarray
    bad: np.ndarray

    @classmethod
    def of(cls, grid: TerrainGrid, layers: GroundLayers, rule: RouteRule) -> RouteBlocks:
        # An unknown step or slope (sparse rings: module docstring) is no evidence of either: a cell
        # whose slope is unknown is not level, and not bad unless its step is.
        slope = layers.slope  # computed from the gradient on each read
        ok = (np.nan_to_num(layers.step, nan=0.0) <= rule.max_step) & (np.nan_to_num(slope, nan=0.0) <= rule.max_slope)
        H, W = grid.shape
        # Whole-grid masks are a byte a cell: built in place, one at a time (a 2 km site has 25 M cells).
        level = np.zeros((H, W), dtype=bool)
        level.ravel()[layers.cells[ok & np.isfinite(slope)]] = True
        level[grid.blocked] = False
        has_level = _per_block(level, False)
        del level
        bad = grid.blocked.copy()
        bad.ravel()[layers.cells[~ok]] = True
        # No bad cell within `margin` cells of an open block's cells: BLOCK / 2 + margin cells >= clearance.
        margin = max(int(np.ceil(rule.clearance / grid.cell_size - BLOCK / 2)), 0)
        clear = ~_per_block(raster.grown(bad, margin), True)
        if HOLE > 0:  # blocks without ground among level ones (padded: a closing erodes from outside too)
            closed = np.asarray(ndimage.binary_closing(np.pad(has_level, HOLE), EIGHT, iterations=HOLE))
            has_level |= closed[HOLE:-HOLE, HOLE:-HOLE]
        return cls(grid, has_level & clear, bad)

    def centres(self, blocks: np.ndarray) -> np.ndarray:
        """(k, 2) map-frame x, y (metres) of the centres of blocks (k,) (flat R w + C)."""
        R, C = np.divmod(np.asarray(blocks, dtype=np.int64), self.open.shape[1])
        g = self.grid
        corner = np.column_stack([C, R]) * BLOCK + BLOCK / 2 + np.asarray(g.offset[::-1], dtype=np.float64)
        return g.origin + corner * g.cell_size

    def entries(self, position: np.ndarray, layers: GroundLayers, rule: RouteRule) -> np.ndarray:
        """(P,) the open block (flat) each place enters the routes by: its own, else the nearest
        within SNAP metres whose straight line from the place is level; -1 where none."""
        h, w = self.open.shape
        rows, cols, inside = self.grid.cell_of(position)
        reach = int(np.ceil(SNAP / (BLOCK * self.grid.cell_size)))
        dr, dc = np.meshgrid(np.arange(-reach, reach + 1), np.arange(-reach, reach + 1), indexing="ij")
        R = np.clip(rows[:, None] // BLOCK + dr.ravel(), 0, h - 1)
        C = np.clip(cols[:, None] // BLOCK + dc.ravel(), 0, w - 1)
        flat = R * w + C
        d = np.linalg.norm(self.centres(flat.ravel()).reshape(*flat.shape, 2) - position[:, None, :2], axis=2)
        own = rows // BLOCK * w + cols // BLOCK
        d = np.where(flat == own[:, None], 0.0, d)  # a place's own block first
        d = np.where(self.open.ravel()[flat] & inside[:, None], d, np.inf)
        best = np.argmin(d, axis=1)
        entry = np.where(d[np.arange(len(d)), best] <= SNAP, flat[np.arange(len(d)), best], -1)
        moved = np.flatnonzero((entry >= 0) & (entry != own))
        if len(moved):
            xy = self.centres(entry[moved])
            ends = np.vstack([position[moved], np.column_stack([xy, ground_height(self.grid, layers, xy)])])
            pairs = np.column_stack([np.arange(len(moved)), np.arange(len(moved)) + len(moved)])
            entry[moved[~_level(edge_geometry(layers, ends, pairs), rule)]] = -1
        return entry

    def graph(self, near: np.ndarray, reach: float) -> tuple[sp.csr_matrix, np.ndarray, np.ndarray]:
        """The 8-connected graph (metres) of the open blocks within `reach` metres (a square) of the
        blocks `near` (k,); node (h w,) of each block (-1: none) and block (n,) of each node."""
        h, w = self.open.shape
        k = int(np.ceil(reach / (BLOCK * self.grid.cell_size)))
        seed = np.zeros(h * w, dtype=bool)
        seed[near] = True
        area = ndimage.maximum_filter(seed.reshape(h, w), size=2 * k + 1) & self.open
        block = np.flatnonzero(area.ravel())
        node = np.full(h * w, -1, dtype=np.int32 if len(block) < 2**31 else np.int64)
        node[block] = np.arange(len(block))
        padded = np.pad(area, 1)
        R, C = np.divmod(block, w)
        neighbours, lengths = [], []
        for dr, dc in _NEIGHBOURS:
            ok = padded[R + 1 + dr, C + 1 + dc]
            if dr and dc:  # a diagonal move needs both blocks beside it open
                ok = ok & padded[R + 1 + dr, C + 1] & padded[R + 1, C + 1 + dc]
            neighbours.append(np.where(ok, node[np.where(ok, block + dr * w + dc, 0)], -1))
            lengths.append(BLOCK * self.grid.cell_size * np.hypot(dr, dc))
        nb = np.column_stack(neighbours)
        valid = nb >= 0
        data = np.broadcast_to(np.asarray(lengths), nb.shape)[valid]
        indptr = np.concatenate([[0], np.cumsum(valid.sum(axis=1))])
        return sp.csr_matrix((data, nb[valid], indptr), shape=(len(block), len(block))), node, block


def _per_block(mask: np.ndarray, pad: bool) -> np.ndarray:
    """(h, w) bool: whether any cell of each BLOCK x BLOCK block of `mask` (H, W) is set (cells
    past the grid's edge count as `pad`)."""
    H, W = mask.shape
    full = np.full((-(-H // BLOCK) * BLOCK, -(-W // BLOCK) * BLOCK), pad)
    full[:H, :W] = mask
    out = np.zeros((full.shape[0] // BLOCK, full.shape[1] // BLOCK), dtype=bool)
    for dr in range(BLOCK):
        for dc in range(BLOCK):
            out |= full[dr::BLOCK, dc::BLOCK]
    return out


def ground_height(grid: TerrainGrid, layers: GroundLayers, xy: np.ndarray) -> np.ndarray:
    """(k,) metres: the ground height at map-frame points `xy` (k, 2): the layers' where the point's
    cell holds ground, else the grid's."""
    at = layers.lookup(xy)
    rows, cols, _ = grid.cell_of(xy)
    height = layers.height_at(np.maximum(at, 0), xy) if len(layers.cells) else np.zeros(len(xy))
    return np.where(at >= 0, height, grid.ground[rows, cols]).astype(np.float64)


def _candidates(
    graph: sp.csr_matrix, dist: np.ndarray, owner: np.ndarray, piece: np.ndarray, max_length: float
) -> np.ndarray:
    """(k, 2) pairs of neighbouring nodes (u, v) reached from places of different pieces: per pair
    of places the cheapest, and of those the CANDIDATES cheapest per pair of pieces (the path's
    length through them at most `max_length` metres; the next is tried where one is not level),
    cheapest first."""
    coo = graph.tocoo()
    u, v, step = coo.row, coo.col, coo.data
    ok = (u < v) & (owner[u] >= 0) & (owner[v] >= 0)
    u, v, step = u[ok], v[ok], step[ok]
    ok = piece[owner[u]] != piece[owner[v]]
    u, v, cost = u[ok], v[ok], dist[u[ok]] + dist[v[ok]] + step[ok]
    keep = cost <= max_length
    u, v, cost = u[keep], v[keep], cost[keep]
    order = np.argsort(cost, kind="stable")
    u, v = u[order], v[order]
    places = np.sort(np.column_stack([owner[u], owner[v]]), axis=1)
    _, first = np.unique(places, axis=0, return_index=True)  # the cheapest meeting of two places
    first = np.sort(first)
    u, v = u[first], v[first]
    pieces = np.sort(np.column_stack([piece[owner[u]], piece[owner[v]]]), axis=1)
    _, group, count = np.unique(pieces, axis=0, return_inverse=True, return_counts=True)
    group = group.ravel()
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    by_group = np.argsort(group, kind="stable")  # cheapest first within each pair of pieces
    rank = np.empty(len(group), dtype=np.int64)
    rank[by_group] = np.arange(len(group)) - start[group[by_group]]
    keep = rank < CANDIDATES
    return np.column_stack([u[keep], v[keep]])


def _route_nodes(pred: np.ndarray, u: int, v: int) -> np.ndarray:
    """(k,) nodes of the route through neighbours u, v: from u's source node to v's."""
    back = [u]
    while pred[back[-1]] >= 0:
        back.append(int(pred[back[-1]]))
    ahead = [v]
    while pred[ahead[-1]] >= 0:
        ahead.append(int(pred[ahead[-1]]))
    return np.asarray(back[::-1] + ahead, dtype=np.int64)


def _lines_open(blocks: RouteBlocks, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(k,) bool: whether each straight line from map-frame point a (2,) to b (k, 2) crosses only
    open blocks (sampled every quarter cell)."""
    g = blocks.grid
    k = int(np.ceil(np.linalg.norm(b - a, axis=1).max(initial=0.0) / (g.cell_size / 4))) + 1
    t = np.linspace(0.0, 1.0, k)[None, :, None]
    point = a + t * (b[:, None, :] - a)  # (k lines, samples, 2)
    rows, cols, inside = g.cell_of(point.reshape(-1, 2))
    h, w = blocks.open.shape
    ok = inside & blocks.open.ravel()[np.minimum(rows // BLOCK, h - 1) * w + np.minimum(cols // BLOCK, w - 1)]
    return np.asarray(ok.reshape(len(b), k).all(axis=1))


@dataclass
class Route:
    """One candidate route between places `ends`: its new places at xyz (k, 3) metres, each the
    route's point `index` (k,) of `points` points (map-frame x, y `path` (points, 2), metres: the
    centres of its blocks, an end place's own position in its block; None for a straight edge),
    and its edges' ground geometry (k + 1, 5)."""

    ends: tuple[int, int]
    xyz: np.ndarray
    index: np.ndarray
    points: int
    geometry: np.ndarray | None = None
    path: np.ndarray | None = None


def route_through(
    blocks: RouteBlocks, layers: GroundLayers, position: np.ndarray, path: np.ndarray, ends: tuple[int, int]
) -> Route:
    """The polyline of a route over blocks `path` (k,) (flat) between places `ends` (module
    docstring): each place stands in its end block, or is linked to that block's centre (SNAP)."""
    g = blocks.grid
    xy = blocks.centres(path)
    rows, cols, _ = g.cell_of(position[list(ends)])
    own = rows // BLOCK * blocks.open.shape[1] + cols // BLOCK == path[[0, -1]]
    for k, end in ((0, 0), (1, -1)):
        if own[k]:
            xy[end] = position[ends[k], :2]
    index = np.asarray([0, *_vertices(blocks, xy, 0, len(xy) - 1, len(xy))], dtype=np.int64)
    index = index[((index > 0) | ~own[0]) & ((index < len(xy) - 1) | ~own[1])]
    return Route(ends, _on_ground(g, layers, xy[index]), index, len(xy), path=xy)


def _vertices(blocks: RouteBlocks, xy: np.ndarray, start: int, stop: int, span: int) -> list[int]:
    """The vertices (indices into the points `xy` (k, 2), map frame, metres) after `start` up to
    `stop` of a polyline over them: from each, the farthest point at most `span` points on whose
    straight line from it crosses only open blocks (the next point where none does)."""
    out, i = [], start
    while i < stop:
        seen = np.flatnonzero(_lines_open(blocks, xy[i], xy[i + 1 : min(stop, i + span) + 1]))
        i = i + 1 + (int(seen[-1]) if len(seen) else 0)
        out.append(i)
    return out


def _on_ground(grid: TerrainGrid, layers: GroundLayers, xy: np.ndarray) -> np.ndarray:
    """(k, 3) the map-frame points `xy` (k, 2) at the ground's height there (metres)."""
    return np.column_stack([xy, ground_height(grid, layers, xy)])


def _judged(
    routes: list[Route], blocks: RouteBlocks, position: np.ndarray, layers: GroundLayers, rule: RouteRule
) -> np.ndarray:
    """(r,) bool: `_judge`'s verdict on each route, a route that is not level judged again split
    finer where a leg is not (`_refined`, which replaces it in `routes`), up to REFINE times."""
    level = _judge(routes, position, layers, rule)
    for _ in range(REFINE):
        retry = {int(i): _refined(blocks, layers, routes[i], rule) for i in np.flatnonzero(~level)}
        finer = {i: route for i, route in retry.items() if route is not None}
        if not finer:
            break
        for i, ok in zip(finer, _judge(list(finer.values()), position, layers, rule), strict=True):
            routes[i], level[i] = finer[i], ok
    return level


def _refined(blocks: RouteBlocks, layers: GroundLayers, route: Route, rule: RouteRule) -> Route | None:
    """`route` (judged) with each leg that is not level and spans two or more of its points
    replaced by the polyline over those points with legs of at most half as many (`_vertices`);
    None where it has no such leg (a straight edge, or legs between neighbouring blocks)."""
    if route.path is None or route.geometry is None:
        return None
    vertex = [0, *route.index.tolist(), route.points - 1]  # the ends' own points: 0 and points - 1
    bad = ~_level(route.geometry, rule)
    out = [vertex[0]]
    for k, (a, b) in enumerate(zip(vertex[:-1], vertex[1:], strict=True)):
        out += _vertices(blocks, route.path, a, b, (b - a + 1) // 2) if bad[k] and b - a >= 2 else [b]
    if out == vertex:
        return None
    index = np.asarray(out[1:-1], dtype=np.int64)
    return Route(route.ends, _on_ground(blocks.grid, layers, route.path[index]), index, route.points, path=route.path)


def _judge(routes: list[Route], position: np.ndarray, layers: GroundLayers, rule: RouteRule) -> np.ndarray:
    """(r,) bool: whether every edge of each route is level, and the route as a whole level across
    its stretches without ground (`level_along`); sets each route's edge geometry."""
    points, pairs, at = [], [], 0
    for r in routes:
        chain = np.vstack([position[r.ends[0]], r.xyz, position[r.ends[1]]])
        points.append(chain)
        pairs.append(at + np.column_stack([np.arange(len(chain) - 1), np.arange(1, len(chain))]))
        at += len(chain)
    if not routes:
        return np.zeros(0, dtype=bool)
    geometry = edge_geometry(layers, np.vstack(points), np.vstack(pairs))
    split = np.cumsum([len(r.xyz) + 1 for r in routes])[:-1]
    level = []
    for r, g, chain in zip(routes, np.split(geometry, split), points, strict=True):
        r.geometry = g
        level.append(bool(_level(g, rule).all()) and level_along(layers, chain[:, :2], rule))
    return np.asarray(level, dtype=bool)


def level_along(layers: GroundLayers, chain: np.ndarray, rule: RouteRule) -> bool:
    """Whether the ground along a polyline `chain` (k, 2) (map frame, metres; sampled every half
    cell) is level across each stretch without ground longer than UNSEEN_CELLS cells: the step it
    hides there, the height difference across it less what the slope both its sides share
    explains (`_shared_rise`), is at most `rule.max_step`, and it is at most
    `rule.max_unobserved` long. Across such a stretch the step layer reads nothing. The stretch is
    measured along the whole polyline: one without ground around a bend is one stretch (a bend in
    a run of blocks without ground left a leg without any ground, which alone could not be
    judged), and False where the polyline holds fewer than two samples with ground."""
    spacing = layers.cell_size / 2
    legs = np.diff(chain, axis=0)
    counts = np.maximum(np.ceil(np.linalg.norm(legs, axis=1) / spacing).astype(np.int64), 1)
    leg = np.repeat(np.arange(len(legs)), counts)
    t = (np.arange(len(leg)) - np.repeat(np.cumsum(counts) - counts, counts)) / counts[leg]
    point = np.vstack([chain[leg] + t[:, None] * legs[leg], chain[-1:]])
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(point, axis=0), axis=1))])
    at = layers.lookup(point)
    known = np.flatnonzero(at >= 0)
    if len(known) < 2:
        return False
    gap = np.diff(along[known])
    across = np.flatnonzero(gap > UNSEEN_CELLS * layers.cell_size + 1e-6)
    if (gap[across] > rule.max_unobserved + spacing).any():
        return False
    before, after = known[across], known[across + 1]
    height = layers.height_at(at[known], point[known])
    rise = height[across + 1] - height[across]
    hidden = np.abs(rise - _shared_rise(layers, at[before], at[after], point[after] - point[before]))
    return bool((hidden <= rule.max_step).all())


def _shared_rise(layers: GroundLayers, before: np.ndarray, after: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """(m,) metres: the rise over `shift` (m, 2) metres (map frame) that the planes of the observed
    cells `before` and `after` (m,) on a stretch's two sides agree on: the gentler of their two
    where both climb or both fall, else 0 (unknown planes are level). Why: across 2.4 m without
    ground a walk falling 0.9 degrees differed by 4.5 cm with its sides' noise, which read as a
    step refused the only route along it; a ramp before a stretch (4 degrees, 11 cm of a curb
    hidden in it) explains nothing where the level top beyond it does not climb with it. From the
    planes and the stretch's displacement, not a slope along the route: around a bend the route
    turns and its sides' slopes along it no longer measure the same ground."""
    first = (np.nan_to_num(layers.fitted_gradient(before)) * shift).sum(axis=1)
    second = (np.nan_to_num(layers.fitted_gradient(after)) * shift).sum(axis=1)
    gentler = np.where(np.abs(first) < np.abs(second), first, second)
    return np.where(first * second > 0, gentler, 0.0)


class RouteBuilder:
    """Collects the places and edges of accepted routes (module docstring)."""

    def __init__(self, position: np.ndarray, terrain: np.ndarray, blocks: RouteBlocks) -> None:
        self.position, self.terrain, self.blocks = position, terrain, blocks
        self.parts: list[tuple[np.ndarray, ...]] = []
        self.count = 0

    def add(self, route: Route) -> None:
        """Appends a judged route's places (terrain of their cell, else of the route's nearer end;
        their room as clearance) and the chain of edges along it."""
        g = self.blocks.grid
        n = len(self.position) + self.count
        chain = np.concatenate([[route.ends[0]], n + np.arange(len(route.xyz)), [route.ends[1]]])
        rows, cols, _ = g.cell_of(route.xyz)
        label = g.label[rows, cols].astype(np.int64)
        nearer = np.where(route.index < route.points / 2, self.terrain[route.ends[0]], self.terrain[route.ends[1]])
        edges = np.column_stack([chain[:-1], chain[1:]])
        assert route.geometry is not None
        self.parts.append(
            (route.xyz, np.where(label >= 0, label, nearer), self._room(route.xyz), edges, route.geometry)
        )
        self.count += len(route.xyz)

    def _room(self, xyz: np.ndarray) -> np.ndarray:
        """(k,) metres from each point to the nearest bad cell's centre, less half a cell, at most ROOM."""
        g = self.blocks.grid
        k = int(np.ceil(ROOM / g.cell_size))
        rows, cols, _ = g.cell_of(xyz)
        out = np.full(len(xyz), ROOM)
        for i, (r, c) in enumerate(zip(rows, cols, strict=True)):
            r0, c0 = max(r - k, 0), max(c - k, 0)
            found = np.argwhere(self.blocks.bad[r0 : r + k + 1, c0 : c + k + 1])
            if len(found):
                d = np.hypot(found[:, 0] + r0 - r, found[:, 1] + c0 - c).min()
                out[i] = min(ROOM, d * g.cell_size - g.cell_size / 2)
        return out

    def result(self) -> LevelRoutes:
        if not self.parts:
            return LevelRoutes.none()
        xyz, terrain, room, edges, geometry = (np.concatenate([p[k] for p in self.parts]) for k in range(5))
        everything = np.vstack([self.position, xyz])
        length = np.linalg.norm(everything[edges[:, 0]] - everything[edges[:, 1]], axis=1)
        swap = edges[:, 0] > edges[:, 1]
        geometry = geometry.copy()
        geometry[swap] = geometry[swap][:, EDGE_GEOMETRY_REVERSED]  # rise and fall read the other way
        return LevelRoutes(xyz, terrain.astype(np.int64), room, np.sort(edges, axis=1), length, geometry)
