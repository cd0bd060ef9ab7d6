"""Configuration of Phase 2 (`terra build`): terrain places, links and regions.

Defaults are the paper's simulation/campus values (0.4 m cells, max_deviation 3.75 m,
max_distance 10 m, gamma 100), except where they do not carry over to other maps and embedders:
region levels adapt to the map (the paper's cuts 50/100/200/400 and spectral 0.45 / 10,000 m^2
remain one setting away: `regions.cuts`, `regions.spectral.thresholds: absolute`).
"""

from __future__ import annotations

from typing import Literal, get_args

from pydantic import Field, field_validator, model_validator

from terra.errors import TerraError
from terra.schemas import Section

RegionMethod = Literal["agglomerative", "spectral"]
REGION_METHODS: tuple[RegionMethod, ...] = get_args(RegionMethod)  # the one list of region methods


def check_region_method(method: str) -> RegionMethod:
    """`method` when it names a region method (the --regions flag, `run_build(regions=...)`), else TerraError."""
    for known in REGION_METHODS:
        if method == known:
            return known
    raise TerraError(f"--regions must be {' or '.join(repr(m) for m in REGION_METHODS)}, got {method!r}")


class TerrainSection(Section):
    """Terrain class per map point from its terrain votes."""

    min_share: float = Field(
        default=0.5, ge=0.0, le=1.0, description="a point's winning terrain needs this share of its votes"
    )
    include: list[str] | None = Field(
        default=None, description="terrain classes to build places for (None = all of the map's)"
    )


