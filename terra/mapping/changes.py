"""What changed between two sessions of one map (issue 26): objects added, removed and moved, and terrain
that changed class, judged only where both sessions observed (not seen is not gone).

It reads the fusion state a joined map keeps: LiDAR returns per point and session (`map/state/session_hits`)
and terrain votes per session (`map/state/session_votes`), beside the object observations of every point
(`map/counts_*`). Lengths in metres, positions in the map frame.

Objects: the map's object points (more object observations than terrain votes), and the points no camera
labelled that stand `standing` metres above the ground (a car only the LiDAR saw: without them its
camera-labelled part alone is a partial car, off centre), that session s returned from are grouped into
clusters (points within `link` metres, at least `min_points`), per session, each with its footprint (the
`cell` x-y cells of its points and between them along rows and columns). A cluster of the first session is
removed when the second session's returns show its place empty, judged from points, not from matching
clusters (an object seen from another side makes another cluster around the same volume):
- the second session returned from at least `observed_fraction` of the footprint's cells (its rays got
  there: what it did not see has not changed);
- the cluster is at least `min_width` wide each way (not a sliver: a car's face seen apart from its body),
  or it is a thin wall of its own, a fence: at least `thin_length` long, its top `thin_height` above the
  ground, and the other session saw open ground on both sides of it (within `thin_side`; a car's side seen
  apart from its body has the car on one side);
- the object stands on the ground (its bottom at most `max_float` above the terrain points around it, and
  some there: not a roof's edge), and it has at least `min_points` returns in its volume (the footprint
  grown by a cell, from `lift` above the ground to its top; a crosswalk's paint has none);
- of the second session's returns around the footprint, a share at most `present_share` times the first
  session's share lies in that volume (shares, so a session that passed farther off, with fewer returns,
  still counts as seeing what stands); or, where the second session looked as closely (`close_share` as
  many cells), it returned only from below the volume in `emptied_share` of the footprint cells the object
  filled (an object moved by less than its length, its new place covering part of the old one).
An added cluster of the second session, likewise the other way round. Two removed (or added) clusters of
one bank entry within `piece_gap` that together fit `piece_extent` are pieces of one object. A removed and
an added cluster with the same most-observed bank entry within `move_radius` are one object moved (greedy,
nearest first).

Terrain: per `terrain_cell` cell, the class with the most votes of each session, over the points both
sessions voted on at least `min_votes` times; cells whose class differs, each with at least `clear_share` of
its session's votes (not a border between two terrains), in patches of at least `min_patch` cells of one pair
(a lone cell is a border's wobble), are changes, summed as area per (before, after) pair. Blocked ground:
the `terrain_cell` cells of an object judged added (or moved there) that the first session saw as traversable
ground (a class not in `untraversable`, read from the session's terrain votes nearest the object's points,
`clear_share` of them agreeing) are "class -> blocked" (a fence across a walkway: "sidewalk -> blocked"), and
those of an object judged removed (or moved away) that the second session saw as such ground "blocked ->
class"; a cell blocked in both sessions is neither. Objects, not cells, decide it: only what both sessions
observed of an object can have changed. Patches as above, or a line of cells at least `thin_length` long (a
fence's line is one cell wide).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

from terra.bundle import Bundle
from terra.errors import TerraError
from terra.mapping.chunks import chunk_folder, is_chunked, stored_rows
from terra.npy import ArraySpec

BLOCKED = "blocked"
"""The terrain name of ground an obstacle stands on, in "sidewalk -> blocked" (a fence put up across a
walkway) and "blocked -> asphalt" (a car gone from its stall)."""


@dataclass(frozen=True)
class ChangeSettings:
    """Thresholds of change detection (metres unless said): see the module docstring."""

    link: float = 0.6
    min_points: int = 12
    cell: float = 0.5
    observed_fraction: float = 0.5
    present_share: float = 0.3
    lift: float = 0.25
    max_float: float = 1.0
    close_share: float = 0.8
    emptied_share: float = 0.5
    min_width: float = 0.3
    thin_length: float = 2.0
    thin_height: float = 0.8
    thin_side: float = 1.0
    standing: tuple[float, float] = (0.3, 2.5)
    piece_gap: float = 2.5
    piece_extent: tuple[float, float] = (6.0, 3.0)
    move_radius: float = 10.0
    terrain_cell: float = 1.0
    min_votes: int = 2
    clear_share: float = 0.75
    min_patch: int = 3
    untraversable: tuple[str, ...] = ("water",)


@dataclass(frozen=True)
class ObjectChange:
    """An object `added`, `removed` or `moved`: its most-observed bank entry (-1, null in JSON, for an object
    only the LiDAR saw), its centre before and after
    (x, y, z metres, map frame; None where it was not there), the distance moved (x, y metres), its size,
    the class name of its entry (None where the map cannot name it) and its region (None without a graph)."""

    change: str
    entry: int
    before: tuple[float, float, float] | None
    after: tuple[float, float, float] | None
    distance: float | None
    size: tuple[float, float, float]
    name: str | None = None
    region: str | None = None

    def to_json(self) -> dict[str, Any]:
        def rounded(v):
            return None if v is None else [round(float(x), 3) for x in v]

        return {
            "change": self.change,
            "name": self.name,
            "entry": None if self.entry < 0 else self.entry,
            "before": rounded(self.before),
            "after": rounded(self.after),
            "distance": None if self.distance is None else round(self.distance, 3),
            "size": rounded(self.size),
            "region": self.region,
        }


@dataclass(frozen=True)
class TerrainChange:
    """Terrain of class `before` in the first session and `after` in the second, over `area_m2` square metres."""

    before: str
    after: str
    area_m2: float

    def to_json(self) -> dict[str, Any]:
        return {"before": self.before, "after": self.after, "area_m2": round(self.area_m2, 3)}


@dataclass
class RegionChanges:
    """The changes in one region: objects added, removed and moved (a move counts where the object now is)
    and terrain area changed (m²) per "before -> after" pair."""

    region: str
    added: int = 0
    removed: int = 0
    moved: int = 0
    terrain_m2: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "region": self.region,
            "added": self.added,
            "removed": self.removed,
            "moved": self.moved,
            "terrain_m2": {pair: round(area, 3) for pair, area in sorted(self.terrain_m2.items())},
        }


@dataclass
class ChangesResult:
    """`terra changes`: the bundle, the two sessions compared, the area both observed (m², x-y cells of
    `ChangeSettings.cell`), object changes, terrain changes (largest area first), the changes per region of
    the scene graph (None without one), and the changed terrain cells for the figure: their centres
    `terrain_cells` (M, 2) metres, map frame, each `terrain_cell_area` m², and their "before -> after"
    pairs."""

    bundle: Path
    first: int
    second: int
    observed_area_m2: float
    objects: list[ObjectChange] = field(default_factory=list)
    terrain: list[TerrainChange] = field(default_factory=list)
    regions: list[RegionChanges] | None = None
    terrain_cells: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    terrain_pairs: list[str] = field(default_factory=list)
    terrain_cell_area: float = 1.0

    def to_json(self) -> dict[str, Any]:
        counts = {kind: sum(o.change == kind for o in self.objects) for kind in ("added", "removed", "moved")}
        return {
            "bundle": str(self.bundle),
            "between": [self.first, self.second],
            "observed_area_m2": round(self.observed_area_m2, 1),
            "counts": counts,
            "objects": [o.to_json() for o in self.objects],
            "terrain": [t.to_json() for t in self.terrain],
            "regions": None if self.regions is None else [r.to_json() for r in self.regions],
        }


@dataclass
class _Sessions:
    """The arrays change detection reads from a joined map."""

    points: np.ndarray  # (N, 3) float64 metres
    hits: np.ndarray  # (N, S) LiDAR returns
    votes: np.ndarray  # (S, N, T) terrain votes
    counts: sp.csr_matrix  # (N, K) object observations
    terrain_classes: list[str]


@dataclass
class _Cluster:
    rows: np.ndarray
    centre: np.ndarray
    size: np.ndarray
    entry: int
    cells: np.ndarray  # sorted unique x-y cell keys of its footprint
    bottom: float  # metres, its lowest and highest point
    top: float


def detect_changes(path: Path, first: int, second: int, settings: ChangeSettings | None = None) -> ChangesResult:
    """Changes from session `first` to session `second` (1-based) of the joined map in bundle `path`."""
    settings = settings or ChangeSettings()
    bundle = Bundle(path)
    data = _load(bundle, first, second)
    a, b = first - 1, second - 1
    seen_a = _cells(data.points[data.hits[:, a] > 0], settings.cell)
    seen_b = _cells(data.points[data.hits[:, b] > 0], settings.cell)
    observed = np.intersect1d(seen_a, seen_b).size * settings.cell**2
    moved, removed, added = _changed_clusters(data, a, b, settings)
    objects = _as_changes(moved, removed, added)
    freed = removed + [old for old, _ in moved]
    blocked = added + [new for _, new in moved]
    terrain, cells, pairs = _terrain_changes(data, a, b, settings, (freed, blocked))
    result = ChangesResult(Path(path), first, second, float(observed), objects, terrain)
    result.terrain_cells, result.terrain_pairs, result.terrain_cell_area = cells, pairs, settings.terrain_cell**2
    return result


def _flat_rows(bundle: Bundle, n: int, k: int, nnz: int, sessions: int) -> tuple[np.ndarray, np.ndarray, sp.csr_matrix]:
    """(points, terrain votes per session, counts) of the flat layout."""
    t = len(bundle.model.terrain_classes)
    unsigned = ("uint8", "uint16", "uint32", "uint64")
    votes = bundle.array("map/state/session_votes", ArraySpec(unsigned, (sessions, n, t)))
    points = bundle.array("map/points", ArraySpec(("float32",), (n, 3), finite=True))
    indptr = bundle.array("map/counts_indptr", ArraySpec(("int64",), (n + 1,)))
    indices = bundle.array("map/counts_indices", ArraySpec(("int32",), (nnz,)))
    values = bundle.array("map/counts_data", ArraySpec(unsigned, (nnz,)))
    return points, votes, sp.csr_matrix((np.asarray(values, np.int64), indices, indptr), shape=(n, k))


def _load(bundle: Bundle, first: int, second: int) -> _Sessions:
    """The joined map's arrays, after checking both sessions exist (TerraError naming the bundle)."""
    info = bundle.model.components.map
    chunked = is_chunked(bundle) and bool(info and info.points) and bundle.has(f"{chunk_folder(0)}/session_hits")
    flat = bundle.has("map/state/session_hits") and bundle.has("map/state/session_votes")
    if info is None or not (chunked or flat):
        raise TerraError(f"{bundle.path}: the map has one session; join another with `terra map SESSION --into`")
    n, k, nnz = int(info.points or 0), int(info.bank or 0), int(info.observations or 0)
    if chunked:  # a live version (terra/mapping/chunks.py)
        names = ("points", "session_hits", "session_votes", "counts")
        rows = stored_rows(bundle, names, n, k, len(bundle.model.terrain_classes))
        hits, points, votes = rows["session_hits"], rows["points"], rows["session_votes"]
        counts = sp.csr_matrix(rows["counts"])
    else:
        hits = bundle.array("map/state/session_hits", ArraySpec(("uint8", "uint16", "uint32", "uint64"), (n, None)))
        points, votes, counts = _flat_rows(bundle, n, k, nnz, int(hits.shape[1]))
    sessions = int(hits.shape[1])
    for value in (first, second):
        if not 1 <= value <= sessions:
            raise TerraError(f"--between {first} {second}: the map has sessions 1 to {sessions}")
    if first == second:
        raise TerraError(f"--between {first} {second}: give two different sessions")
    if votes.shape[0] != sessions:
        raise TerraError(f"{bundle.path}/map: terrain votes of {votes.shape[0]} sessions, expected {sessions}")
    return _Sessions(
        np.asarray(points, np.float64),
        np.asarray(hits, np.int64),
        np.asarray(votes, np.int64),
        counts,
        list(bundle.model.terrain_classes),
    )


