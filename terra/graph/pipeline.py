"""Phase 2: the metric-semantic map of a bundle -> terrain places, links, embeddings, regions.

`build_scene_graph` works on a MetricSemanticMap in memory; `build_graph` reads the bundle, runs it
and adds component `graph/` atomically (the bundle is unchanged when anything fails). A rebuild
keeps the node ids and the saved objects of the graph it replaces (terra.graph.ids).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from terra.background import Background, usable_cores
from terra.bundle import Bundle, BundleWriter
from terra.errors import TerraError
from terra.graph.agglomerative import AdaptiveCuts, agglomerative_assignments
from terra.graph.config import BuildConfig, GroundSection, check_region_method
from terra.graph.crossings import CrossingRule, gap_places, level_links
from terra.graph.embedding import image_embeddings, point_embeddings
from terra.graph.grid import GridFrame, TerrainGrid, block_under_objects, build_terrain_grid, grid_frame
from terra.graph.grid_links import GridPathRules, link_pieces_on_grid
from terra.graph.ground import (
    GroundLayers,
    as_ground_terrain,
    edge_geometry,
    ground_layers,
    has_terrain_votes,
    heights_in_gaps,
    layers_on_grid,
    points_ground,
    step_lines,
)
from terra.graph.level_routes import MAX_UNOBSERVED, RouteRule, level_routes
from terra.graph.linking import (
    bridge_components,
    grid_gap_length,
    grid_line_clear,
    grid_line_crosses,
    grid_line_passable,
    link_across,
    link_dead_ends,
    link_strip_gaps,
)
from terra.graph.places import CellPlaces, extract_places, unique_edge_rows
from terra.graph.regions import build_levels
from terra.graph.results import BuildStats, EdgeCounts, EmbeddingSources, GridTiles, GvdTiles
from terra.graph.room import obstacle_points, place_room
from terra.graph.scene_graph import (
    EDGE_BRIDGE,
    EDGE_CROSS_TERRAIN,
    EDGE_GVD,
    EDGE_LEVEL_ROUTE,
    Places,
    RegionLevel,
    SceneGraph,
)
from terra.graph.spectral import SpectralStop, spectral_assignments
from terra.graph.tiled_grid import TiledGridStats, build_terrain_grid_tiled
from terra.graph.tiled_gvd import TiledGvdStats, tiled_gvd
from terra.graph.tiling import tile_cells
from terra.mapping.semantic_map import MetricSemanticMap
from terra.progress import StageTimer, progress


@dataclass
class GraphBuild:
    """A built scene graph with its counters (for the manifest) and stage timings."""

    graph: SceneGraph
    stats: BuildStats = field(default_factory=BuildStats)
    timer: StageTimer = field(default_factory=StageTimer)
    ground: GroundLayers | None = field(default=None, kw_only=True)  # the ground's geometry layers on the terrain grid


@dataclass
class TerrainPlaceSet:
    """Places of all terrains before linking: positions (P, 3) m, terrain (P,), clearance (P,) m,
    GVD edges (E, 2) with costs (E,) m. After the GVD places, `gap_places` places sit on gaps in
    curbs (terra.graph.crossings), linked to both sides by `gap_links` (k, 2), not by a GVD; the
    last `route_places` places, added once linked, on the bends of level routes
    (terra.graph.level_routes)."""

    position: np.ndarray
    terrain: np.ndarray
    clearance: np.ndarray
    edges: np.ndarray
    weight: np.ndarray
    gap_places: int = 0
    gap_links: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    route_places: int = 0

    def gvd_places(self) -> TerrainPlaceSet:
        """The places of the terrain GVDs alone (those before the gap places)."""
        n = len(self.position) - self.gap_places - self.route_places
        return TerrainPlaceSet(self.position[:n], self.terrain[:n], self.clearance[:n], self.edges, self.weight)


@dataclass
class PlaceCounts:
    """What `terrain_places` counted: places per terrain index, patches too small for a place, and
    the GVD tiling when it was used; places on gaps in curbs count with their terrain."""

    per_terrain: dict[int, int] = field(default_factory=dict)
    patches_dropped: int = 0
    gvd_tiles: GvdTiles | None = None


@dataclass
class PlaceLinks:
    """Every place edge (E, 2) with its cost (E,) m and kind (E,) (EDGE_GVD, ...), plus the counters
    the summary reports: links along grid paths, and bridges that cross no clear line."""

    edges: np.ndarray
    weight: np.ndarray
    kind: np.ndarray
    grid_links: int
    bridges_not_clear: int
    geometry: np.ndarray | None = None  # (E, 5) ground geometry of each edge, once computed


def terrain_places(
    grid: TerrainGrid,
    terrains: list[int],
    config: BuildConfig,
    show_progress: bool = False,
    barrier: np.ndarray | None = None,
    layers: GroundLayers | None = None,
) -> tuple[TerrainPlaceSet, np.ndarray, PlaceCounts]:
    """Places and GVD edges of every terrain in `terrains`, the union of the cleaned terrain masks
    (traversable cells), and per-terrain counters. `barrier` (H, W) bool: cells no terrain's GVD
    runs over (`gvd_barrier`); they stay traversable, so links may still cross them. A place
    stands at its cell's ground height (the grid's), or with `layers`, where its cell holds no
    ground, at the ground across the gap it stands in (terra.graph.ground.heights_in_gaps)."""
    s = grid.cell_size
    positions, terrain_ids, clearances, edges, weights = [], [], [], [], []
    traversable = np.zeros(grid.shape, dtype=bool)
    counts = PlaceCounts()
    tile_stats = TiledGvdStats()
    offset = 0
    min_cells = int(np.ceil(config.grid.min_component_area / (s * s)))
    for t in progress(terrains, "terrain GVDs", enabled=show_progress):
        mask, dropped = grid.terrain_mask(t, config.grid.close_iterations, config.grid.open_iterations, min_cells)
        counts.patches_dropped += dropped
        traversable |= mask
        if not mask.any():
            counts.per_terrain[t] = 0
            del mask  # before the next terrain's mask: one full-grid mask at a time
            continue
        cp = _mask_places(mask & ~barrier if barrier is not None else mask, config, s, tile_stats, grid.blocked)
        xy = grid.cell_centres(cp.cells)
        z = grid.ground_at(cp.cells)
        if layers is not None:
            z = heights_in_gaps(layers, xy, z)
        positions.append(np.column_stack([xy, z]))
        terrain_ids.append(np.full(len(cp.cells), t, dtype=np.int64))
        clearances.append(cp.clearance * s)
        dz = z[cp.edges[:, 0]] - z[cp.edges[:, 1]] if len(cp.edges) else np.zeros(0)
        edges.append(cp.edges + offset)
        weights.append(np.hypot(cp.length * s, dz))
        offset += len(cp.cells)
        counts.per_terrain[t] = int(len(cp.cells))
        del mask
    place_set = TerrainPlaceSet(
        position=np.vstack(positions) if positions else np.zeros((0, 3)),
        terrain=np.concatenate(terrain_ids) if terrain_ids else np.zeros(0, np.int64),
        clearance=np.concatenate(clearances) if clearances else np.zeros(0),
        edges=np.vstack(edges).astype(np.int64) if edges else np.zeros((0, 2), np.int64),
        weight=np.concatenate(weights) if weights else np.zeros(0),
    )
    if tile_stats.windows:
        counts.gvd_tiles = GvdTiles(tile_stats.windows, round(tile_stats.max_margin * s, 3), tile_stats.rounds)
    return place_set, traversable, counts


def _mask_places(
    mask: np.ndarray, config: BuildConfig, cell_size: float, tile_stats: TiledGvdStats, obstacles: np.ndarray
) -> CellPlaces:
    """The places of one terrain mask (extract_places with `build.gvd`, in cells of `cell_size` m),
    no edge's straight segment across an `obstacles` (H, W) cell (the grid's blocked cells)."""
    g, s = config.gvd, cell_size
    return extract_places(
        mask,
        min_clearance=g.min_clearance / s,
        min_gap=g.min_gap / s,
        gvd_result=_tiled_gvd(mask, config, s, tile_stats),
        prune_ratio=g.prune_ratio,
        prune_length=g.prune_length / s,
        junction_merge=g.junction_merge,
        max_deviation=g.max_deviation / s,
        max_distance=g.max_distance / s,
        cover_radius=g.cover_radius / s if g.cover_radius is not None else np.inf,
        obstacles=obstacles,
    )


def gvd_barrier(layers: GroundLayers | None, config: BuildConfig, lidar_only: bool) -> np.ndarray | None:
    """(H, W) bool: on a LiDAR-only map, the lines of cells whose ground step reads above
    `build.ground.barrier_step` (terra.graph.ground.step_lines), which the ground's GVD does not
    cross. Why: a camera map's terrains meet at a curb (sidewalk, road), so each terrain's GVD keeps
    to one level; a LiDAR-only map has one terrain, `ground`, whose GVD ran across curbs anywhere,
    and a wheelchair, refused every such edge, found no way across a road. Split at its steps, the
    ground's GVD keeps to each level and passes between levels where the ground is level (a curb
    cut); each place links to the nearest place across them (place_links). The lines are also
    kept on `layers` (`lines`, `line_step`): an edge over one reads a step of at least
    `barrier_step` (edge_geometry), as the line's own cells read unevenly, and not at all in its
    LiDAR shadow. None on a camera map, without layers, or with `barrier_step` null."""
    step = config.ground.barrier_step
    if not lidar_only or layers is None or step is None:
        return None
    layers.lines, layers.line_step = step_lines(layers, step), step
    return layers.lines


def with_gap_places(
    places: TerrainPlaceSet,
    traversable: np.ndarray,
    grid: TerrainGrid,
    layers: GroundLayers | None,
    config: BuildConfig,
) -> TerrainPlaceSet:
    """`places` with a place on each gap in a curb appended, linked level to both sides
    (terra.graph.crossings); unchanged without ground layers, or with `linking.curb_gap_max_step` None."""
    lk = config.linking
    if layers is None or lk.curb_gap_max_step is None or len(places.position) == 0:
        return places
    rule = CrossingRule(
        lk.curb_gap_max_step, lk.curb_gap_min_width, lk.curb_gap_max_width, lk.max_link_distance, lk.link_candidates
    )
    position, terrain, clearance, links = gap_places(
        grid, traversable, layers, places.position[:, :2], places.terrain, rule
    )
    if len(position) == 0:
        return places
    n = len(places.position)
    return TerrainPlaceSet(
        np.vstack([places.position, position]),
        np.concatenate([places.terrain, terrain]).astype(np.int64),
        np.concatenate([places.clearance, clearance]),
        places.edges,
        places.weight,
        gap_places=len(position),
        gap_links=np.column_stack([links[:, 0] + n, links[:, 1]]).astype(np.int64),
    )


def _tile_cells(config: BuildConfig, shape: tuple[int, int]) -> int | None:
    """Cells per tile side, or None when the grid fits in one tile (then nothing is tiled)."""
    tile = tile_cells(config.tiles.size, config.grid.cell_size)
    return None if tile is None or tile >= max(shape) else tile


def terrain_grid(
    points: np.ndarray,
    point_terrain: np.ndarray,
    config: BuildConfig,
    stats: TiledGridStats | None = None,
    frame: GridFrame | None = None,
) -> TerrainGrid:
    """The terrain grid of the map's points (build_terrain_grid), tile by tile when
    `build.tiles.size` is smaller than the grid (the same grid: terra.graph.tiled_grid, which
    falls back to one piece, saying why in `stats`, when `build.grid.weak_reach` is null), with the
    ground under object outlines blocked (`build.grid.object_extent`, grid.block_under_objects).
    `frame`: `grid_frame` of the points, when the caller has it already (the grid lies on it)."""
    gc = config.grid
    args = (
        points,
        point_terrain,
        gc.cell_size,
        gc.obstacle_height,
        gc.obstacle_min_points,
        gc.support_radius,
        gc.min_support,
    )
    kwargs = {
        "fill_radius": gc.fill_radius,
        "weak_support": gc.weak_support,
        "weak_reach": gc.weak_reach,
        "support_cell": gc.support_cell,
    }
    frame = frame or grid_frame(points, point_terrain, gc.cell_size)
    tile = _tile_cells(config, frame.shape)
    if tile is None:
        grid = build_terrain_grid(*args, **kwargs, frame=frame)
    else:
        margin = int(np.ceil(config.tiles.overlap / gc.cell_size))
        grid = build_terrain_grid_tiled(
            *args, **kwargs, tile=tile, margin=margin, read_radius=gc.close_iterations + 1, stats=stats, frame=frame
        )
    if gc.object_extent is not None:  # on the whole grid: an outline may straddle two tiles
        block_under_objects(grid, gc.object_extent)
    return grid


def _tiled_gvd(
    mask: np.ndarray, config: BuildConfig, cell_size: float, stats: TiledGvdStats
) -> tuple[np.ndarray, np.ndarray] | None:
    """The GVD of one terrain mask tile by tile (terra.graph.tiled_gvd), or None to let
    extract_places compute it in one piece."""
    tile = _tile_cells(config, mask.shape)
    if tile is None:
        return None
    return tiled_gvd(
        mask,
        config.gvd.min_clearance / cell_size,
        config.gvd.min_gap / cell_size,
        tile=tile,
        margin=int(np.ceil(config.tiles.overlap / cell_size)),
        stats=stats,
    )


def strip_links(ps: TerrainPlaceSet, grid: TerrainGrid, config: BuildConfig) -> tuple[np.ndarray, np.ndarray]:
    """Same-terrain links across short gaps between pieces of one terrain strip (linking.py): the
    line may cross at most `strip_max_blocked` metres of blocked cells and `strip_max_gap` metres
    not labelled with the strip's terrain (unlabelled cells count)."""
    lk = config.linking
    if lk.strip_link_distance is None:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    clear = grid_line_passable(grid.blocked, grid.origin, grid.cell_size, lk.strip_max_blocked)
    gap = grid_gap_length(grid.label, grid.origin, grid.cell_size)
    return link_strip_gaps(
        ps.position,
        ps.terrain,
        ps.edges,
        lk.strip_link_distance,
        lk.link_candidates,
        clear=clear,
        gap=gap,
        max_gap=lk.strip_max_gap,
    )


