"""What Phase 2 returns: the counters of a scene graph build (`BuildStats`, also written to manifest
components.graph.stats) and `BuildResult`, the summary of `terra build` whose `to_json()` is its
`--json` output. Text rendering lives in terra/cli/render_stages.py; `from_json` reads the JSON back
into the same result (for callers of `--json`; nothing in Terra parses its own output)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # a result is built and read without the graph modules
    import numpy as np

    from terra.graph.scene_graph import SceneGraph
    from terra.progress import StageTimer


@dataclass
class EdgeCounts:
    """Place edges by kind."""

    gvd: int = 0
    cross_terrain: int = 0
    bridge: int = 0
    level_route: int = 0

    def to_json(self) -> dict[str, int]:
        return {
            "gvd": self.gvd,
            "cross_terrain": self.cross_terrain,
            "bridge": self.bridge,
            "level_route": self.level_route,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> EdgeCounts:
        # level_route: absent from manifests written before routes were built
        return cls(int(data["gvd"]), int(data["cross_terrain"]), int(data["bridge"]), int(data.get("level_route", 0)))

    @classmethod
    def of(cls, kind: np.ndarray) -> EdgeCounts:
        """The counts of place edge kinds (E,) (terra.graph.scene_graph.EDGE_KINDS, in field order)."""
        from terra.graph.scene_graph import EDGE_KINDS

        return cls(*(int((kind == k).sum()) for k in EDGE_KINDS))


@dataclass
class EmbeddingSources:
    """Places whose embedding came from images, from map points, or from the terrain's name."""

    images: int = 0
    points: int = 0
    terrain_text: int = 0

    def to_json(self) -> dict[str, int]:
        return {"images": self.images, "points": self.points, "terrain_text": self.terrain_text}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> EmbeddingSources:
        return cls(int(data["images"]), int(data["points"]), int(data["terrain_text"]))


@dataclass
class GridTiles:
    """How the terrain grid was built: tile windows, the widest overlap (m), and, when it was built
    in one piece although tiles were asked for, why."""

    windows: int
    max_overlap_m: float
    one_piece: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {"windows": self.windows, "max_overlap_m": self.max_overlap_m, "one_piece": self.one_piece}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> GridTiles:
        return cls(int(data["windows"]), float(data["max_overlap_m"]), data.get("one_piece"))


@dataclass
class GvdTiles:
    """How the GVDs were computed tile by tile: windows, the widest overlap (m), thinning rounds."""

    windows: int
    max_overlap_m: float
    thinning_rounds: int

    def to_json(self) -> dict[str, Any]:
        return {"windows": self.windows, "max_overlap_m": self.max_overlap_m, "thinning_rounds": self.thinning_rounds}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> GvdTiles:
        return cls(int(data["windows"]), float(data["max_overlap_m"]), int(data["thinning_rounds"]))


@dataclass
class BuildStats:
    """The counters of one build: places per terrain name, terrain patches too small for a place,
    grid size (rows, cols) and blocked cells, edges by kind, grid-path links, bridges without a clear
    line, where the place embeddings came from (and the rule, in words), the tiling when used, and
    on a LiDAR-only map the cells of the lines of steps that split its ground's GVD."""

    places_per_terrain: dict[str, int] = field(default_factory=dict)
    patches_dropped: int = 0
    grid_cells: tuple[int, int] = (0, 0)
    blocked_cells: int = 0
    edges: EdgeCounts = field(default_factory=EdgeCounts)
    grid_links: int = 0
    bridges_not_clear: int = 0
    embedding_source: EmbeddingSources = field(default_factory=EmbeddingSources)
    embedding_rule: str = ""
    grid_tiles: GridTiles | None = None
    gvd_tiles: GvdTiles | None = None
    # LiDAR-only maps: cells of the lines of steps that split the ground's GVD (pipeline.gvd_barrier)
    step_line_cells: int | None = None

    def to_json(self) -> dict[str, Any]:
        data: dict[str, Any] = {
            "places_per_terrain": dict(self.places_per_terrain),
            "patches_dropped": self.patches_dropped,
            "grid_cells": list(self.grid_cells),
            "blocked_cells": self.blocked_cells,
            "edges": self.edges.to_json(),
            "grid_links": self.grid_links,
            "bridges_not_clear": self.bridges_not_clear,
            "embedding_source": self.embedding_source.to_json(),
            "embedding_rule": self.embedding_rule,
        }
        if self.grid_tiles is not None:
            data["grid_tiles"] = self.grid_tiles.to_json()
        if self.gvd_tiles is not None:
            data["gvd_tiles"] = self.gvd_tiles.to_json()
        if self.step_line_cells is not None:
            data["step_line_cells"] = self.step_line_cells
        return data

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> BuildStats:
        rows, cols = data["grid_cells"]
        grid_tiles, gvd_tiles = data.get("grid_tiles"), data.get("gvd_tiles")
        return cls(
            places_per_terrain={str(k): int(v) for k, v in data["places_per_terrain"].items()},
            patches_dropped=int(data["patches_dropped"]),
            grid_cells=(int(rows), int(cols)),
            blocked_cells=int(data["blocked_cells"]),
            edges=EdgeCounts.from_json(data["edges"]),
            grid_links=int(data["grid_links"]),
            bridges_not_clear=int(data["bridges_not_clear"]),
            embedding_source=EmbeddingSources.from_json(data["embedding_source"]),
            embedding_rule=str(data["embedding_rule"]),
            grid_tiles=GridTiles.from_json(grid_tiles) if grid_tiles is not None else None,
            gvd_tiles=GvdTiles.from_json(gvd_tiles) if gvd_tiles is not None else None,
            step_line_cells=int(data["step_line_cells"]) if data.get("step_line_cells") is not None else None,
        )


@dataclass
class BuildResult:
    """What `terra build` did: counts of the stored graph, its counters and stage timings (seconds).
    `tile_size_m` (the configured tile side) and `timer` (calls per stage) serve the text summary
    only; they are not part of the JSON and not compared."""

    bundle: Path
    places: int
    place_edges: int
    regions_per_level: list[int]
    region_method: str
    stats: BuildStats
    seconds: dict[str, float]
    tile_size_m: float | None = field(default=None, compare=False)
    timer: StageTimer | None = field(default=None, compare=False, repr=False)

    @classmethod
    def of(cls, bundle: Path, graph: SceneGraph, stats: BuildStats, timer: StageTimer, tile_size_m: float | None):
        """The summary of `graph`, built into `bundle`."""
        return cls(
            bundle=Path(bundle),
            places=len(graph.places),
            place_edges=int(len(graph.place_edges)),
            regions_per_level=[len(level) for level in graph.regions],
            region_method=graph.region_method,
            stats=stats,
            seconds=timer.to_json(),
            tile_size_m=tile_size_m,
            timer=timer,
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "bundle": str(self.bundle),
            "places": self.places,
            "place_edges": self.place_edges,
            "regions_per_level": list(self.regions_per_level),
            "region_method": self.region_method,
            "stats": self.stats.to_json(),
            "seconds": dict(self.seconds),
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> BuildResult:
        return cls(
            bundle=Path(data["bundle"]),
            places=int(data["places"]),
            place_edges=int(data["place_edges"]),
            regions_per_level=[int(n) for n in data["regions_per_level"]],
            region_method=str(data["region_method"]),
            stats=BuildStats.from_json(data["stats"]),
            seconds={str(k): float(v) for k, v in data["seconds"].items()},
        )