def _cells(points: np.ndarray, cell: float) -> np.ndarray:
    """Sorted unique x-y cell keys of `points` (N, >= 2) metres."""
    return np.unique(_keys(np.floor(points[:, :2] / cell).astype(np.int64)))


def _keys(ij: np.ndarray) -> np.ndarray:
    """One int64 key per x-y cell index pair (M, 2); the low half holds j as a signed 32-bit number."""
    return (ij[:, 0] << 32) ^ (ij[:, 1] & 0xFFFFFFFF)


def _unkey(keys: np.ndarray) -> np.ndarray:
    """The (M, 2) cell index pairs of `keys`."""
    j = (keys & 0xFFFFFFFF).astype(np.int64)
    return np.stack([keys >> 32, np.where(j >= 1 << 31, j - (1 << 32), j)], axis=1)


class _CellIndex:
    """The rows of some map points by x-y cell, to read which of them lie in a footprint."""

    def __init__(self, points: np.ndarray, rows: np.ndarray, cell: float):
        keys = _keys(np.floor(points[rows, :2] / cell).astype(np.int64))
        order = np.argsort(keys, kind="stable")
        self.keys, self.rows = keys[order], rows[order]

    def has(self, cells: np.ndarray) -> np.ndarray:
        """(M,) whether any point lies in each of `cells` (a binary search: the keys are sorted)."""
        at = np.minimum(np.searchsorted(self.keys, cells), max(self.keys.size - 1, 0))
        return self.keys[at] == cells if self.keys.size else np.zeros(cells.size, dtype=bool)

    def rows_in(self, cells: np.ndarray) -> np.ndarray:
        """Rows of the points in any of `cells` (sorted unique keys)."""
        left = np.searchsorted(self.keys, cells, side="left")
        right = np.searchsorted(self.keys, cells, side="right")
        lengths = right - left
        if not lengths.sum():
            return np.zeros(0, np.int64)
        starts = np.repeat(left - np.cumsum(lengths) + lengths, lengths)
        return self.rows[starts + np.arange(int(lengths.sum()))]