def grid_links(
    ps: TerrainPlaceSet, edges: np.ndarray, grid: TerrainGrid, config: BuildConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Same-terrain links along grid paths between pieces that `edges` (GVD and strip links) leave
    apart (terra.graph.grid_links), and their costs in metres."""
    lk = config.linking
    if lk.grid_link_distance is None:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    rules = GridPathRules(
        grid.label, grid.blocked, grid.origin, grid.cell_size, lk.grid_link_max_gap, lk.grid_link_max_length
    )
    return link_pieces_on_grid(ps.position, ps.terrain, edges, rules, lk.grid_link_distance, lk.link_candidates)


def place_embeddings(
    msm: MetricSemanticMap, position: np.ndarray, terrain: np.ndarray, max_range: float
) -> tuple[np.ndarray, EmbeddingSources]:
    """(P, D) unit image embeddings by the paper's rule, falling back to point embeddings and, for
    places with nothing in range, the terrain's text embedding; counts per source."""
    P, D = len(position), msm.dim
    emb = np.zeros((P, D), np.float32)
    from_images = np.zeros(P, dtype=bool)
    if len(msm.images):
        emb, from_images = image_embeddings(position, msm.images_observing, msm.images.embedding, max_range)
    rest = np.flatnonzero(~from_images)
    if rest.size:
        emb[rest] = point_embeddings(position[rest], msm.points, msm.counts, msm.bank, msm.ms_avg_norms(), max_range)
    from_points = ~from_images & (np.abs(emb).sum(axis=1) > 0)
    none = ~from_images & ~from_points
    emb[none] = np.asarray(msm.terrain_embeddings, np.float32)[terrain[none]]
    return emb, EmbeddingSources(int(from_images.sum()), int(from_points.sum()), int(none.sum()))


def embedding_rule(msm: MetricSemanticMap, max_range: float) -> str:
    """One line for the manifest saying which rule gave the place embeddings."""
    if len(msm.images) == 0:
        return (
            "points: the map has no images, so each place takes the mean MS-Avg feature of the map points "
            f"within {max_range:g} m"
        )
    return (
        f"images: mean whole-image embedding of the images within {max_range:g} m that saw the place "
        f"(else the nearest that saw it; else points within {max_range:g} m)"
    )


def region_assignments(
    position: np.ndarray, embedding: np.ndarray, terrain: np.ndarray, edges: np.ndarray, config: BuildConfig
) -> list[np.ndarray]:
    """Per region level (1 = finest), (P,) region label of every place, by the configured method."""
    r = config.regions
    if r.method == "agglomerative":
        adaptive = AdaptiveCuts(r.levels, r.first_level_size, r.top_regions, r.snap)
        cuts = tuple(r.cuts) if r.cuts is not None else None
        return agglomerative_assignments(
            position,
            embedding,
            terrain,
            r.gamma,
            cuts,
            r.dense_max_places,
            r.micro_max_clusters,
            r.gap_levels,
            adaptive,
        )
    sc = r.spectral
    relative = sc.thresholds == "relative"
    stop = SpectralStop(
        sc.semantic_fraction if relative else sc.max_semantic_diff,
        sc.area_fraction if relative else sc.min_area,
        sc.stop_rule,
        relative,
    )
    return spectral_assignments(
        position,
        embedding,
        edges,
        gamma=r.gamma,
        levels=r.levels,
        stop=stop,
        sigma=sc.sigma,
        min_places=sc.min_places,
        max_depth=sc.max_depth,
        seed=r.seed,
        top=r.top_regions,
    )


def build_scene_graph(
    msm: MetricSemanticMap,
    config: BuildConfig | None = None,
    show_progress: bool = False,
    previous: SceneGraph | None = None,
) -> GraphBuild:
    """The scene graph of a map. TerraError when the map gives nothing to build on.

    `previous`: the graph an earlier build of the bundle gave; its ids are carried to the nodes that
    did not change (places within half a grid cell, see terra.graph.ids) and its objects (`terra
    find --save`) are kept with their ids, each linked to its nearest new place. Without it the
    ids are the indices."""
    config = config or BuildConfig()
    timer = StageTimer()
    lidar_only = not has_terrain_votes(msm)
    ground = None
    if lidar_only:  # LiDAR only: places on the segmented ground, which the grid needs first
        with timer.stage("ground"):
            ground = points_ground(msm.points, config.ground)
        msm = as_ground_terrain(msm, ground)
    names, terrains = terrains_to_build(msm, config)
    grid, grid_stats, layers = _grid_and_layers(msm, ground, names, terrains, config, timer)
    with timer.stage("GVD places"):
        barrier = gvd_barrier(layers, config, lidar_only)
        places, traversable, counts = terrain_places(grid, terrains, config, show_progress, barrier, layers)
        places = with_gap_places(places, traversable, grid, layers, config)
        _count_places(counts, places.terrain[len(places.position) - places.gap_places :])
    if len(places.position) == 0:
        raise TerraError(no_places_reason(lidar_only))
    with timer.stage("links"):
        links = with_level_links(
            place_links(places, traversable, grid, config, barrier), places, traversable, grid, layers, config
        )
    with timer.stage("obstacle points"):
        obstacles = obstacle_points(msm.points, grid, config.grid.obstacle_height)
    with timer.stage("edge ground, place room, level routes"):
        places, links, room = with_level_routes(places, links, grid, layers, config, obstacles)
        _count_places(counts, places.terrain[len(places.position) - places.route_places :])
    with timer.stage("place embeddings"):
        embedding, sources = place_embeddings(msm, places.position, places.terrain, config.embedding.max_range)
    with timer.stage(f"regions ({config.regions.method})"):
        assignments = region_assignments(places.position, embedding, places.terrain, links.edges, config)
        levels = build_levels(assignments, places.position, embedding)
    graph = scene_graph(msm, places, embedding, links, levels, config, room)
    if links.geometry is not None:
        graph.place_edge_geometry = links.geometry
    if previous is not None:
        graph = with_previous_ids(graph, previous, config.grid.cell_size / 2)
    stats = _build_stats(msm, grid, grid_stats, counts, links, sources, config)
    stats.step_line_cells = int(barrier.sum()) if barrier is not None else None
    return GraphBuild(graph, stats, timer, ground=layers)


def _count_places(counts: PlaceCounts, terrain: np.ndarray) -> None:
    """Adds places of `terrain` (k,) to the counts per terrain (gap and route places count with theirs)."""
    for t in terrain:
        counts.per_terrain[int(t)] = counts.per_terrain.get(int(t), 0) + 1


def with_level_links(
    links: PlaceLinks,
    places: TerrainPlaceSet,
    traversable: np.ndarray,
    grid: TerrainGrid,
    layers: GroundLayers | None,
    config: BuildConfig,
) -> PlaceLinks:
    """`links` with the level links of terra.graph.crossings.level_links appended (cross-terrain
    edges costing their straight 3-D length, metres); unchanged without ground layers, or with
    `linking.curb_gap_max_step` or `linking.level_link_distance` None."""
    lk = config.linking
    if layers is None or lk.curb_gap_max_step is None or lk.level_link_distance is None or len(places.position) < 2:
        return links
    new = level_links(
        places.position, places.terrain, links.edges, traversable, grid, layers,
        lk.curb_gap_max_step, lk.level_link_distance, lk.link_candidates,
    )  # fmt: skip
    length = np.linalg.norm(places.position[new[:, 0]] - places.position[new[:, 1]], axis=1)
    return replace(
        links,
        edges=np.vstack([links.edges, new]),
        weight=np.concatenate([links.weight, length]),
        kind=np.concatenate([links.kind, np.full(len(new), EDGE_CROSS_TERRAIN, dtype=links.kind.dtype)]),
    )


def with_level_routes(
    places: TerrainPlaceSet,
    links: PlaceLinks,
    grid: TerrainGrid,
    layers: GroundLayers | None,
    config: BuildConfig,
    obstacles: np.ndarray,
) -> tuple[TerrainPlaceSet, PlaceLinks, np.ndarray]:
    """`places` and `links` with every edge's ground geometry, and the places and edges of the
    routes that join the pieces of the graph over level ground (terra.graph.level_routes)
    appended, and every place's room (P,) metres (terra.graph.room) from the `obstacles` (M, 2)
    (map-frame x, y, metres; `obstacle_points`); no geometry and no routes without ground layers,
    and no routes with `linking.level_route_length` None. The room is read before the routes,
    which take their sources by it, not by the clearance: a hole in the scan beside a place is no
    wall."""
    room = place_room(places.position, obstacles)
    if layers is None or len(places.position) < 2:
        return places, links, room
    geometry = edge_geometry(layers, places.position, links.edges)
    links = replace(links, geometry=geometry)
    lk = config.linking
    if lk.level_route_length is None:
        return places, links, room
    rule = RouteRule(
        lk.level_route_max_step,
        lk.level_route_max_slope,
        MAX_UNOBSERVED,
        lk.level_route_clearance,
        lk.level_route_length,
    )
    new = level_routes(places.position, places.terrain, room, links.edges, geometry, grid, layers, rule)
    places = replace(
        places,
        position=np.vstack([places.position, new.position]),
        terrain=np.concatenate([places.terrain, new.terrain]),
        clearance=np.concatenate([places.clearance, new.clearance]),
        route_places=len(new.position),
    )
    links = replace(
        links,
        edges=np.vstack([links.edges, new.edges]),
        weight=np.concatenate([links.weight, new.length]),
        kind=np.concatenate([links.kind, np.full(len(new.edges), EDGE_LEVEL_ROUTE, dtype=links.kind.dtype)]),
        geometry=np.vstack([geometry, new.geometry]),
    )
    return places, links, np.concatenate([room, place_room(new.position, obstacles)])


def no_places_reason(lidar_only: bool) -> str:
    """The one line for a map that gives no place."""
    if lidar_only:
        return (
            "no patch of LiDAR ground is large enough for a place: the map has no camera terrain semantics (its "
            "images gave none), so places are built on the ground segmented from its points, and too little was "
            "seen (see build.grid.min_component_area)"
        )
    return "no terrain patch is large enough for a place (see build.grid.min_component_area)"


def terrains_to_build(msm: MetricSemanticMap, config: BuildConfig) -> tuple[list[str], list[int]]:
    """The map's terrain class names and the indices of those to build places for
    (`build.terrain.include`, default all); TerraError for a map without terrain classes or an
    included name the map does not have."""
    names = list(msm.terrain_classes)
    if not names:
        raise TerraError(
            "the map lists no terrain classes (manifest 'terrain_classes' is empty); rebuild it with `terra map`"
        )
    if config.terrain.include is None:
        return names, list(range(len(names)))
    unknown = [n for n in config.terrain.include if n not in names]
    if unknown:
        raise TerraError(
            f"build.terrain.include: terrain class {unknown[0]!r} is not in the map (it has: {', '.join(names)})"
        )
    return names, [names.index(n) for n in config.terrain.include]


def _grid_and_layers(
    msm: MetricSemanticMap,
    ground: np.ndarray | None,
    names: list[str],
    terrains: list[int],
    config: BuildConfig,
    timer: StageTimer,
) -> tuple[TerrainGrid, TiledGridStats, GroundLayers | None]:
    """The terrain grid of the map points whose terrain is one of `terrains`, how it was tiled, and
    with `build.ground.layers` the ground layers on it (None without). The layers need of the grid
    only its frame, known before it, and its blocked cells (`layers_on_grid`, at the end): the
    ground's segmentation (unless `ground` (N,) bool gives it, as for a LiDAR-only map, whose grid
    is built on it) and the layers run on a second thread while the grid is built, and on two cores
    add to a build's wall time only what outlasts the grid."""
    point_terrain = _point_terrain(msm, names, terrains, config)
    frame = grid_frame(msm.points, point_terrain, config.grid.cell_size)
    section = config.ground
    beside = None
    if section.layers and len(msm.points) <= section.beside_grid_points and usable_cores() > 1:
        beside = Background(_layers_on_frame, msm.points, ground, frame, section, name="terra-ground")
    with timer.stage("terrain grid"):
        grid_stats = TiledGridStats()
        grid = terrain_grid(msm.points, point_terrain, config, grid_stats, frame)  # on the layers' frame
    del point_terrain  # no later stage reads it
    if not section.layers:
        return grid, grid_stats, None
    with timer.stage("ground layers"):
        layers = beside.result() if beside is not None else _layers_on_frame(msm.points, ground, frame, section)
        gc = config.grid
        layers = layers_on_grid(layers, grid, msm.points, band=gc.obstacle_height, min_points=gc.obstacle_min_points)
        return grid, grid_stats, layers


def _point_terrain(msm: MetricSemanticMap, names: list[str], terrains: list[int], config: BuildConfig) -> np.ndarray:
    """(N,) int16 terrain index of each map point that the grid is built on (one of `terrains`,
    with a vote share of at least `terrain.min_share`), -1 for the others; TerraError when none is."""
    point_terrain = msm.terrain_index(config.terrain.min_share, dtype=np.int16)  # 2 bytes a point
    point_terrain[~np.isin(point_terrain, terrains)] = -1
    if not (point_terrain >= 0).any():
        raise TerraError(
            f"the map has no terrain points (of {', '.join(names[t] for t in terrains)}) "
            f"with a vote share >= {config.terrain.min_share}"
        )
    return point_terrain


def _layers_on_frame(
    points: np.ndarray, ground: np.ndarray | None, frame: GridFrame, section: GroundSection
) -> GroundLayers:
    """The ground layers of the map points (N, 3) (metres) on `frame`, before the grid's blocked
    cells are known (`ground_layers`); `ground` (N,) bool, or None to segment the points first."""
    if ground is None:
        ground = points_ground(points, section)
    return ground_layers(np.asarray(points)[ground], frame)


def place_links(
    places: TerrainPlaceSet,
    traversable: np.ndarray,
    grid: TerrainGrid,
    config: BuildConfig,
    barrier: np.ndarray | None = None,
) -> PlaceLinks:
    """Every edge between places: the GVD edges, strip and grid-path links within a terrain, then
    dead-end links across terrains, links across the lines of steps of `barrier` (H, W) bool
    (`gvd_barrier`: each place to the nearest place beyond one within
    `build.linking.step_link_distance`, for the robots that climb them), and bridges between
    components; unique, cheapest kept."""
    lk = config.linking
    clear = grid_line_clear(traversable, grid.origin, grid.cell_size) if lk.require_clear_line else None
    kwargs = {"clear": clear} if clear is not None else {}
    gvd = places.gvd_places()  # gap places are no pieces of a terrain's strip
    strips, strip_len = strip_links(gvd, grid, config)
    gvd_edges, gvd_weight = np.vstack([places.edges, strips]), np.concatenate([places.weight, strip_len])
    paths, path_len = grid_links(gvd, gvd_edges, grid, config)
    gvd_edges, gvd_weight = np.vstack([gvd_edges, paths]), np.concatenate([gvd_weight, path_len])
    gaps = places.gap_links
    gap_len = np.linalg.norm(places.position[gaps[:, 0]] - places.position[gaps[:, 1]], axis=1)
    links, link_len = link_dead_ends(
        places.position,
        places.terrain,
        np.vstack([gvd_edges, gaps]),
        lk.max_link_distance,
        lk.link_candidates,
        **kwargs,
    )
    if barrier is not None and lk.step_link_distance is not None:  # across the lines of steps
        across = grid_line_crosses(barrier, grid.origin, grid.cell_size)
        steps, step_len = link_across(places.position, lk.step_link_distance, lk.link_candidates, across, **kwargs)
        links, link_len = np.vstack([links, steps]), np.concatenate([link_len, step_len])
    edges = np.vstack([gvd_edges, gaps, links])
    weight = np.concatenate([gvd_weight, gap_len, link_len])
    kind = np.concatenate([np.full(len(gvd_edges), EDGE_GVD), np.full(len(gaps) + len(links), EDGE_CROSS_TERRAIN)])
    bridges, bridge_cost, bridge_clear = bridge_components(
        places.position, edges, lk.bridge_penalty, lk.link_candidates, **kwargs
    )
    edges = np.vstack([edges, bridges])
    weight = np.concatenate([weight, bridge_cost])
    kind = np.concatenate([kind, np.full(len(bridges), EDGE_BRIDGE)])
    edges, weight, kind = unique_typed_edges(edges, weight, kind)
    return PlaceLinks(edges, weight, kind, len(paths), int((~bridge_clear).sum()))


def scene_graph(
    msm: MetricSemanticMap,
    places: TerrainPlaceSet,
    embedding: np.ndarray,
    links: PlaceLinks,
    levels: list[RegionLevel],
    config: BuildConfig,
    room: np.ndarray | None = None,
) -> SceneGraph:
    """The SceneGraph of built places, their embeddings (P, D), links and region levels (ids =
    indices); `room` (P,) metres to the nearest obstacle (terra.graph.room), unknown without."""
    return SceneGraph(
        terrain_classes=list(msm.terrain_classes),
        terrain_embeddings=np.asarray(msm.terrain_embeddings, dtype=np.float32),
        places=Places(
            places.position.astype(np.float64),
            places.terrain.astype(np.int64),
            places.clearance.astype(np.float64),
            embedding.astype(np.float32),
            room=None if room is None else np.asarray(room, dtype=np.float64),
        ),
        place_edges=links.edges,
        place_edge_weight=links.weight,
        place_edge_kind=links.kind,
        regions=levels,
        embedder=msm.embedder,
        region_method=config.regions.method,
    )


def with_previous_ids(graph: SceneGraph, previous: SceneGraph, tolerance: float) -> SceneGraph:
    """`graph` with the previous build's objects (linked to their nearest new place, 2-D) and the
    ids of the previous build carried over."""
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

    from terra.graph.ids import carry_ids

    kept = previous.objects
    if len(kept):
        place = cKDTree(graph.places.position[:, :2]).query(np.asarray(kept.center)[:, :2])[1]
        graph = replace(graph, objects=replace(kept, place=np.asarray(place, dtype=np.int64)))
    return carry_ids(graph, previous, tolerance)


def _build_stats(
    msm: MetricSemanticMap,
    grid: TerrainGrid,
    grid_stats: TiledGridStats,
    counts: PlaceCounts,
    links: PlaceLinks,
    sources: EmbeddingSources,
    config: BuildConfig,
) -> BuildStats:
    """The build's counters, as the manifest and `terra build` report them."""
    names, kind = list(msm.terrain_classes), links.kind
    grid_tiles = None
    if grid_stats.windows or grid_stats.one_piece:
        overlap = round(grid_stats.max_margin * config.grid.cell_size, 3)
        grid_tiles = GridTiles(grid_stats.windows, overlap, grid_stats.one_piece)
    return BuildStats(
        places_per_terrain={names[t]: n for t, n in counts.per_terrain.items()},
        patches_dropped=counts.patches_dropped,
        grid_cells=(int(grid.shape[0]), int(grid.shape[1])),
        blocked_cells=int(grid.blocked.sum()),
        edges=EdgeCounts.of(kind),
        grid_links=links.grid_links,
        bridges_not_clear=links.bridges_not_clear,
        embedding_source=sources,
        embedding_rule=embedding_rule(msm, config.embedding.max_range),
        grid_tiles=grid_tiles,
        gvd_tiles=counts.gvd_tiles,
    )


def unique_typed_edges(
    edges: np.ndarray, weight: np.ndarray, kind: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unique (i < j) edges keeping the cheapest (lowest kind on ties), ordered by (i, j)."""
    rows = unique_edge_rows(edges, weight, kind)
    return np.sort(edges, axis=1)[rows].astype(np.int64), weight[rows].astype(np.float64), kind[rows].astype(np.int64)


def _check_bundle(bundle: Bundle) -> None:
    from terra.mapping.chunks import is_chunked  # a live version keeps its map in row chunks

    if not bundle.has_component("map") or not (bundle.has("map/points") or is_chunked(bundle)):
        raise TerraError(f"{bundle.path}: the bundle has no map; build one with `terra map` first")


def previous_graph(bundle: Bundle) -> SceneGraph | None:
    """The bundle's current scene graph, whose ids the rebuild keeps; None when it has none or it
    cannot be read (a damaged or unsupported graph is what a rebuild replaces; its ids restart)."""
    from terra.graph.storage import load_scene_graph

    if not bundle.has_component("graph"):
        return None
    try:
        return load_scene_graph(bundle)
    except TerraError:
        return None


def build_graph(
    bundle_path: Path, config: BuildConfig | None = None, regions: str | None = None, progress: bool = True
) -> SceneGraph:
    """Build the scene graph of the map in `bundle_path` and add it to the bundle (atomically)."""
    return run_build(bundle_path, config, regions, progress).graph


def run_build(
    bundle_path: Path, config: BuildConfig | None = None, regions: str | None = None, show_progress: bool = True
) -> GraphBuild:
    """`build_graph` with its counters and timings (used by `terra build` for the summary)."""
    from terra.mapping.storage import load_map

    config = config or BuildConfig()
    if regions is not None:
        method = check_region_method(regions)
        config = config.model_copy(update={"regions": config.regions.model_copy(update={"method": method})})
    bundle = Bundle(bundle_path)
    _check_bundle(bundle)
    timer = StageTimer()
    with timer.stage("load map"):
        msm = load_map(bundle, max_ids=False)  # the build never reads the MS-Max ids
    result = build_scene_graph(msm, config, show_progress, previous=previous_graph(bundle))
    for name, seconds in result.timer.seconds.items():
        timer.add(name, seconds)
    with timer.stage("write"):
        commit_graph(bundle, result, config)
    result.timer = timer
    return result


def commit_graph(bundle: Bundle, result: GraphBuild, config: BuildConfig, **extra: Any) -> None:
    """Write `result` as component `graph/` of the bundle's next version (atomically), recording
    the config, the counters, the map version it was built on and any `extra` manifest entries."""
    from terra.graph.ground import write_ground_layers
    from terra.graph.storage import write_scene_graph

    with BundleWriter(bundle.path, base=bundle, drop_components=("graph",)) as writer:
        map_info = bundle.model.components.map
        info = {
            "config": config.model_dump(mode="json"),
            "stats": result.stats.to_json(),
            "map_version": map_info.version if map_info is not None and map_info.version is not None else 0,
            **extra,
        }
        write_scene_graph(writer, result.graph, info)
        if result.ground is not None:
            write_ground_layers(writer, result.ground)
