"""What changed between two sessions of one map (issue 26): objects added, removed and moved, and terrain
that changed class, judged only where both sessions observed (not seen is not gone).

It reads the fusion state a joined map keeps: LiDAR returns per point and session (`map/state/session_hits`)
and terrain votes per session (`map/state/session_votes`), beside the object observations of every point
(`map/counts_*`). Lengths in metres, positions in the map frame.

Objects: the map's object points (more object observations than terrain votes) that session s returned from
are grouped into clusters (points within `link` metres, at least `min_points`), per session. A cluster of the
first session with a cluster of the second within `same_distance` (centroids, x and y) or sharing half its
footprint cells is the same object. An unmatched cluster of the first session is removed when the second
session observed where it stood (returns in at least `observed_fraction` of the inner cells of its footprint,
or, for a footprint too thin to have inner cells, `thin_observed_fraction` of all) and returned from few of
its points; an added cluster of the second, likewise the other way round. A removed and an added cluster
with the same most-observed bank entry within `move_radius` are one object moved (greedy, nearest first).

Terrain: per `terrain_cell` cell, the class with the most votes of each session, over the points both
sessions voted on at least `min_votes` times; cells whose class differs, each with at least `clear_share` of
its session's votes (not a border between two terrains), are changes, summed as area per (before, after) pair.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

from terra.bundle import Bundle
from terra.errors import TerraError
from terra.npy import ArraySpec


@dataclass(frozen=True)
class ChangeSettings:
    """Thresholds of change detection (metres unless said): see the module docstring."""

    link: float = 0.6
    min_points: int = 12
    cell: float = 0.5
    same_distance: float = 1.0
    observed_fraction: float = 0.5
    thin_observed_fraction: float = 0.9
    move_radius: float = 10.0
    terrain_cell: float = 1.0
    min_votes: int = 2
    clear_share: float = 0.75


@dataclass(frozen=True)
class ObjectChange:
    """An object `added`, `removed` or `moved`: its most-observed bank entry, its centre before and after
    (x, y, z metres, map frame; None where it was not there), the distance moved (x, y metres) and its size."""

    change: str
    entry: int
    before: tuple[float, float, float] | None
    after: tuple[float, float, float] | None
    distance: float | None
    size: tuple[float, float, float]

    def to_json(self) -> dict[str, Any]:
        def rounded(v):
            return None if v is None else [round(float(x), 3) for x in v]

        return {
            "change": self.change,
            "entry": self.entry,
            "before": rounded(self.before),
            "after": rounded(self.after),
            "distance": None if self.distance is None else round(self.distance, 3),
            "size": rounded(self.size),
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
class ChangesResult:
    """`terra changes`: the bundle, the two sessions compared, the area both observed (m², x-y cells of
    `ChangeSettings.cell`), object changes and terrain changes (largest area first)."""

    bundle: Path
    first: int
    second: int
    observed_area_m2: float
    objects: list[ObjectChange] = field(default_factory=list)
    terrain: list[TerrainChange] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        counts = {kind: sum(o.change == kind for o in self.objects) for kind in ("added", "removed", "moved")}
        return {
            "bundle": str(self.bundle),
            "between": [self.first, self.second],
            "observed_area_m2": round(self.observed_area_m2, 1),
            "counts": counts,
            "objects": [o.to_json() for o in self.objects],
            "terrain": [t.to_json() for t in self.terrain],
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
    cells: np.ndarray  # sorted unique x-y cell keys


def detect_changes(path: Path, first: int, second: int, settings: ChangeSettings | None = None) -> ChangesResult:
    """Changes from session `first` to session `second` (1-based) of the joined map in bundle `path`."""
    settings = settings or ChangeSettings()
    data = _load(Bundle(path), first, second)
    a, b = first - 1, second - 1
    seen_a = _cells(data.points[data.hits[:, a] > 0], settings.cell)
    seen_b = _cells(data.points[data.hits[:, b] > 0], settings.cell)
    observed = np.intersect1d(seen_a, seen_b).size * settings.cell**2
    objects = _object_changes(data, a, b, seen_a, seen_b, settings)
    terrain = _terrain_changes(data, a, b, settings)
    return ChangesResult(Path(path), first, second, float(observed), objects, terrain)


def _load(bundle: Bundle, first: int, second: int) -> _Sessions:
    """The joined map's arrays, after checking both sessions exist (TerraError naming the bundle)."""
    info = bundle.model.components.map
    if info is None or not bundle.has("map/state/session_hits") or not bundle.has("map/state/session_votes"):
        raise TerraError(f"{bundle.path}: the map has one session; join another with `terra map SESSION --into`")
    n, k, nnz = int(info.points or 0), int(info.bank or 0), int(info.observations or 0)
    hits = bundle.array("map/state/session_hits", ArraySpec(("uint8", "uint16", "uint32", "uint64"), (n, None)))
    sessions = int(hits.shape[1])
    for value in (first, second):
        if not 1 <= value <= sessions:
            raise TerraError(f"--between {first} {second}: the map has sessions 1 to {sessions}")
    if first == second:
        raise TerraError(f"--between {first} {second}: give two different sessions")
    t = len(bundle.model.terrain_classes)
    unsigned = ("uint8", "uint16", "uint32", "uint64")
    votes = bundle.array("map/state/session_votes", ArraySpec(unsigned, (sessions, n, t)))
    points = bundle.array("map/points", ArraySpec(("float32",), (n, 3), finite=True))
    indptr = bundle.array("map/counts_indptr", ArraySpec(("int64",), (n + 1,)))
    indices = bundle.array("map/counts_indices", ArraySpec(("int32",), (nnz,)))
    values = bundle.array("map/counts_data", ArraySpec(unsigned, (nnz,)))
    counts = sp.csr_matrix((np.asarray(values, np.int64), indices, indptr), shape=(n, k))
    return _Sessions(
        np.asarray(points, np.float64),
        np.asarray(hits, np.int64),
        np.asarray(votes, np.int64),
        counts,
        list(bundle.model.terrain_classes),
    )