def _clusters(data: _Sessions, rows: np.ndarray, settings: ChangeSettings) -> list[_Cluster]:
    """Object clusters of the points `rows` (points within `link` metres joined, at least `min_points`)."""
    if rows.size == 0:
        return []
    xyz = data.points[rows]
    pairs = cKDTree(xyz).query_pairs(settings.link, output_type="ndarray")
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(rows.size, rows.size))
    _, label = connected_components(graph, directed=False)
    out = []
    for members in np.split(np.argsort(label, kind="stable"), np.cumsum(np.bincount(label))[:-1]):
        if members.size < settings.min_points:
            continue
        mine = rows[members]
        observed = np.asarray(data.counts[mine].sum(axis=0)).ravel()
        entry = int(observed.argmax()) if observed.any() else -1  # -1: seen by LiDAR only
        low, high = xyz[members].min(axis=0), xyz[members].max(axis=0)
        footprint = _footprint(xyz[members], settings.cell)
        out.append(
            _Cluster(mine, xyz[members].mean(axis=0), high - low, entry, footprint, float(low[2]), float(high[2]))
        )
    return out


def _footprint(xyz: np.ndarray, cell: float) -> np.ndarray:
    """Sorted keys of the x-y cells where an object stood: its points' cells and the cells between them
    along both the rows and the columns of the grid (a car's LiDAR points cover its roof and sides, not the
    ground under it). Spans, not a convex hull: exact on a grid and cheap for a building-sized cluster."""
    cells = _cells(xyz, cell)
    ij = _unkey(cells)
    low = ij.min(axis=0)
    local = ij - low
    shape = local.max(axis=0) + 1
    first = [np.full(shape[k], np.iinfo(np.int64).max) for k in (0, 1)]
    last = [np.full(shape[k], -1) for k in (0, 1)]
    for k in (0, 1):  # per row (k = 0) and per column (k = 1): the first and last cell taken
        np.minimum.at(first[k], local[:, k], local[:, 1 - k])
        np.maximum.at(last[k], local[:, k], local[:, 1 - k])
    gi, gj = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    inside = (gj >= first[0][gi]) & (gj <= last[0][gi]) & (gi >= first[1][gj]) & (gi <= last[1][gj])
    grid = np.stack([gi[inside], gj[inside]], axis=1) + low
    return np.union1d(cells, _keys(grid))


