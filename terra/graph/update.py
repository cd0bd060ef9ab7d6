"""Incremental Phase 2: the scene graph of a grown map, rebuilt only around what changed.

A live session commits a map version every few seconds, and most of the map is as it was. A
`GraphUpdater` keeps what its last graph was built from (per map point, a hash of its position,
rounded to `build.update.move_tolerance`, and of its terrain class; for a live fusion's maps kept per
fusion row, compared only at the rows the fusion changed, and moved once a row is the tolerance
away from where it last counted, `next_digest`), finds the points added, removed, moved or
re-classed since, and rebuilds the graph only there:

1. changed tiles: the squares of `build.update.tile` metres (a fixed lattice of the map frame,
   anchored at x = y = 0) that hold at least `min_changed_points` changed points (fewer wait, and
   count again at the next update);
2. the zone: the changed tiles grown by `replace_margin`; its places are rebuilt. The crops: each
   connected part's bounding box grown by `context_margin` (a long part that fills less than half
   of its box, as the band a sweep rebuilds, cut into squares of `max_crop_side` first, each a part
   of its own whose cut edges are stitched to its neighbours' places), whose points the rebuild reads: the
   terrain grid, the per-terrain GVD places and the links of the crop, by the same functions a
   full build runs on the whole map (terra.graph.pipeline); on a LiDAR-only map, on the crop's
   ground segmented from its points (terra.graph.ground), as a full build does on the whole map.
   When the crops cover `full_fraction` of the map's extent (a young map, a small site), the
   update is a full build: it would cost as much, and the full build is exact;
3. places: the old ones outside the zone, with their ids, edges, embeddings and edge ground
   geometry, and the crops' inside it. An edge cut by the zone's border is stitched: its lost end
   is replaced by the nearest place of the same terrain on the other side within
   `stitch_distance` (its cost is the straight 3-D length between the places it now joins);
   bridges then join the components, as a full build's do (costed as not clear: there is no
   whole-map grid to check the line on); new edges read their ground geometry on the crops;
4. embeddings: computed for the new places and for the old ones within `embedding.max_range` of
   the zone, the only ones new images can have seen;
5. regions: each new place joins, at every level, the regions of its nearest kept place; the
   levels are clustered in full once the places that are not the same places again (terrain and
   position within half a cell) since the last full clustering exceed `recluster_fraction` of
   all places (or nothing old is left). Ids follow terra.graph.ids: kept places keep theirs
   exactly, regions by shared places.

Against a full build of the same map the update differs in three named ways, measured by
benchmarks/bench_live_graph.py: the zone's places come from the crops' GVD (the same as the whole
map's wherever no free area inside the zone reaches past its crop), stitched edges, and regions
grown rather than re-clustered. A live session ends with a full build (`Session.close`), so the
graph of a finished drive is the batch graph of its map exactly.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from terra.errors import TerraError
from terra.graph import raster
from terra.graph.config import BuildConfig
from terra.graph.grid import TerrainGrid
from terra.graph.ground import (
    GroundLayers,
    as_ground_terrain,
    edge_geometry,
    grid_layers,
    has_terrain_votes,
    points_ground,
)
from terra.graph.gvd import EIGHT
from terra.graph.linking import bridge_components
from terra.graph.pipeline import (
    GraphBuild,
    PlaceLinks,
    TerrainPlaceSet,
    build_scene_graph,
    gvd_barrier,
    no_places_reason,
    place_embeddings,
    place_links,
    region_assignments,
    scene_graph,
    terrain_grid,
    terrain_places,
    terrains_to_build,
    unique_typed_edges,
    with_gap_places,
    with_level_links,
    with_level_routes,
    with_previous_ids,
)
from terra.graph.regions import build_levels
from terra.graph.results import BuildStats, EdgeCounts, EmbeddingSources
from terra.graph.room import obstacle_points
from terra.graph.scene_graph import (
    EDGE_BRIDGE,
    EDGE_GEOMETRY_COLUMNS,
    EDGE_GEOMETRY_FORWARDS,
    EDGE_GEOMETRY_REVERSED,
    SceneGraph,
)
from terra.mapping.semantic_map import FusionRows, MetricSemanticMap, terrain_winners
from terra.progress import StageTimer

_HASH = np.array([0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9, 0x27D4EB2F165667C5], dtype=np.uint64)


@dataclass
class MapDigest:
    """What a graph was built from, one entry per map point: a hash (N,) uint64 of its position
    rounded to the digest's step and of its terrain class, its position (N, 3) float32 metres (map
    frame) and its class (N,) int16 (-1: none the graph builds on).

    For a map a fusion made, entry r is the fusion's row r (creation order; `fusion` and `serial`
    name the fusion and which of its maps this is, `rows` (N,) the entry of each map point): the
    next map of the same fusion is compared entry by entry at the rows it changed (`next_digest`),
    and an entry is the row as it was last counted as changed, so a voxel mean that drifts a
    little with every scan counts once it has moved the step from there, not whenever it crosses
    a rounding boundary. For any other map, entry i is map point i (`rows` None), and two digests
    are compared through their sorted hashes."""

    hashes: np.ndarray
    position: np.ndarray
    terrain: np.ndarray
    rows: np.ndarray | None = None
    fusion: str | None = None
    serial: int = 0
    _sorted: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    def sorted(self) -> tuple[np.ndarray, np.ndarray]:
        """(the hashes sorted, the entry of each), computed once."""
        if self._sorted is None:
            order = np.argsort(self.hashes)
            self._sorted = (self.hashes[order], order)
        return self._sorted

    def point_terrain(self, points: np.ndarray) -> np.ndarray:
        """(K,) int16 the classes of map points `points` (K,) (indices in the map's order)."""
        return self.terrain[points if self.rows is None else self.rows[points]]


def point_hashes(points: np.ndarray, terrain: np.ndarray, step: float) -> np.ndarray:
    """(N,) uint64 hashes of points (N, 3) metres with their terrain classes (N,): each point's
    position rounded to `step` metres (1 mm when 0) and its class (64 bits: a collision between two
    of a million points is about one in 10^7, and would only hide one change)."""
    points = np.asarray(points, dtype=np.float32)
    scale = np.float32(1.0 / max(step, 1e-3))
    hashes = np.asarray(terrain, dtype=np.int64).view(np.uint64) * _HASH[3]
    with np.errstate(over="ignore"):  # wrapping multiplication is the hash
        for axis in range(3):
            cells = np.rint(points[:, axis] * scale).astype(np.int64).view(np.uint64)
            hashes ^= (cells * _HASH[axis]) >> np.uint64(axis)
    return hashes


def map_digest(points: np.ndarray, terrain: np.ndarray, step: float, rows: FusionRows | None = None) -> MapDigest:
    """The digest of map points (N, 3) metres with their terrain classes (N,) int16, hashed at
    `step` metres (point_hashes); `rows`: the points' rows in the fusion that made them, when known
    (the digest's entries are then the fusion's rows)."""
    points = np.asarray(points, dtype=np.float32)
    terrain = np.asarray(terrain, dtype=np.int16)
    hashes = point_hashes(points, terrain, step)
    if rows is None or len(rows.rows) != len(points):
        return MapDigest(hashes, points.copy(), terrain)
    by_row = np.empty_like(hashes), np.empty_like(points), np.empty_like(terrain)
    for out, values in zip(by_row, (hashes, points, terrain)):
        out[rows.rows] = values
    return MapDigest(*by_row, rows=rows.rows, fusion=rows.fusion, serial=rows.serial)


def next_digest(
    old: MapDigest | None, msm: MetricSemanticMap, terrain_of: Callable[[np.ndarray], np.ndarray], step: float
) -> MapDigest:
    """The digest of `msm` whose points' classes are `terrain_of(votes)` (votes (K, T) -> (K,)
    int16): when `old` is the digest of the same fusion's map before this one, its entries are
    copied and only the rows the fusion changed since are classed, compared and, where they count
    as changed (`_counted`), replaced (a live map changes a fraction of its rows between two
    updates); otherwise the whole map is hashed."""
    rows = msm.fusion_rows
    chained = (
        old is not None
        and rows is not None
        and rows.changed is not None
        and rows.index is not None
        and old.fusion == rows.fusion
        and rows.serial == old.serial + 1
        and len(rows.rows) == len(msm.points) >= len(old.hashes)
        and _covers_new_rows(rows.changed, len(old.hashes), len(msm.points))
    )
    if not chained:
        return map_digest(msm.points, terrain_of(msm.terrain_votes), step, rows)
    assert old is not None and rows is not None and rows.changed is not None and rows.index is not None
    at = rows.index[rows.changed]
    now = np.asarray(msm.points[at], dtype=np.float32)
    classes = terrain_of(msm.terrain_votes[at])
    counted = _counted(old, rows.changed, now, classes, step)
    n, where = len(msm.points), rows.changed[counted]
    position, terrain, hashes = (_grown_copy(a, n) for a in (old.position, old.terrain, old.hashes))
    position[where], terrain[where] = now[counted], classes[counted]
    hashes[where] = point_hashes(now[counted], classes[counted], step)
    return MapDigest(hashes, position, terrain, rows=rows.rows, fusion=rows.fusion, serial=rows.serial)


def _counted(old: MapDigest, changed: np.ndarray, now: np.ndarray, classes: np.ndarray, step: float) -> np.ndarray:
    """(K,) which of the rows `changed` (K,) the fusion changed, now at positions (K, 3) metres
    with classes (K,), count as changed against `old`: rows added since, re-classed, or moved by
    more than `step` metres along an axis from where `old` last counted them."""
    counted = np.ones(len(changed), dtype=bool)
    seen = np.flatnonzero(changed < len(old.hashes))
    rows = changed[seen]
    moved = np.abs(now[seen] - old.position[rows]).max(axis=1) > np.float32(step)
    counted[seen] = moved | (classes[seen] != old.terrain[rows])
    return counted


def _covers_new_rows(changed: np.ndarray, old: int, n: int) -> bool:
    """Whether the sorted distinct rows `changed` include every row from `old` to `n` (the rows a
    fusion added since the map of `old` rows: each was made by a scan point, so each changed)."""
    added = n - old
    return added == 0 or (len(changed) >= added and int(changed[-added]) == old and int(changed[-1]) == n - 1)


def _grown_copy(array: np.ndarray, n: int) -> np.ndarray:
    """A copy of `array` with n rows (rows past its own uninitialised: the caller sets them)."""
    out = np.empty((n, *array.shape[1:]), dtype=array.dtype)
    out[: len(array)] = array
    return out


def changed_points(old: MapDigest, new: MapDigest) -> np.ndarray:
    """(K, 2) x, y metres of the points of either digest that the other lacks: points added,
    removed, re-classed or moved by more than the digest's step (both their places count)."""
    if old.fusion is not None and old.fusion == new.fusion and len(new.hashes) >= len(old.hashes):
        # One fusion's maps, entry by entry: a fusion only appends rows, so a row past the old
        # map's is added, and one whose hash differs moved or was re-classed.
        kept = len(old.hashes)
        differ = np.flatnonzero(old.hashes != new.hashes[:kept])
        return np.vstack([new.position[differ, :2], new.position[kept:, :2], old.position[differ, :2]]).astype(
            np.float64
        )
    old_sorted, old_order = old.sorted()
    new_sorted, new_order = new.sorted()
    added = new_order[~_members(new_sorted, old_sorted)]
    removed = old_order[~_members(old_sorted, new_sorted)]
    return np.vstack([new.position[added, :2], old.position[removed, :2]]).astype(np.float64)


def _members(values: np.ndarray, sorted_values: np.ndarray) -> np.ndarray:
    """(N,) whether each of the sorted `values` is in the sorted array `sorted_values` (both
    sorted: the search walks memory in order, several times faster than random look-ups)."""
    if len(sorted_values) == 0:
        return np.zeros(len(values), dtype=bool)
    at = np.minimum(np.searchsorted(sorted_values, values), len(sorted_values) - 1)
    return sorted_values[at] == values


@dataclass(frozen=True)
class TileZone:
    """The rebuilt area on the tile lattice: tiles from `origin` (x, y tile indices) of `tile`
    metres; `zone` (X, Y) int32 labels the rebuilt tiles by connected part (1..K, 0 elsewhere),
    `near` (X, Y) bool marks those within the embedding range of the zone; `crops[k - 1]` =
    (x0, y0, x1, y1) metres, the map part the rebuild of part k reads."""

    tile: float
    origin: tuple[int, int]
    zone: np.ndarray
    near: np.ndarray
    crops: list[tuple[float, float, float, float]]

    def _lookup(self, mask: np.ndarray, xy: np.ndarray) -> np.ndarray:
        ij = np.floor(np.asarray(xy, dtype=np.float64)[:, :2] / self.tile).astype(np.int64) - np.asarray(self.origin)
        inside = (ij >= 0).all(axis=1) & (ij[:, 0] < mask.shape[0]) & (ij[:, 1] < mask.shape[1])
        out = np.zeros(len(ij), dtype=mask.dtype)
        out[inside] = mask[ij[inside, 0], ij[inside, 1]]
        return out

    def in_zone(self, xy: np.ndarray) -> np.ndarray:
        """(N,) whether each position (N, >=2) metres lies in the rebuilt area."""
        return self._lookup(self.zone, xy) > 0

    def part(self, xy: np.ndarray) -> np.ndarray:
        """(N,) the part (1..K) of the rebuilt area each position lies in, 0 outside it."""
        return self._lookup(self.zone, xy)

    def near_zone(self, xy: np.ndarray) -> np.ndarray:
        """(N,) whether each position lies within the embedding range of the rebuilt area."""
        return self._lookup(self.near, xy)

    @property
    def area(self) -> float:
        """Square metres of the rebuilt area."""
        return float((self.zone > 0).sum()) * self.tile * self.tile

    @property
    def crop_area(self) -> float:
        """Square metres of map the rebuild reads (the crops, overlaps counted twice)."""
        return float(sum((x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in self.crops))


def tile_zone(changed_xy: np.ndarray, config: BuildConfig, min_points: int | None = None) -> TileZone | None:
    """The zone around changed positions (K, 2) metres (module docstring): the tiles holding at
    least `min_points` of them (default `update.min_changed_points`), grown; None when no tile
    holds that many."""
    up = config.update
    tile = up.tile
    ij = _tile_counts(np.floor(changed_xy / tile).astype(np.int64))
    ij = ij[0][ij[1] >= (up.min_changed_points if min_points is None else min_points)]
    if len(ij) == 0:
        return None
    grow = int(np.ceil(up.replace_margin / tile))
    reach = grow + int(np.ceil(config.embedding.max_range / tile))
    low = ij.min(axis=0) - reach
    shape = tuple(int(v) for v in ij.max(axis=0) - low + reach + 1)
    changed = np.zeros(shape, dtype=bool)
    changed[ij[:, 0] - low[0], ij[:, 1] - low[1]] = True
    grown = _grow(changed, grow)
    near = _grow(grown, reach - grow)
    zone, parts = _cut_long(*_parts(grown), max(1, int(up.max_crop_side // tile)))
    crops = []
    for rows, cols in parts:
        x0, x1 = (low[0] + rows.start) * tile - up.context_margin, (low[0] + rows.stop) * tile + up.context_margin
        y0, y1 = (low[1] + cols.start) * tile - up.context_margin, (low[1] + cols.stop) * tile + up.context_margin
        crops.append((float(x0), float(y0), float(x1), float(y1)))
    return TileZone(tile, (int(low[0]), int(low[1])), zone, near, crops)


def _tile_counts(ij: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct tiles (T, 2) of tile indices (K, 2) and how many of them fall in each (T,), in
    (x, y) order: one key per tile, as np.unique(axis=0) sorts rows several times slower."""
    if len(ij) == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    low = ij.min(axis=0)
    span = int(ij[:, 1].max() - low[1]) + 1
    keys, count = np.unique((ij[:, 0] - low[0]) * span + (ij[:, 1] - low[1]), return_counts=True)
    return np.column_stack([keys // span + low[0], keys % span + low[1]]), count


def _parts(mask: np.ndarray) -> tuple[np.ndarray, list[tuple[slice, slice]]]:
    """8-connected parts of `mask`: (labels 1..K as int32, each part's bounding slices)."""
    from scipy import ndimage

    labels, _ = raster.label(mask, EIGHT, np.int32)
    boxes = [box for box in ndimage.find_objects(labels) if box is not None]
    return labels, [(box[0], box[1]) for box in boxes]


def _cut_long(
    zone: np.ndarray, boxes: list[tuple[slice, slice]], block: int
) -> tuple[np.ndarray, list[tuple[slice, slice]]]:
    """The parts (labels 1..K, their bounding slices) with each part longer than `block` tiles that
    fills less than half of its bounding box cut into squares of `block` tiles, each piece a part of
    its own (labels 1..K' again). A sweep rebuilds the band the robot drove since the last one: its
    bounding box, read as one crop, was mostly map far from any change."""
    from scipy import ndimage

    out = np.zeros_like(zone)
    count = 0
    for label, (rows, cols) in enumerate(boxes, start=1):
        part = zone[rows, cols] == label
        r, c = np.nonzero(part)
        if max(part.shape) > block and r.size < part.size / 2:
            _, piece = np.unique((r // block) * part.shape[1] + c // block, return_inverse=True)
        else:
            piece = np.zeros(r.size, dtype=np.int64)
        window = out[rows, cols]  # a view: the parts' boxes may overlap, their tiles do not
        window[r, c] = count + 1 + piece
        count += int(piece.max()) + 1 if r.size else 0
    cut = [box for box in ndimage.find_objects(out) if box is not None]
    return out, [(box[0], box[1]) for box in cut]


def _grow(mask: np.ndarray, tiles: int) -> np.ndarray:
    """`mask` grown by `tiles` squares in every direction (chessboard)."""
    if tiles <= 0:
        return mask.copy()
    return raster.grown(mask, tiles)


@dataclass
class UpdateStats:
    """What one graph update did: `kind` 'full' or 'incremental' (and why a full build ran), tiles
    changed, the rebuilt area (m^2) and the crop read (m^2), places kept / rebuilt / removed,
    edges stitched across the border, whether the regions were re-clustered in full."""

    kind: str = "full"
    reason: str = ""
    changed_points: int = 0
    zone_area: float = 0.0
    crop_area: float = 0.0
    places_kept: int = 0
    places_new: int = 0
    places_removed: int = 0
    stitched_edges: int = 0
    regions_reclustered: bool = True
    sweep: bool = False

    def to_json(self) -> dict:
        return {
            "kind": self.kind,
            "reason": self.reason,
            "changed_points": self.changed_points,
            "zone_area_m2": round(self.zone_area, 1),
            "crop_area_m2": round(self.crop_area, 1),
            "places_kept": self.places_kept,
            "places_new": self.places_new,
            "places_removed": self.places_removed,
            "stitched_edges": self.stitched_edges,
            "regions_reclustered": self.regions_reclustered,
            "sweep": self.sweep,
        }


@dataclass
class GraphUpdate(GraphBuild):
    """A GraphBuild made by `GraphUpdater.update`, with what the update did."""

    update: UpdateStats = field(default_factory=UpdateStats)


class GraphUpdater:
    """The scene graph of one growing map, updated version after version (module docstring).

    `update(msm)` returns the graph of the map `msm`: a full build the first time (or `full=True`),
    then an incremental one around what changed since the previous call. `previous`: a graph an
    earlier build left (its ids and saved objects are carried, as `terra build` carries them)."""

    def __init__(self, config: BuildConfig | None = None, previous: SceneGraph | None = None) -> None:
        self.config = config or BuildConfig()
        self.graph: SceneGraph | None = previous
        self._digest: MapDigest | None = None
        self._classes: tuple = ()  # what the digest's classes were computed from (_digest_of)
        self._replaced_since_clustering = 0
        # Changed points in tiles that held too few to be rebuilt yet: they count again next time.
        self._pending = np.zeros((0, 2))
        self._since_sweep = 0  # updates since the last that rebuilt every waiting change

    def update(self, msm: MetricSemanticMap, full: bool = False) -> GraphUpdate:
        """The graph of `msm` (see the class docstring); TerraError when the map gives nothing to build on."""
        full_map, lidar_only = msm, not has_terrain_votes(msm)
        if lidar_only:  # as a full build sees it: one class, `ground`, from the LiDAR (terra.graph.ground)
            msm = as_ground_terrain(msm, np.zeros(len(msm.points), dtype=bool))
        _, terrains = terrains_to_build(msm, self.config)
        why = self._full_reason(full)
        if why:
            self._digest = None  # not compared: its memory goes before the whole-map build
            result = self._full(full_map, why)
            digest = self._digest_of(msm, terrains, lidar_only)
        else:
            digest = self._digest_of(msm, terrains, lidar_only)
            assert self._digest is not None and self.graph is not None
            zone, changed, sweep = self._zone(digest)
            if zone is None:
                result = GraphUpdate(self.graph, update=UpdateStats("incremental", "nothing changed", 0, 0.0, 0.0))
                result.update.places_kept = len(self.graph.places)
                result.update.regions_reclustered = False
            elif _covered_share(zone, msm.points) >= self.config.update.full_fraction:
                result = self._full(full_map, "the changed area covers most of the map")
            else:
                result = self._incremental(msm, None if lidar_only else digest, terrains, zone)
                result.update.changed_points, result.update.sweep = len(changed), sweep
        self.graph, self._digest = result.graph, digest
        return result

    def _digest_of(self, msm: MetricSemanticMap, terrains: list[int], lidar_only: bool) -> MapDigest:
        """The digest of `msm`, chained to the previous one where both are of one fusion and classed
        alike (next_digest). A LiDAR-only map's classes are all 0: its ground comes from each crop's
        geometry, and the digest needs only the points."""
        classes = (lidar_only, tuple(terrains))
        share = self.config.terrain.min_share

        def terrain_of(votes: np.ndarray) -> np.ndarray:
            if lidar_only:
                return np.zeros(len(votes), dtype=np.int16)
            winners = terrain_winners(votes, share, np.int16)
            winners[~np.isin(winners, terrains)] = -1
            return winners

        old = self._digest if classes == self._classes else None
        self._classes = classes
        return next_digest(old, msm, terrain_of, self.config.update.move_tolerance)

    def _zone(self, digest: MapDigest) -> tuple[TileZone | None, np.ndarray, bool]:
        """The rebuilt area of this update, the changed positions (K, 2) metres it counted, and
        whether it is a sweep: every `update.sweep_every` updates, tiles with fewer changed points
        than `min_changed_points` are rebuilt too, so no change waits longer than that."""
        assert self._digest is not None
        changed = np.vstack([self._pending, changed_points(self._digest, digest)])
        every = self.config.update.sweep_every
        self._since_sweep += 1
        sweep = every > 0 and self._since_sweep >= every
        zone = tile_zone(changed, self.config, min_points=1 if sweep else None)
        if sweep:
            self._since_sweep = 0
        self._pending = changed if zone is None else changed[~zone.in_zone(changed)]
        return zone, changed, sweep

    def _full_reason(self, full: bool) -> str:
        if full:
            return "asked for"
        if self._digest is None or self.graph is None:
            return "first build of this session"
        if len(self._pending) > self.config.update.max_pending_points:
            return f"more than {self.config.update.max_pending_points:,} changed points were waiting"
        return ""

    def _full(self, msm: MetricSemanticMap, why: str) -> GraphUpdate:
        built = build_scene_graph(msm, self.config, previous=self.graph)
        self._replaced_since_clustering = self._since_sweep = 0
        self._pending = np.zeros((0, 2))
        return GraphUpdate(built.graph, built.stats, built.timer, UpdateStats("full", why))

    def _incremental(
        self, msm: MetricSemanticMap, digest: MapDigest | None, terrains: list[int], zone: TileZone
    ) -> GraphUpdate:
        """The update around `zone`; `digest` the map's (its points' classes), or None for a
        LiDAR-only map (each crop's ground is segmented from its points)."""
        assert self.graph is not None
        old, timer, stats = self.graph, StageTimer(), UpdateStats("incremental")
        stats.zone_area, stats.crop_area = zone.area, zone.crop_area
        with timer.stage("crop places"):
            crop = _rebuilt_places(msm, digest, terrains, zone, self.config)
        with timer.stage("stitch"):
            merged, links, stitched = _merge(old, crop, zone, self.config)
        if len(merged.position) == 0:
            raise TerraError(no_places_reason(lidar_only=digest is None))
        stats.places_kept = int((merged.old_index >= 0).sum())
        stats.places_new = len(merged.position) - stats.places_kept
        stats.places_removed = len(old.places) - stats.places_kept
        stats.stitched_edges = stitched
        with timer.stage("place embeddings"):
            embedding, sources = _embeddings(msm, old, merged, stats.places_kept, zone, self.config)
        with timer.stage("regions"):
            self._replaced_since_clustering += _places_changed(old, merged, stats.places_kept, self.config)
            recluster = self._replaced_since_clustering > self.config.update.recluster_fraction * max(
                len(merged.position), 1
            )
            levels = _regions(old, merged, embedding, links, stats.places_kept, recluster, self.config)
            if recluster:
                self._replaced_since_clustering = 0
            stats.regions_reclustered = recluster
        graph = _graph(msm, old, merged, embedding, links, levels, self.config)
        if self.config.ground.layers and (old.has_edge_geometry or len(old.place_edges) == 0):
            graph.place_edge_geometry = _edge_geometry(old, merged, links, crop.layers)
        build_stats = BuildStats(
            places_per_terrain={
                msm.terrain_classes[t]: int((merged.terrain == t).sum()) for t in sorted(set(terrains))
            },
            edges=EdgeCounts.of(links.kind),
            embedding_source=sources,
            embedding_rule="as the full build's, for the places in or near the rebuilt area",
        )
        return GraphUpdate(graph, build_stats, timer, stats)


def _covered_share(zone: TileZone, points: np.ndarray) -> float:
    """The share of the map's x, y extent (points (N, 3) metres) that the zone's crops cover."""
    # Per column: a reduction over axis 0 of an (N, 2) view is forty times slower (42 ms at 700k points).
    low = np.array([points[:, 0].min(), points[:, 1].min()], dtype=np.float64)
    high = np.array([points[:, 0].max(), points[:, 1].max()], dtype=np.float64)
    extent = float(np.prod(np.maximum(high - low, 1e-9)))
    covered = 0.0
    for x0, y0, x1, y1 in zone.crops:
        width = max(0.0, min(x1, high[0]) - max(x0, low[0]))
        height = max(0.0, min(y1, high[1]) - max(y0, low[1]))
        covered += width * height
    return min(covered / extent, 1.0)


@dataclass
class _Rebuilt:
    """The places of every crop (concatenated), their links, and which of them each crop owns
    (those in its own part of the zone): the places that replace the zone's."""

    places: TerrainPlaceSet
    links: PlaceLinks
    take: np.ndarray
    room: np.ndarray  # (P,) metres to the nearest obstacle of each place (terra.graph.room)
    layers: list[GroundLayers] = field(default_factory=list)  # each crop's ground geometry


def _rebuilt_places(
    msm: MetricSemanticMap, digest: MapDigest | None, terrains: list[int], zone: TileZone, config: BuildConfig
) -> _Rebuilt:
    """Each part of the zone rebuilt from its crop: the places and links a full build gives on the
    map points inside the crop, of which those in the part replace the old places there, and the
    crop's ground layers when the build computes them (`build.ground.layers`). digest: the map's,
    whose classes the crop's points take, or None for a LiDAR-only map: its crops' ground,
    segmented, is class 0."""
    # Contiguous columns: a comparison over a strided column of the (N, 3) points costs about four
    # times as much, and each crop scans the whole map.
    x, y = np.ascontiguousarray(msm.points[:, 0]), np.ascontiguousarray(msm.points[:, 1])
    parts: list[tuple[TerrainPlaceSet, PlaceLinks, np.ndarray]] = []
    layers: list[GroundLayers] = []
    rooms: list[np.ndarray] = []  # each part's places' room (terra.graph.room), on its crop's grid
    for k, (x0, y0, x1, y1) in enumerate(zone.crops, start=1):
        inside = np.flatnonzero((x >= x0) & (x < x1) & (y >= y0) & (y < y1))
        points = msm.points[inside]
        ground = points_ground(points, config.ground) if digest is None or config.ground.layers else None
        if digest is None:
            assert ground is not None
            crop_terrain = np.where(ground, 0, -1).astype(np.int16)
        else:
            crop_terrain = digest.point_terrain(inside)
        if not (crop_terrain >= 0).any():
            continue
        grid = terrain_grid(points, crop_terrain, config)
        crop_layers = None
        if ground is not None and config.ground.layers:
            gc = config.grid
            crop_layers = grid_layers(points, ground, grid, band=gc.obstacle_height, min_points=gc.obstacle_min_points)
            layers.append(crop_layers)
        built = _crop_places(points, grid, crop_layers, terrains, digest is None, config)
        if built is not None:
            places, links, room = built
            parts.append((places, links, zone.part(places.position) == k))
            rooms.append(room)
    offsets = np.cumsum([0] + [len(p.position) for p, _, _ in parts])
    places = TerrainPlaceSet(
        np.vstack([np.zeros((0, 3))] + [p.position for p, _, _ in parts]),
        np.concatenate([np.zeros(0, np.int64)] + [p.terrain for p, _, _ in parts]).astype(np.int64),
        np.concatenate([np.zeros(0)] + [p.clearance for p, _, _ in parts]),
        *_no_edges(),
    )
    links = PlaceLinks(
        np.vstack([np.zeros((0, 2), np.int64)] + [lk.edges + o for (_, lk, _), o in zip(parts, offsets)]),
        np.concatenate([np.zeros(0)] + [lk.weight for _, lk, _ in parts]),
        np.concatenate([np.zeros(0, np.int64)] + [lk.kind for _, lk, _ in parts]),
        0,
        0,
    )
    take = np.concatenate([np.zeros(0, dtype=bool)] + [t for _, _, t in parts])
    return _Rebuilt(places, links, take, np.concatenate([np.zeros(0), *rooms]), layers)


def _crop_places(
    points: np.ndarray,
    grid: TerrainGrid,
    layers: GroundLayers | None,
    terrains: list[int],
    lidar_only: bool,
    config: BuildConfig,
) -> tuple[TerrainPlaceSet, PlaceLinks, np.ndarray] | None:
    """The places, links and room (terra.graph.room) a full build gives on one crop's `points`
    (N, 3) and `grid`, by the same functions; None where it has no place."""
    barrier = gvd_barrier(layers, config, lidar_only=lidar_only)
    places, traversable, _ = terrain_places(grid, terrains, config, barrier=barrier, layers=layers)
    places = with_gap_places(places, traversable, grid, layers, config)
    if not len(places.position):
        return None
    links = place_links(places, traversable, grid, config, barrier)
    links = with_level_links(links, places, traversable, grid, layers, config)
    return with_level_routes(
        places, links, grid, layers, config, obstacle_points(points, grid, config.grid.obstacle_height)
    )


@dataclass
class _Merged:
    """The places of an update, kept old ones first (in their old order), then the crop's."""

    position: np.ndarray
    terrain: np.ndarray
    clearance: np.ndarray
    old_index: np.ndarray  # (P,) index in the old graph, -1 for new places
    room: np.ndarray  # (P,) metres (terra.graph.room; NaN for kept places of a graph without it)


def _merge(old: SceneGraph, crop: _Rebuilt, zone: TileZone, config: BuildConfig) -> tuple[_Merged, PlaceLinks, int]:
    """Kept old places + the rebuilt places in the zone, their edges, stitches across the zone's
    border and bridges between components; and the number of stitched edges."""
    keep = np.flatnonzero(~zone.in_zone(old.places.position))
    new_places, new_links = crop.places, crop.links
    take = np.flatnonzero(crop.take)
    merged = _Merged(
        np.vstack([old.places.position[keep], new_places.position[take]]),
        np.concatenate([old.places.terrain[keep], new_places.terrain[take]]).astype(np.int64),
        np.concatenate([old.places.clearance[keep], new_places.clearance[take]]),
        np.concatenate([keep, np.full(len(take), -1)]).astype(np.int64),
        np.concatenate([np.asarray(old.places.room, dtype=np.float64)[keep], crop.room[take]]),
    )
    old_to = _index_map(len(old.places), keep, 0)
    new_to = _index_map(len(new_places.position), take, len(keep))
    kept_kind = old.place_edge_kind != EDGE_BRIDGE  # bridges are recomputed on the merged places
    # Each side's edges, costs, kinds, places (positions, terrains) and their merged indices. A cut
    # edge is stitched to a merged place of another group than its taken end's: the kept places are
    # group 0, the rebuilt ones their part's number (the old side's to rebuilt places, as before; a
    # part's to kept places and to the parts beside it, where a long part was cut: `_cut_long`).
    old_edges = (old.place_edges[kept_kind], old.place_edge_weight[kept_kind], old.place_edge_kind[kept_kind])
    group = np.concatenate([np.zeros(len(keep), np.int64), zone.part(new_places.position[take]).astype(np.int64)])
    sides = (
        (*old_edges, old.places, old_to),
        (new_links.edges, new_links.weight, new_links.kind, new_places, new_to),
    )
    parts, stitched = [], []
    for side_edges, side_weight, side_kind, places, to in sides:
        parts.append(_remap(side_edges, side_weight, side_kind, to))
        cut = _stitch(
            side_edges, side_kind, places.position, places.terrain, to, merged, group, config.update.stitch_distance
        )
        stitched.append(_costed(cut, merged.position))
    edges = np.vstack([p[0] for p in parts] + [s[0] for s in stitched])
    weight = np.concatenate([p[1] for p in parts] + [s[1] for s in stitched])
    kind = np.concatenate([p[2] for p in parts] + [s[2] for s in stitched])
    edges, weight, kind = unique_typed_edges(edges, weight, kind)
    lk = config.linking
    never_clear = lambda a, b: np.zeros(len(a), dtype=bool)  # noqa: E731  # no whole-map grid to check a line on
    bridges, cost, _ = bridge_components(merged.position, edges, lk.bridge_penalty, lk.link_candidates, never_clear)
    edges = np.vstack([edges, bridges])
    weight = np.concatenate([weight, cost])
    kind = np.concatenate([kind, np.full(len(bridges), EDGE_BRIDGE)])
    edges, weight, kind = unique_typed_edges(edges, weight, kind)
    return merged, PlaceLinks(edges, weight, kind, 0, len(bridges)), int(sum(len(s[0]) for s in stitched))


def _no_edges() -> tuple[np.ndarray, np.ndarray]:
    return np.zeros((0, 2), np.int64), np.zeros(0)


def _index_map(count: int, taken: np.ndarray, offset: int) -> np.ndarray:
    """(count,) merged index of each place of a part (-1 where it was not taken)."""
    out = np.full(count, -1, dtype=np.int64)
    out[taken] = offset + np.arange(len(taken))
    return out


def _remap(
    edges: np.ndarray, weight: np.ndarray, kind: np.ndarray, to: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The edges whose both ends were taken, in merged indices."""
    ends = to[edges] if len(edges) else np.zeros((0, 2), np.int64)
    both = (ends >= 0).all(axis=1)
    return ends[both], weight[both], kind[both]


def _stitch(
    edges: np.ndarray,
    kind: np.ndarray,
    position: np.ndarray,
    terrain: np.ndarray,
    to: np.ndarray,
    merged: _Merged,
    group: np.ndarray,
    reach: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Edges of one side cut by a border (one end taken into the merged places, the other not): (k, 2)
    pairs of (the taken end's merged index, the lost end's replacement: its nearest same-terrain
    merged place of another `group` (M,) than the taken end's, within `reach` metres (2-D)) and
    their kinds (k,); a lost end with no replacement is left out."""
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

    none = np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    if len(edges) == 0:
        return none
    ends = to[edges]
    cut = np.flatnonzero((ends >= 0).sum(axis=1) == 1)
    taken_side = np.where(ends[cut, 0] >= 0, 0, 1)
    taken = ends[cut, taken_side]
    lost = edges[cut, 1 - taken_side]
    spread = 1e9  # same terrain only: terrains far apart along a third axis
    pairs, kinds = [none[0]], [none[1]]
    for g in np.unique(group[taken]):
        candidates = np.flatnonzero(group != g)
        mine = np.flatnonzero(group[taken] == g)
        if len(candidates) == 0:
            continue
        tree = cKDTree(np.column_stack([merged.position[candidates, :2], merged.terrain[candidates] * spread]))
        query = np.column_stack([position[lost[mine], :2], terrain[lost[mine]] * spread])
        distance, at = tree.query(query, distance_upper_bound=reach)
        found = np.isfinite(distance)
        pairs.append(np.column_stack([taken[mine][found], candidates[at[found]]]))
        kinds.append(kind[cut][mine][found])
    return np.vstack(pairs), np.concatenate(kinds)


def _costed(stitch: tuple[np.ndarray, np.ndarray], position: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stitched pairs that are not loops, with their straight 3-D length (metres) as cost."""
    pairs, kind = stitch
    ok = pairs[:, 0] != pairs[:, 1]
    pairs, kind = pairs[ok], kind[ok]
    return pairs, np.linalg.norm(position[pairs[:, 0]] - position[pairs[:, 1]], axis=1), kind


def _edge_geometry(old: SceneGraph, merged: _Merged, links: PlaceLinks, layers: list[GroundLayers]) -> np.ndarray:
    """(E, 5) float32 ground geometry of the merged edges (step m, rise and fall degrees from
    edges[:, 0] to edges[:, 1], unobserved stretch m, cross slope degrees, as
    terra.graph.ground.edge_geometry): an old edge between kept places keeps its own (rise and fall
    swapped when its ends are now the other way round); the others are read on the crops' layers
    (the largest where crops overlap; 0 where no crop saw the ground under them, as a full build
    reads unseen ground; the unobserved stretch of an edge beyond one crop is the longest any crop
    holds)."""
    edges = links.edges
    out = np.zeros((len(edges), len(EDGE_GEOMETRY_COLUMNS)), dtype=np.float32)
    for layer in layers:
        out = np.maximum(out, edge_geometry(layer, merged.position, edges))
    if not old.has_edge_geometry or len(edges) == 0:
        return out
    ends = merged.old_index[edges]
    both = np.flatnonzero((ends >= 0).all(axis=1))
    count = len(old.places)
    keys = old.place_edges[:, 0] * count + old.place_edges[:, 1]
    order = np.argsort(keys)
    for first, second, columns in ((0, 1, EDGE_GEOMETRY_FORWARDS), (1, 0, EDGE_GEOMETRY_REVERSED)):
        wanted = ends[both, first] * count + ends[both, second]
        at = np.minimum(np.searchsorted(keys[order], wanted), len(keys) - 1)
        hit = keys[order][at] == wanted
        kept = old.place_edge_geometry[order[at[hit]]][:, columns]
        # A column an older bundle did not record (NaN) is read on the layers like a new edge's.
        out[both[hit]] = np.where(np.isnan(kept), out[both[hit]], kept)
    return out


def _embeddings(
    msm: MetricSemanticMap, old: SceneGraph, merged: _Merged, kept: int, zone: TileZone, config: BuildConfig
) -> tuple[np.ndarray, EmbeddingSources]:
    """(P, D) place embeddings: kept places far from the zone keep theirs, the rest are computed."""
    embedding = np.zeros((len(merged.position), old.places.embedding.shape[1]), np.float32)
    embedding[:kept] = old.places.embedding[merged.old_index[:kept]]
    redo = np.flatnonzero((merged.old_index < 0) | zone.near_zone(merged.position))
    sources = EmbeddingSources(0, 0, 0)
    if len(redo):
        embedding[redo], sources = place_embeddings(
            msm, merged.position[redo], merged.terrain[redo], config.embedding.max_range
        )
    return embedding, sources


def _places_changed(old: SceneGraph, merged: _Merged, kept: int, config: BuildConfig) -> int:
    """Rebuilt places that are not an old place again (same terrain within half a cell, the rule
    that carries ids), and old places that are gone."""
    from terra.graph.ids import match_points

    gone = np.setdiff1d(np.arange(len(old.places)), merged.old_index[:kept])
    match = match_points(
        old.places.position[gone],
        old.places.terrain[gone],
        merged.position[kept:],
        merged.terrain[kept:],
        config.grid.cell_size / 2,
    )
    return int((match < 0).sum() + len(gone) - (match >= 0).sum())


def _regions(
    old: SceneGraph,
    merged: _Merged,
    embedding: np.ndarray,
    links: PlaceLinks,
    kept: int,
    recluster: bool,
    config: BuildConfig,
):
    """Region levels of the merged places: re-clustered in full, or grown (module docstring)."""
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

    if recluster or kept == 0 or not old.regions:
        assignments = region_assignments(merged.position, embedding, merged.terrain, links.edges, config)
        return build_levels(assignments, merged.position, embedding)
    nearest = np.arange(len(merged.position))
    if len(merged.position) > kept:
        _, at = cKDTree(merged.position[:kept, :2]).query(merged.position[kept:, :2])
        nearest[kept:] = at
    source = merged.old_index[nearest]  # the old place whose regions each place takes
    assignments = [old.place_region(level.level)[source] for level in old.regions]
    return build_levels(assignments, merged.position, embedding)


def _graph(
    msm: MetricSemanticMap,
    old: SceneGraph,
    merged: _Merged,
    embedding: np.ndarray,
    links: PlaceLinks,
    levels: list,
    config: BuildConfig,
) -> SceneGraph:
    """The updated SceneGraph with the old graph's ids carried and its saved objects relinked."""
    places = TerrainPlaceSet(merged.position, merged.terrain, merged.clearance, *_no_edges())
    graph = scene_graph(msm, places, embedding, links, levels, config, merged.room)
    graph = replace(graph, next_id=dict(old.next_id))
    return with_previous_ids(graph, old, config.grid.cell_size / 2)
