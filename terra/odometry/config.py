"""The `odometry` config section: KISS-ICP's parameters as Terra exposes them."""

from __future__ import annotations

from pydantic import Field

from terra.schemas import Section


class OdometryConfig(Section):
    """KISS-ICP settings (its defaults, except one thread: the result is then bit-for-bit
    repeatable, which Terra's same-input-same-bytes rule needs)."""

    max_range: float = Field(default=100.0, gt=0.0, description="metres; farther points are not registered")
    min_range: float = Field(
        default=0.0, ge=0.0, description="metres; nearer points (the robot itself) are not registered"
    )
    voxel_size: float | None = Field(
        default=None, gt=0.0, description="metres; None = max_range / 100, as KISS-ICP does"
    )
    max_points_per_voxel: int = Field(default=20, ge=1, description="points kept per voxel of the local map")
    initial_threshold: float = Field(default=2.0, gt=0.0, description="metres, the first correspondence threshold")
    min_motion_th: float = Field(
        default=0.1, ge=0.0, description="metres of motion below which the threshold is not updated"
    )
    max_num_iterations: int = Field(default=500, ge=1, description="ICP iterations per scan")
    convergence_criterion: float = Field(default=1e-4, gt=0.0, description="ICP stops when the update is smaller")
    deskew: bool = Field(
        default=True, description="correct each scan's motion during the sweep when points carry times"
    )
    velocity_window_s: float = Field(
        default=0.5, gt=0.0, description="seconds of past poses the deskewing velocity is averaged over"
    )
    threads: int = Field(
        default=1, ge=0, description="registration threads; 0 = all cores (faster, not bit-for-bit repeatable)"
    )