def _dilate(cells: np.ndarray) -> np.ndarray:
    """`cells` and their eight neighbours (sorted unique keys)."""
    ij = _unkey(cells)
    steps = np.array([(di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1)])
    return np.unique(_keys((ij[:, None, :] + steps[None]).reshape(-1, 2)))


def _standing_unlabelled(data: _Sessions, terrain_rows: np.ndarray, s: ChangeSettings) -> np.ndarray:
    """(N,) the points no camera labelled (no object observation, no terrain vote) that stand `standing`
    metres (low, high) above the lowest terrain point of their `terrain_cell` cell: an object only the
    LiDAR saw (a car beside the route, out of the cameras' view), at the height of cars and benches."""
    unlabelled = (np.asarray(data.counts.sum(axis=1)).ravel() == 0) & (data.votes.sum(axis=(0, 2)) == 0)
    out = np.zeros(len(data.points), dtype=bool)
    if not terrain_rows.any() or not unlabelled.any():
        return out
    keys = _keys(np.floor(data.points[:, :2] / s.terrain_cell).astype(np.int64))
    ground_keys, inverse = np.unique(keys[terrain_rows], return_inverse=True)
    lowest = np.full(ground_keys.size, np.inf)
    np.minimum.at(lowest, inverse.ravel(), data.points[terrain_rows, 2])
    rows = np.flatnonzero(unlabelled)
    at = np.clip(np.searchsorted(ground_keys, keys[rows]), 0, ground_keys.size - 1)
    known = ground_keys[at] == keys[rows]
    height = data.points[rows, 2] - np.where(known, lowest[at], np.inf)
    out[rows] = known & (height >= s.standing[0]) & (height <= s.standing[1])
    return out


