"""World presets and the world generator: preset name + seed -> World, deterministically."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terra.errors import TerraError
from terra.sim.builder import WorldBuilder
from terra.sim.config import SimConfig
from terra.sim.heightfield import Heightfield
from terra.sim.layout import BLOCK_KINDS, ROAD, grid_layout, tiny_layout
from terra.sim.world import World


@dataclass(frozen=True)
class Preset:
    """size: side of the square world, metres. blocks: blocks per side (0 = the tiny site).
    spacing: metres between frames. route_length: metres (None = the whole tour).
    row_stride: drive every row_stride-th east-west road (None = every block's own tour).
    full_tours: with row_stride, how many blocks beside the route get their own tour."""

    name: str
    size: float
    blocks: int
    spacing: float
    route_length: float | None
    resolution: float
    max_frames: int | None = None
    row_stride: int | None = None
    full_tours: int | None = None


PRESETS: dict[str, Preset] = {
    "tiny": Preset("tiny", 60.0, 0, 4.0, None, 0.25, max_frames=40),
    "small": Preset("small", 150.0, 2, 2.7, None, 0.25),
    "campus": Preset("campus", 500.0, 4, 2.0, None, 0.5, row_stride=2, full_tours=1),
    "large": Preset("large", 2000.0, 16, 4.0, 12000.0, 0.5, row_stride=3, full_tours=12),
    # 3.2 km x 3.2 km (10.24 km^2): every second east-west road end to end, so every block borders
    # a driven road and the LiDAR (100 m) sees the whole campus (46.6 km, 3,106 frames); a keyframe
    # every 15 m (10 s at the default 1.5 m/s), well inside the LiDAR's and camera's reach, so each
    # stretch of ground is in several frames.
    "huge": Preset("huge", 3200.0, 26, 15.0, None, 0.5, row_stride=2, full_tours=6),
}


def get_preset(name: str) -> Preset:
    if name not in PRESETS:
        raise TerraError(f"unknown preset {name!r}; expected one of: {', '.join(PRESETS)}")
    return PRESETS[name]


def generate_world(preset: str, seed: int = 0, config: SimConfig | None = None) -> World:
    """The world of a preset for a seed (same preset, seed and config -> same world)."""
    p = get_preset(preset)
    config = config or SimConfig()
    rng = np.random.default_rng([int(seed), sum(map(ord, p.name))])
    ground = Heightfield.random(rng, config.ground_relief_m)
    resolution = config.terrain_resolution or p.resolution
    b = WorldBuilder(f"sim-{p.name}-seed{seed}", int(seed), (0.0, 0.0, p.size, p.size), resolution, ground, rng)
    if p.blocks == 0:
        tiny_layout(b)
    else:
        n = p.blocks
        block = (p.size - ROAD) / n - ROAD
        if n == 2:
            kinds = ["building", "park", "mall", "parking"]  # SW, SE, NW, NE
        else:
            kinds = list(rng.permutation(np.resize(np.array(BLOCK_KINDS), n * n)))
        grid_layout(b, n, block, kinds, p.row_stride, p.full_tours)
    length = config.route.length_m or p.route_length
    return b.finish(length, config.geometry)