def _cells(points: np.ndarray, cell: float) -> np.ndarray:
    """Sorted unique x-y cell keys of `points` (N, >= 2) metres."""
    ij = np.floor(points[:, :2] / cell).astype(np.int64)
    return np.unique((ij[:, 0] << 32) ^ (ij[:, 1] & 0xFFFFFFFF))


def _clusters(data: _Sessions, rows: np.ndarray, settings: ChangeSettings) -> list[_Cluster]:
    """Object clusters of the points `rows` (points within `link` metres joined)."""
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
        entry = int(np.asarray(data.counts[mine].sum(axis=0)).ravel().argmax())
        low, high = xyz[members].min(axis=0), xyz[members].max(axis=0)
        out.append(_Cluster(mine, xyz[members].mean(axis=0), high - low, entry, _cells(xyz[members], settings.cell)))
    return out


def _object_changes(
    data: _Sessions, a: int, b: int, seen_a: np.ndarray, seen_b: np.ndarray, settings: ChangeSettings
) -> list[ObjectChange]:
    """Removed, added and moved objects from session a to session b (0-based columns)."""
    object_rows = np.asarray(data.counts.sum(axis=1)).ravel() > data.votes.sum(axis=(0, 2))
    before = _clusters(data, np.flatnonzero(object_rows & (data.hits[:, a] > 0)), settings)
    after = _clusters(data, np.flatnonzero(object_rows & (data.hits[:, b] > 0)), settings)
    removed = [c for c in before if _gone(c, after, data.hits[:, b], seen_b, settings)]
    added = [c for c in after if _gone(c, before, data.hits[:, a], seen_a, settings)]
    moved, removed, added = _pair_moves(removed, added, settings)
    changes = [_change("moved", old, new) for old, new in moved]
    changes += [_change("removed", c, None) for c in removed] + [_change("added", None, c) for c in added]
    return sorted(changes, key=lambda c: (c.change, c.before or c.after or ()))


def _gone(cluster: _Cluster, others: list[_Cluster], hits: np.ndarray, seen: np.ndarray, s: ChangeSettings) -> bool:
    """Whether the other session observed `cluster`'s place and saw no object there (no cluster matching it,
    few returns from its points)."""
    for other in others:
        if np.linalg.norm((other.centre - cluster.centre)[:2]) < s.same_distance:
            return False
        shared = np.intersect1d(other.cells, cluster.cells, assume_unique=True).size
        if shared >= 0.5 * min(other.cells.size, cluster.cells.size):
            return False
    if np.count_nonzero(hits[cluster.rows] > 0) >= 0.75 * cluster.rows.size:
        return False
    inside = _interior(cluster.cells)
    if inside.size:
        return np.isin(inside, seen, assume_unique=True).mean() >= s.observed_fraction
    return np.isin(cluster.cells, seen, assume_unique=True).mean() >= s.thin_observed_fraction


def _interior(cells: np.ndarray) -> np.ndarray:
    """The footprint cells whose four neighbours are in the footprint too: where the object stood, not its
    edge, whose cell the other session may have hit from the far side (a wall seen from behind)."""
    i, j = cells >> 32, (cells & 0xFFFFFFFF).astype(np.int64)
    j = np.where(j >= 1 << 31, j - (1 << 32), j)  # the low half holds a signed 32-bit index

    def key(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return (a << 32) ^ (b & 0xFFFFFFFF)

    inner = np.ones(cells.size, dtype=bool)
    for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        inner &= np.isin(key(i + di, j + dj), cells, assume_unique=False)
    return cells[inner]


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


def _terrain_changes(data: _Sessions, a: int, b: int, settings: ChangeSettings) -> list[TerrainChange]:
    """Area per (before, after) terrain class pair over the cells both sessions voted on."""
    votes_a, votes_b = data.votes[a], data.votes[b]
    both = (votes_a.sum(axis=1) >= settings.min_votes) & (votes_b.sum(axis=1) >= settings.min_votes)
    if not both.any():
        return []
    ij = np.floor(data.points[both, :2] / settings.terrain_cell).astype(np.int64)
    _, cell = np.unique(ij, axis=0, return_inverse=True)
    cell = cell.ravel()
    n_cells, t = int(cell.max()) + 1, votes_a.shape[1]
    per_cell_a = np.zeros((n_cells, t), np.int64)
    per_cell_b = np.zeros((n_cells, t), np.int64)
    np.add.at(per_cell_a, cell, votes_a[both])
    np.add.at(per_cell_b, cell, votes_b[both])
    class_a, class_b = per_cell_a.argmax(axis=1), per_cell_b.argmax(axis=1)
    clear_a = per_cell_a.max(axis=1) >= settings.clear_share * per_cell_a.sum(axis=1)
    clear_b = per_cell_b.max(axis=1) >= settings.clear_share * per_cell_b.sum(axis=1)
    changed = (class_a != class_b) & clear_a & clear_b  # a cell on a border between two terrains is neither
    pair_keys, areas = np.unique(class_a[changed] * t + class_b[changed], return_counts=True)
    names = data.terrain_classes
    out = [
        TerrainChange(names[int(k) // t], names[int(k) % t], float(n) * settings.terrain_cell**2)
        for k, n in zip(pair_keys, areas)
    ]
    return sorted(out, key=lambda c: (-c.area_m2, c.before, c.after))