def _object_changes(data: _Sessions, a: int, b: int, settings: ChangeSettings) -> list[ObjectChange]:
    """Removed, added and moved objects from session a to session b (0-based columns)."""
    return _as_changes(*_changed_clusters(data, a, b, settings))


def _changed_clusters(
    data: _Sessions, a: int, b: int, settings: ChangeSettings
) -> tuple[list[tuple[_Cluster, _Cluster]], list[_Cluster], list[_Cluster]]:
    """The object clusters that changed from session a to session b (0-based columns): pairs (before, after)
    of moved ones, removed ones (session a's points) and added ones (session b's)."""
    object_rows = np.asarray(data.counts.sum(axis=1)).ravel() > data.votes.sum(axis=(0, 2))
    terrain_rows = data.votes.sum(axis=(0, 2)) > np.asarray(data.counts.sum(axis=1)).ravel()
    ground = _CellIndex(data.points, np.flatnonzero(terrain_rows), settings.cell)
    index = [_CellIndex(data.points, np.flatnonzero(data.hits[:, k] > 0), settings.cell) for k in (a, b)]
    candidates = object_rows | _standing_unlabelled(data, terrain_rows, settings)
    before = _clusters(data, np.flatnonzero(candidates & (data.hits[:, a] > 0)), settings)
    after = _clusters(data, np.flatnonzero(candidates & (data.hits[:, b] > 0)), settings)
    removed = [c for c in before if _gone(c, data.points, index[0], index[1], ground, settings)]
    added = [c for c in after if _gone(c, data.points, index[1], index[0], ground, settings)]
    removed, added = _join_pieces(removed, data.points, settings), _join_pieces(added, data.points, settings)
    return _pair_moves(removed, added, settings)


def _as_changes(
    moved: list[tuple[_Cluster, _Cluster]], removed: list[_Cluster], added: list[_Cluster]
) -> list[ObjectChange]:
    """The object changes of changed clusters, in (kind, place) order."""
    changes = [_change("moved", old, new) for old, new in moved]
    changes += [_change("removed", c, None) for c in removed] + [_change("added", None, c) for c in added]
    return sorted(changes, key=lambda c: (c.change, c.before or c.after or ()))


def _gone(
    cluster: _Cluster, points: np.ndarray, own: _CellIndex, other: _CellIndex, ground: _CellIndex, s: ChangeSettings
) -> bool:
    """Whether the other session looked where `cluster` stood and found it empty: it returned from most of
    the footprint's cells (its rays got there: a place it never saw has not changed), and of its returns
    around the footprint (grown by a cell) at most `present_share` times as large a share lie in the
    object's volume (from `lift` above the ground to the object's top) as of the cluster's own session's.
    Shares of each session's own returns, so a session that passed far off (fewer returns) still counts as
    seeing what stands; points, not cluster shapes, so an object seen from another side is still there."""
    if other.has(cluster.cells).mean() < s.observed_fraction:
        return False  # not seen there
    around = _dilate(cluster.cells)
    floor = points[ground.rows_in(around), 2]
    # No ground around it, or ground well below it: a part of something taller (a roof's edge), not a
    # thing that stands on its own
    if floor.size == 0 or cluster.bottom > float(np.median(floor)) + s.max_float:
        return False
    base = float(np.median(floor))
    if min(cluster.size[:2]) < s.min_width and not _wall_of_its_own(cluster, points, other, base, s):
        return False  # a sliver (a car's face seen edge on, apart from its body), not a fence
    low, high = max(base + s.lift, cluster.bottom), cluster.top + s.lift
    z_own, z_other = points[own.rows_in(around), 2], points[other.rows_in(around), 2]
    in_own = int(np.count_nonzero((z_own >= low) & (z_own <= high)))
    in_other = int(np.count_nonzero((z_other >= low) & (z_other <= high)))
    if in_own < s.min_points or z_other.size < s.min_points:  # flat (a crosswalk) or barely seen: not judged
        return False
    if in_other / z_other.size <= s.present_share * in_own / z_own.size:
        return True
    return _emptied(cluster, points, own, other, (low, high), s)