class GridSection(Section):
    """One 2D occupancy grid per terrain class."""

    cell_size: float = Field(default=0.4, gt=0.0, description="metres per grid cell")
    support_radius: float = Field(
        default=1.6,
        ge=0.0,
        description=(
            "metres; each cell takes the majority terrain of the cells within this half-window (0 = its own points "
            "only)"
        ),
    )
    min_support: float = Field(
        default=0.6,
        ge=0.0,
        le=1.0,
        description=(
            "share of the window's cells that must hold labelled terrain points for the cell to take their majority; "
            "for filling and weak_support, the share that must hold ground points, labelled or not (drops sparse "
            "distant scan rings)"
        ),
    )
    support_cell: float | None = Field(
        default=0.4,
        gt=0.0,
        description=(
            "metres; min_support and weak_support are shares of the window's area, counted on sub-cells of about this "
            "size, so they mean the same ground at every cell size (None = shares of whole cells: a coarse grid then "
            "keeps sparse distant scan rings a fine one drops)"
        ),
    )
    weak_support: float | None = Field(
        default=0.1,
        ge=0.0,
        le=1.0,
        description=(
            "a window with this smaller share of labelled cells also takes their majority where it continues a patch of"
            " that class meeting min_support (hysteresis: sparsely labelled stretches of a strip keep its class; "
            "isolated noisy patches do not); None = never"
        ),
    )
    weak_reach: float | None = Field(
        default=16.0,
        gt=0.0,
        description=(
            "metres; such cells are labelled at most this far (along the sparsely labelled chain) from the patch they "
            "continue (None = any distance)"
        ),
    )
    fill_radius: float = Field(
        default=2.0,
        ge=0.0,
        description=(
            "metres; densely scanned ground no camera labelled takes the class of the labelled cells within this "
            "distance when they all agree (0 = never)"
        ),
    )
    close_iterations: int = Field(
        default=1,
        ge=0,
        description=(
            "3x3 closings of each terrain mask (the paper's opening of the obstacle mask: fills sparse-point holes)"
        ),
    )
    open_iterations: int = Field(
        default=1, ge=0, description="3x3 openings of each terrain mask (removes slivers one or two cells wide)"
    )
    obstacle_height: tuple[float, float] | None = Field(
        default=(0.3, 2.0),
        description=(
            "points this many metres above the local ground block a cell: points without a terrain class above the "
            "terrain points' height, and any point above the segmented ground's (None = never)"
        ),
    )
    obstacle_min_points: int = Field(default=2, ge=1, description="points in the height band needed to block a cell")
    object_extent: float | None = Field(
        default=6.0,
        gt=0.0,
        description=(
            "metres; free cells inside the convex hull of a blocked outline at most this long on each side (a parked "
            "car seen from one side: its near side blocked, the ground under its body free) are blocked (None = never)"
        ),
    )
    min_component_area: float = Field(
        default=2.0, ge=0.0, description="terrain patches smaller than this (m^2) get no place (reported as dropped)"
    )

    @field_validator("obstacle_height")
    @classmethod
    def _band(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and not v[0] < v[1]:
            raise ValueError("obstacle_height must be (low, high) with low < high, metres above ground")
        return v


class TilesSection(Section):
    """The terrain grid and the per-terrain GVD computed one tile (plus an overlap) at a time, so
    `terra build`'s working memory follows the tile, not the map. The result is the same as in one
    piece: each tile's overlap grows until that is proven (terra.graph.tiled_grid, tiled_gvd)."""

    size: float | None = Field(
        default=400.0, gt=0.0, description="metres; side of a square tile (None = the whole grid in one piece)"
    )
    overlap: float = Field(
        default=50.0,
        gt=0.0,
        description=(
            "metres of overlap tried first around each tile; doubled where a tile's result is not yet proven equal to "
            "the one-piece result"
        ),
    )


class GvdSection(Section):
    """Per-terrain generalized Voronoi diagram and place extraction on it."""

    min_clearance: float = Field(
        default=0.4, ge=0.0, description="GVD cells need at least this distance (m) to the terrain's boundary"
    )
    min_gap: float = Field(
        default=0.6,
        ge=0.0,
        description=(
            "metres; two nearest obstacle points of one obstacle component count as different walls only with this much"
            " clearance at their midpoint (rejects steps of one digitised wall)"
        ),
    )
    prune_ratio: float = Field(
        default=1.5,
        ge=0.0,
        description=(
            "dead-end branches shorter than prune_ratio * junction clearance + prune_length are removed (corner spurs)"
        ),
    )
    prune_length: float = Field(default=1.0, ge=0.0, description="metres, see prune_ratio")
    junction_merge: float = Field(
        default=1.0,
        ge=0.0,
        description="junctions joined by a GVD path shorter than this times their clearance become one node",
    )
    max_deviation: float = Field(
        default=3.75,
        gt=0.0,
        description=(
            "metres; a GVD path is split where it strays further than this from its chord (and wherever its chord "
            "crosses a blocked cell)"
        ),
    )
    max_distance: float = Field(
        default=10.0, gt=0.0, description="metres; paths with a longer chord are split near their middle"
    )
    cover_radius: float | None = Field(
        default=5.0,
        gt=0.0,
        description=(
            "metres; a pruned GVD branch reaching farther than this from the kept GVD (into a pocket: a service pad, a "
            "plaza) is restored so the pocket gets a place (None = never)"
        ),
    )


class LinkingSection(Section):
    """Cross-terrain links and bridges that make the places graph connected."""

    max_link_distance: float = Field(
        default=20.0,
        gt=0.0,
        description="metres; a dead end links to the nearest place of another terrain within this range",
    )
    link_candidates: int = Field(
        default=8,
        ge=1,
        description="nearest other-terrain places tried per dead end (the first with a clear line wins)",
    )
    require_clear_line: bool = Field(
        default=True, description="links may only cross mapped terrain cells, never blocked or unmapped ones"
    )
    bridge_penalty: float = Field(
        default=100.0,
        ge=1.0,
        description="bridges between otherwise disconnected components cost their length times this",
    )
    strip_link_distance: float | None = Field(
        default=12.0,
        gt=0.0,
        description=(
            "metres; a dead end of one terrain's places links to the nearest same-terrain place of another piece within"
            " this range, across a gap (None = never)"
        ),
    )
    strip_max_gap: float = Field(
        default=4.0,
        ge=0.0,
        description=(
            "metres; such a link may cross at most this much of cells not labelled with its terrain (a stretch the "
            "cameras missed or took for something else, not a road between two sidewalks)"
        ),
    )
    strip_max_blocked: float = Field(
        default=0.8,
        ge=0.0,
        description="metres; and at most this much of blocked cells (a post or a trunk standing on the strip)",
    )
    grid_link_distance: float | None = Field(
        default=12.0,
        gt=0.0,
        description=(
            "metres; places of one terrain in different pieces of its places graph this close (2D) are joined by a path"
            " on the terrain grid where one is allowed (terra.graph.grid_links; None = never)"
        ),
    )
    grid_link_max_gap: float = Field(
        default=4.0,
        ge=0.0,
        description=(
            "metres; such a path may cross at most this much of unlabelled free cells (never blocked cells or another "
            "terrain's)"
        ),
    )
    grid_link_max_length: float = Field(
        default=30.0, gt=0.0, description="metres; and be at most this long (the link costs the path's length)"
    )
    curb_gap_max_step: float | None = Field(
        default=0.04,
        ge=0.0,
        description=(
            "metres; a stretch of the boundary between two terrains whose step is at most this, inside a line of "
            "higher steps (a curb cut, a driveway), gets a place linked level to both sides (terra.graph.crossings; "
            "needs ground.layers; None = never)"
        ),
    )
    curb_gap_min_width: float = Field(default=1.0, gt=0.0, description="metres; the narrowest such gap")
    level_link_distance: float | None = Field(
        default=6.0,
        gt=0.0,
        description=(
            "metres; a place that the edges whose step is at most curb_gap_max_step cannot take to another terrain "
            "nearby links to the nearest place of another terrain within this range along a clear line over observed, "
            "level ground (terra.graph.crossings.level_links; needs ground.layers; None = never)"
        ),
    )
    step_link_distance: float | None = Field(
        default=15.0,
        gt=0.0,
        description=(
            "LiDAR-only maps, metres: every place links to the nearest place beyond a line of steps that split the "
            "ground's GVD (ground.barrier_step) within this range along a clear line; each robot's profile judges the "
            "step, read at least barrier_step (a legged robot takes a curb, a wheelchair does not; None = no links "
            "across the lines: the ground's sides meet where it is level, and by bridges)"
        ),
    )
    curb_gap_max_width: float = Field(
        default=12.0, gt=0.0, description="metres; the widest (a longer level stretch is no gap in a curb)"
    )
    level_route_length: float | None = Field(
        default=40.0,
        gt=0.0,
        description=(
            "metres; pieces of the places graph that no level edge joins are joined by routes of at most this length "
            "over level ground, with a place at each bend (terra.graph.level_routes; needs ground.layers; None = never)"
        ),
    )
    level_route_max_step: float = Field(
        default=0.05,
        ge=0.0,
        description="metres; the largest step a level edge or route crosses (the wheelchair profile's, the strictest)",
    )
    level_route_max_slope: float = Field(
        default=8.0, ge=0.0, le=90.0, description="degrees; the steepest rise or fall of a level edge or route"
    )
    level_route_clearance: float = Field(
        default=0.45,
        ge=0.0,
        description="metres of level ground a route keeps on each side (half the wheelchair profile's width)",
    )

    @model_validator(mode="after")
    def _gap_widths(self) -> LinkingSection:
        if self.curb_gap_min_width > self.curb_gap_max_width:
            raise ValueError("curb_gap_min_width must be at most curb_gap_max_width")
        return self


class EmbeddingSection(Section):
    """Image embedding of each place (the paper's rule)."""

    max_range: float = Field(
        default=20.0,
        gt=0.0,
        description="metres; images taken within this range whose camera saw the place are averaged",
    )


class SpectralSection(Section):
    """Recursive two-way spectral splits of the places graph.

    Stopping thresholds are relative to the map by default (`thresholds: relative`): a cluster
    stops splitting once its semantic difference is below `semantic_fraction` times the whole
    map's, or its 2D bounding box below `area_fraction` times the map's. The semantic difference
    of the same places is about 0.45 with CLIP image embeddings and 0.18 with the text embedder, so
    the paper's absolute values (`thresholds: absolute`: `max_semantic_diff`, `min_area`) only
    split maps built with the embedder and at the size they were chosen for.
    """

    thresholds: Literal["relative", "absolute"] = Field(
        default="relative",
        description="'relative' to the map's own semantic difference and area, or the paper's 'absolute' values",
    )
    semantic_fraction: float = Field(
        default=0.3,
        gt=0.0,
        le=1.0,
        description="relative: stop below this share of the whole map's semantic difference",
    )
    area_fraction: float = Field(
        default=0.01,
        gt=0.0,
        le=1.0,
        description="relative: stop below this share of the whole map's 2D bounding-box area",
    )
    max_semantic_diff: float = Field(
        default=0.45,
        ge=0.0,
        description="absolute: a cluster with a smaller semantic difference stops splitting (the paper's CLIP value)",
    )
    min_area: float = Field(
        default=10000.0, ge=0.0, description="absolute: m^2; a cluster whose 2D bounding box is smaller stops splitting"
    )
    stop_rule: Literal["either", "both"] = Field(
        default="either",
        description="'either' (the paper): stop when one test holds; 'both' (the reference code): only when both hold",
    )
    sigma: float | None = Field(
        default=None, gt=0.0, description="affinity exp(-w / sigma) on place edges; None = median edge weight"
    )
    min_places: int = Field(default=4, ge=2, description="clusters with fewer places are not split")
    max_depth: int = Field(default=24, ge=1, description="safety cap on the recursion depth")


class RegionsSection(Section):
    """Hierarchical region levels above the places.

    Agglomerative levels are adaptive by default (`cuts: null`): level 1 has about
    places / `first_level_size` regions, the top level `top_regions`, the levels between a
    geometric progression, each cut at a natural break of the tree's merge heights, so every level
    carries information on any map (terra.graph.agglomerative). `cuts: [50, 100, 200, 400]` gives
    the paper's fixed heights exactly. Spectral levels: the leaves of the split tree, then the
    clusters after fewer and fewer splits (largest first), with the same counts rule above them.
    """

    method: RegionMethod = "agglomerative"
    gamma: float = Field(default=100.0, ge=0.0, description="weight w = |p_i - p_j| (m) + gamma * (1 - cos(e_i, e_j))")
    cuts: list[float] | None = Field(
        default=None,
        max_length=8,
        description=(
            "agglomerative cut heights, one region level each, increasing (the paper: 50, 100, 200, 400); None = "
            "adaptive levels"
        ),
    )
    gap_levels: int | None = Field(
        default=None,
        ge=1,
        le=8,
        description=(
            "instead of `cuts`: this many levels cut just below the largest merge-height gaps (the reference's integer "
            "agg_params; not the paper's default)"
        ),
    )
    levels: int = Field(
        default=4, ge=1, le=8, description="region levels of the adaptive agglomerative cuts and of spectral regions"
    )
    first_level_size: float = Field(
        default=12.0, gt=1.0, description="adaptive levels: about this many places per level-1 region"
    )
    top_regions: int = Field(
        default=3, ge=1, description="adaptive levels: regions of the top level (fewer on maps too small for them)"
    )
    snap: float = Field(
        default=1.25,
        ge=1.0,
        description=(
            "adaptive agglomerative cuts move within this factor of each level's count to a natural break of the merge "
            "heights (1 = exact counts)"
        ),
    )
    dense_max_places: int = Field(
        default=5000,
        ge=2,
        description=(
            "exact average linkage on a condensed P x P matrix up to this many places; above, on micro-clusters"
        ),
    )
    micro_max_clusters: int = Field(
        default=5000,
        ge=2,
        description="micro-clusters (terrain x grid cell) used above dense_max_places, at most this many",
    )
    seed: int = 0
    spectral: SpectralSection = Field(default_factory=SpectralSection)

    @field_validator("cuts")
    @classmethod
    def _increasing(cls, v: list[float] | None) -> list[float] | None:
        if v is not None and (not v or any(b <= a for a, b in zip(v, v[1:])) or v[0] <= 0):
            raise ValueError(
                "cuts must be a non-empty list of increasing positive numbers (or null for adaptive levels)"
            )
        return v


class GroundSection(Section):
    """Ground from the LiDAR points (terra.graph.ground): the segmentation of the map's points and
    the geometry layers (height, slope, step, roughness) on the terrain grid."""

    cell_size: float = Field(
        default=0.5, gt=0.0, description="metres per cell of the segmentation's lowest-point surface"
    )
    windows: list[float] = Field(
        default_factory=lambda: [1.0, 2.0, 4.0, 8.0],
        description="metres: widths of the growing openings that remove what stands on the ground (increasing)",
    )
    slope: float = Field(
        default=0.2, ge=0.0, description="metres of height a cell may rise per metre of window growth and stay ground"
    )
    base_height: float = Field(
        default=0.1, ge=0.0, description="metres a cell may always rise above the opened surface and stay ground"
    )
    max_height: float = Field(default=2.5, gt=0.0, description="metres: the most a cell may rise and stay ground")
    tolerance: float = Field(
        default=0.15, gt=0.0, description="metres above the ground surface (the cell's lowest point) a point is ground"
    )
    standing_tolerance: float | None = Field(
        default=0.05,
        gt=0.0,
        description="metres: the same in a cell where something stands (a point 0.3-2 m above its lowest), whose "
        "foot would pass for ground (null: `tolerance` everywhere)",
    )
    layers: bool = Field(
        default=True,
        description="compute the geometry layers and per-edge step and slope (false: none, as before; `plan --robot` "
        "then has nothing to check)",
    )
    beside_grid_points: int = Field(
        default=2_000_000,
        ge=0,
        description="maps of at most this many points segment their ground and compute the layers on a second "
        "thread while the terrain grid is built: on two cores the layers then add about half as much to a build's "
        "wall time, and about 90 bytes a map point to its peak memory; larger maps (and 0, or a single core) "
        "compute them one after the other, the peak first",
    )
    barrier_step: float | None = Field(
        default=0.08,
        gt=0.0,
        description="LiDAR-only maps, metres: a line of ground cells whose step reads above this (a curb, the foot "
        "of a low wall) splits the ground's GVD, so places keep to each level and pass between levels where the "
        "ground is level (a curb cut); needs `layers` (null: the GVD of the ground crosses steps)",
    )

    @field_validator("windows")
    @classmethod
    def _increasing(cls, v: list[float]) -> list[float]:
        if not v or any(b <= a for a, b in zip(v, v[1:])) or v[0] <= 0:
            raise ValueError("windows must be a non-empty list of increasing positive widths, metres")
        return v


class UpdateSection(Section):
    """Incremental updates of a live map's graph (terra.graph.update): only the tiles around what
    changed since the previous version are rebuilt; a live session's last graph is a full build."""

    tile: float = Field(
        default=8.0, gt=0.0, description="metres; side of the fixed squares that mark where the map changed"
    )
    min_changed_points: int = Field(
        default=200,
        ge=1,
        description=(
            "a tile is rebuilt once it holds this many changed map points (the ground and objects near the robot); "
            "sparser changes (far returns, voxel means that moved) wait for more, or for the next sweep"
        ),
    )
    sweep_every: int = Field(
        default=10,
        ge=0,
        description=(
            "every this many updates, the tiles holding fewer than min_changed_points changed points are rebuilt "
            "too, so no change waits longer (0: they wait for more, or for the closing full build)"
        ),
    )
    max_pending_points: int = Field(
        default=1_000_000,
        ge=0,
        description="changed points waiting in tiles below min_changed_points before a full build",
    )
    replace_margin: float = Field(
        default=8.0, ge=0.0, description="metres around the changed tiles whose places are rebuilt"
    )
    context_margin: float = Field(
        default=8.0,
        ge=0.0,
        description="metres of map read around the rebuilt area (the GVD of a free area wider than this may differ)",
    )
    max_crop_side: float = Field(
        default=96.0,
        gt=0.0,
        description=(
            "metres; a rebuilt part longer than this whose bounding box it fills less than half of (a band along the "
            "drive, as a sweep gives) is cut into squares of this side, each read with a crop of its own"
        ),
    )
    move_tolerance: float = Field(
        default=0.05, ge=0.0, description="metres a map point may move (its voxel mean) before it counts as changed"
    )
    stitch_distance: float = Field(
        default=4.0,
        gt=0.0,
        description="metres; an edge cut by the rebuilt area's border joins the nearest place this close",
    )
    full_fraction: float = Field(
        default=0.6,
        gt=0.0,
        le=1.0,
        description=(
            "a full build instead, once the crops to read cover this share of the map's extent (an update would cost "
            "as much, and the full build is exact)"
        ),
    )
    recluster_fraction: float = Field(
        default=0.25,
        gt=0.0,
        le=1.0,
        description=(
            "regions are re-clustered in full once this share of the places changed since the last full clustering"
        ),
    )


class BuildConfig(Section):
    terrain: TerrainSection = Field(default_factory=TerrainSection)
    grid: GridSection = Field(default_factory=GridSection)
    tiles: TilesSection = Field(default_factory=TilesSection)
    gvd: GvdSection = Field(default_factory=GvdSection)
    linking: LinkingSection = Field(default_factory=LinkingSection)
    embedding: EmbeddingSection = Field(default_factory=EmbeddingSection)
    regions: RegionsSection = Field(default_factory=RegionsSection)
    ground: GroundSection = Field(default_factory=GroundSection)
    update: UpdateSection = Field(default_factory=UpdateSection)
