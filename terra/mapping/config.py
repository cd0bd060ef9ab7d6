"""Configuration of Phase 1 (`terra map`): perception, projection, fusion, visibility, checkpoints.

Defaults follow the paper and the authors' simulation settings where they give numbers (DBSCAN
eps 2.0 m / 5 samples, bank match threshold 0.9, 20 m image range), and our own choices elsewhere.
"""

from __future__ import annotations

from pydantic import Field

from terra.perception.config import NOISE_PRESETS, NoiseConfig, PerceptionConfig
from terra.schemas import Section

__all__ = [
    "MappingConfig",
    "PerceptionConfig",
    "NoiseConfig",
    "NOISE_PRESETS",
    "ProjectionConfig",
    "FusionConfig",
    "VisibilityConfig",
]


class ProjectionConfig(Section):
    """min_depth: metres in front of the camera below which points are ignored.
    zbuffer_px: side of the square pixel cell in which only the nearest point is visible (1 = per
    pixel). max_time_offset: seconds an image stamp may differ from its scan's stamp."""

    min_depth: float = Field(default=0.1, gt=0.0)
    zbuffer_px: int = Field(default=1, ge=1, le=64)
    max_time_offset: float = Field(default=0.1, ge=0.0)


class FusionConfig(Section):
    """voxel_size: metres, cell of the accumulated map (and of association when the dataset ships
    no global map). gate: metres, largest scan-point to map-point distance for an association.
    use_global_map: use the dataset's own global map when it has one.
    dbscan_eps (metres) / dbscan_min_samples: the per-mask clustering; only the largest cluster
    keeps the mask's embedding. dbscan_voxel: metres; a mask's points are merged per voxel of this
    size into weighted samples before DBSCAN (0 = cluster every point). match_threshold: cosine at
    or above which a mask reuses a bank entry. max_terrain_overlap: masks with a larger share of
    terrain pixels are dropped."""

    voxel_size: float = Field(default=0.4, gt=0.0)
    gate: float = Field(default=1.0, gt=0.0)
    use_global_map: bool = True
    dbscan_eps: float = Field(default=2.0, gt=0.0)
    dbscan_min_samples: int = Field(default=5, ge=1)
    dbscan_voxel: float = Field(default=0.2, ge=0.0)
    match_threshold: float = Field(default=0.9, gt=-1.0, le=1.0)
    max_terrain_overlap: float = Field(default=0.5, ge=0.0, le=1.0)


class VisibilityConfig(Section):
    """cell_size: metres, edge of the voxels on which we record which images saw which part of
    the map (Phase 2 asks which images within 20 m saw a place)."""

    cell_size: float = Field(default=2.0, gt=0.0)


class MappingConfig(Section):
    perception: PerceptionConfig = Field(default_factory=PerceptionConfig)
    projection: ProjectionConfig = Field(default_factory=ProjectionConfig)
    fusion: FusionConfig = Field(default_factory=FusionConfig)
    visibility: VisibilityConfig = Field(default_factory=VisibilityConfig)
    checkpoint_every: int = Field(default=50, ge=1, description="frames between resumable checkpoints")