def _wall_of_its_own(cluster: _Cluster, points: np.ndarray, other: _CellIndex, base: float, s: ChangeSettings) -> bool:
    """Whether a sliver `cluster` (under `min_width` across, so nearly along a grid axis) is a thin wall
    standing on its own, a fence: at least `thin_length` long, its top `thin_height` above the ground `base`
    (z, metres), and the other session returned from the ground (below `lift` over `base`) in at least
    `observed_fraction` of the `cell` cells within `thin_side` metres of it on each side. A car's side seen
    apart from its body is as long and tall, but on one side of it stands the car: no ground there."""
    if max(cluster.size[:2]) < s.thin_length or cluster.top - base < s.thin_height:
        return False
    across = np.eye(2, dtype=np.int64)[int(np.argmin(cluster.size[:2]))]
    ij = _unkey(cluster.cells)
    steps = np.arange(1, int(np.ceil(s.thin_side / s.cell)) + 1)
    for sign in (-1, 1):
        side = np.setdiff1d(_keys((ij[None] + sign * steps[:, None, None] * across).reshape(-1, 2)), cluster.cells)
        rows = other.rows_in(side)
        low = points[rows, 2] <= base + s.lift
        ground = np.unique(_keys(np.floor(points[rows[low], :2] / s.cell).astype(np.int64)))
        if ground.size < s.observed_fraction * side.size:
            return False
    return True


def _emptied(
    cluster: _Cluster,
    points: np.ndarray,
    own: _CellIndex,
    other: _CellIndex,
    volume: tuple[float, float],
    s: ChangeSettings,
) -> bool:
    """Whether the other session, looking as closely (at least `close_share` as many returns around the
    footprint), returned only from below the object's volume `volume` (z from, to) in at least
    `emptied_share` of the footprint cells where the own session returned from inside it: an object moved
    by less than its length, whose new place still covers part of its old one."""

    def occupied(index: _CellIndex) -> tuple[np.ndarray, np.ndarray]:
        rows = index.rows_in(cluster.cells)
        key = _keys(np.floor(points[rows, :2] / s.cell).astype(np.int64))
        z = points[rows, 2]
        return np.unique(key), np.unique(key[(z >= volume[0]) & (z <= volume[1])])

    seen_own, full_own = occupied(own)
    seen_other, full_other = occupied(other)
    if seen_other.size < s.close_share * seen_own.size or full_own.size < 4:
        return False
    looked = np.intersect1d(full_own, seen_other, assume_unique=True)
    empty = np.setdiff1d(looked, full_other, assume_unique=True)
    return empty.size >= s.emptied_share * full_own.size


def _join_pieces(clusters: list[_Cluster], points: np.ndarray, s: ChangeSettings) -> list[_Cluster]:
    """`clusters` (all gone) with pieces of one object joined: two of one bank entry whose footprints lie
    within `piece_gap` metres and whose points together still fit an object (`piece_extent`: at most that
    long and wide along their main axes), as a car seen in two parts, its middle hidden. Two cars parked
    side by side or end to end together are wider or longer than that."""
    out = list(clusters)
    joined = True
    while joined:
        joined = False
        for i, j in combinations(range(len(out)), 2):
            a, b = out[i], out[j]
            if a.entry != b.entry:
                continue
            gap = cKDTree(_unkey(a.cells) * s.cell).query(_unkey(b.cells) * s.cell)[0]
            rows = np.concatenate([a.rows, b.rows])
            if np.min(gap) > s.piece_gap or not _fits(points[rows, :2], s.piece_extent):
                continue
            xyz = points[rows]
            low, high = xyz.min(axis=0), xyz.max(axis=0)
            cells = np.union1d(a.cells, b.cells)
            out[i] = _Cluster(rows, xyz.mean(axis=0), high - low, a.entry, cells, float(low[2]), float(high[2]))
            del out[j]
            joined = True
            break
    return out


def _fits(xy: np.ndarray, extent: tuple[float, float]) -> bool:
    """Whether points `xy` (M, 2) metres span at most `extent` (length, width) along their principal axes."""
    centred = xy - xy.mean(axis=0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    span = np.ptp(centred @ axes.T, axis=0)
    return bool(span[0] <= extent[0] and span[1] <= extent[1])


def _pair_moves(
    removed: list[_Cluster], added: list[_Cluster], settings: ChangeSettings
) -> tuple[list[tuple[_Cluster, _Cluster]], list[_Cluster], list[_Cluster]]:
    """Removed and added clusters of one bank entry within `move_radius`, nearest pairs first."""
    pairs = sorted(
        (float(np.linalg.norm((new.centre - old.centre)[:2])), i, j)
        for i, old in enumerate(removed)
        for j, new in enumerate(added)
        if old.entry == new.entry
    )
    used_old, used_new, moved = set(), set(), []
    for distance, i, j in pairs:
        if distance <= settings.move_radius and i not in used_old and j not in used_new:
            used_old.add(i)
            used_new.add(j)
            moved.append((removed[i], added[j]))
    rest_old = [c for i, c in enumerate(removed) if i not in used_old]
    return moved, rest_old, [c for j, c in enumerate(added) if j not in used_new]


def _change(kind: str, old: _Cluster | None, new: _Cluster | None) -> ObjectChange:
    def point(c: _Cluster | None) -> tuple[float, float, float] | None:
        return None if c is None else (float(c.centre[0]), float(c.centre[1]), float(c.centre[2]))

    some = old if old is not None else new
    assert some is not None
    distance = None if old is None or new is None else float(np.linalg.norm((new.centre - old.centre)[:2]))
    size = (float(some.size[0]), float(some.size[1]), float(some.size[2]))
    return ObjectChange(kind, some.entry, point(old), point(new), distance, size)


def _terrain_changes(
    data: _Sessions, a: int, b: int, settings: ChangeSettings, obstacles: tuple[list[_Cluster], list[_Cluster]]
) -> tuple[list[TerrainChange], np.ndarray, list[str]]:
    """Area per (before, after) terrain pair: cells both sessions voted on whose class changed, and cells an
    obstacle gone (`obstacles[0]`, session a's clusters) freed or an obstacle come (`obstacles[1]`, session
    b's) blocked; the changed cells' centres (M, 2) metres and their "before -> after" pairs."""
    names = [*data.terrain_classes, BLOCKED]
    n = len(names)
    ij, before, after = _class_changes(data, a, b, settings)
    keep = _patches(ij, before * n + after, settings.min_patch)
    ij, before, after = ij[keep], before[keep], after[keep]
    bij, bbefore, bafter = _blocked_cells(data, (a, b), obstacles, ij, settings)
    along = settings.thin_length / settings.terrain_cell  # a fence's line of cells, one wide, counts too
    keep = _patches(bij, bbefore * n + bafter, settings.min_patch, min_span=along)
    ij, before = np.vstack([ij, bij[keep]]), np.concatenate([before, bbefore[keep]])
    after = np.concatenate([after, bafter[keep]])
    pair_keys, counts = np.unique(before * n + after, return_counts=True)
    area = settings.terrain_cell**2
    out = [TerrainChange(names[int(k) // n], names[int(k) % n], float(c) * area) for k, c in zip(pair_keys, counts)]
    centres = (ij + 0.5) * settings.terrain_cell
    pairs = [f"{names[i]} -> {names[j]}" for i, j in zip(before, after)]
    return sorted(out, key=lambda c: (-c.area_m2, c.before, c.after)), centres, pairs


def _class_changes(data: _Sessions, a: int, b: int, s: ChangeSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The `terrain_cell` cells (M, 2) int64 indices both sessions voted on whose class changed, each with
    at least `clear_share` of its session's votes, and their class indices before and after (M,)."""
    votes_a, votes_b = data.votes[a], data.votes[b]
    both = (votes_a.sum(axis=1) >= s.min_votes) & (votes_b.sum(axis=1) >= s.min_votes)
    if not both.any():
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    cell_ij, per_cell_a = _cell_votes(data.points[both], votes_a[both], s.terrain_cell)
    _, per_cell_b = _cell_votes(data.points[both], votes_b[both], s.terrain_cell)
    class_a, clear_a = _clear_class(per_cell_a, s.clear_share)
    class_b, clear_b = _clear_class(per_cell_b, s.clear_share)
    changed = (class_a != class_b) & clear_a & clear_b  # a cell on a border between two terrains is neither
    return cell_ij[changed], class_a[changed], class_b[changed]


def _cell_votes(points: np.ndarray, votes: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """The x-y cells (C, 2) int64 indices of `points` (N, >= 2) metres and the sum of `votes` (N, T) in each
    (C, T)."""
    cell_ij, inverse = np.unique(np.floor(points[:, :2] / cell).astype(np.int64), axis=0, return_inverse=True)
    per_cell = np.zeros((cell_ij.shape[0], votes.shape[1]), np.int64)
    np.add.at(per_cell, inverse.ravel(), votes)
    return cell_ij, per_cell


def _clear_class(per_cell: np.ndarray, clear_share: float) -> tuple[np.ndarray, np.ndarray]:
    """(C,) the most-voted class of each cell's votes (C, T) and whether it has `clear_share` of them."""
    return per_cell.argmax(axis=1), per_cell.max(axis=1) >= clear_share * per_cell.sum(axis=1)


def _blocked_cells(
    data: _Sessions,
    sessions: tuple[int, int],
    obstacles: tuple[list[_Cluster], list[_Cluster]],
    exclude: np.ndarray,
    s: ChangeSettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cells (M, 2) int64 an obstacle left (the `terrain_cell` cells of its session a points: "blocked ->
    class") or came to stand on (session b's: "class -> blocked"), where the session that saw the ground free
    saw a traversable class there (`_free_ground`); not a cell blocked in both sessions (an object moved by
    less than its length) nor one of `exclude` (indices (K, 2): changed class already). Their class indices
    before and after (M,), `BLOCKED` as one past the terrain classes."""
    blocked = len(data.terrain_classes)
    rows = [np.concatenate([c.rows for c in side]) if side else np.zeros(0, np.int64) for side in obstacles]
    keys = [_keys(np.floor(data.points[r, :2] / s.terrain_cell).astype(np.int64)) for r in rows]
    dropped = np.union1d(np.intersect1d(keys[0], keys[1]), _keys(exclude))
    out = [np.zeros((0, 2), np.int64)], [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for k, free in enumerate(sessions[::-1]):  # gone: session b saw the ground free; come: session a did
        ij, terrain = _free_ground(data, free, rows[k][~np.isin(keys[k], dropped)], s)
        out[0].append(ij)
        out[1].append(np.full(len(ij), blocked) if k == 0 else terrain)
        out[2].append(terrain if k == 0 else np.full(len(ij), blocked))
    return np.vstack(out[0]), np.concatenate(out[1]), np.concatenate(out[2])


def _free_ground(data: _Sessions, session: int, rows: np.ndarray, s: ChangeSettings) -> tuple[np.ndarray, np.ndarray]:
    """The `terrain_cell` cells (M, 2) int64 of the obstacle points `rows` and the class (M,) `session`
    (0-based) saw on the ground there: each point takes the most-voted class of the nearest point that
    session voted on (`min_votes`) within a cell's length in x-y (the map's terrain votes are sparse: only
    points a camera labelled), and a cell the class of `clear_share` of its points, if traversable (not in
    `untraversable`). Beside a fence, the ground under it."""
    voted = np.flatnonzero(data.votes[session].sum(axis=1) >= s.min_votes)
    if rows.size == 0 or voted.size == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    distance, nearest = cKDTree(data.points[voted, :2]).query(
        data.points[rows, :2], distance_upper_bound=s.terrain_cell
    )
    seen = np.isfinite(distance)
    terrain_of_point = data.votes[session][voted[nearest[seen]]].argmax(axis=1)
    ij = np.floor(data.points[rows[seen], :2] / s.terrain_cell).astype(np.int64)
    cell_ij, inverse = np.unique(ij, axis=0, return_inverse=True)
    per_cell = np.zeros((cell_ij.shape[0], data.votes.shape[2]), np.int64)
    np.add.at(per_cell, (inverse.ravel(), terrain_of_point), 1)
    terrain, clear = _clear_class(per_cell, s.clear_share)
    untraversable = [i for i, name in enumerate(data.terrain_classes) if name in s.untraversable]
    keep = clear & ~np.isin(terrain, untraversable)
    return cell_ij[keep], terrain[keep]


def _patches(ij: np.ndarray, pair: np.ndarray, min_cells: int, min_span: float | None = None) -> np.ndarray:
    """(M,) whether each changed cell (indices `ij` (M, 2), its class pair `pair`) belongs to a patch of at
    least `min_cells` cells of its pair touching at edges or corners, or, given `min_span`, one spanning at
    least that many cells along x or y (a fence's line of cells): a lone cell is a border's wobble between
    two visits' labels, not a lawn turned to dirt."""
    if ij.shape[0] == 0 or min_cells <= 1:
        return np.ones(ij.shape[0], dtype=bool)
    pairs = cKDTree(ij.astype(np.float64)).query_pairs(1.5, output_type="ndarray")  # the 8 neighbours
    pairs = pairs[pair[pairs[:, 0]] == pair[pairs[:, 1]]]
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(ij), len(ij)))
    _, label = connected_components(graph, directed=False)
    keep = np.bincount(label)[label] >= min_cells
    if min_span is not None:
        low = np.full((label.max() + 1, 2), np.iinfo(np.int64).max)
        high = np.full((label.max() + 1, 2), np.iinfo(np.int64).min)
        np.minimum.at(low, label, ij)
        np.maximum.at(high, label, ij)
        keep |= (high - low + 1).max(axis=1)[label] >= min_span
    return keep
