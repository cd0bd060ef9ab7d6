"""How another process reopens the source a `terra map` client maps: plain JSON data, never a Dataset.

Dask workers read frames themselves (images never travel through the scheduler), so they need the
source's address, not its contents: a dataset path with its loader and options, or a simulated campus
(preset and seed; the simulator is deterministic, so every worker renders the same frames). Paths are
made absolute as the client sees them, without resolving symbolic links: a worker on another machine
needs the same path (the same mount point, or a shared file system).

A source whose poses the client computes with LiDAR odometry (`poses: odometry`) is perceived on the
workers without them: perception reads images only, and running KISS-ICP on every worker would
repeat the client's sequential registration. The workers see identity poses instead (`PoselessView`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from terra.datasets.base import Dataset, Frame
from terra.errors import TerraError


@dataclass(frozen=True)
class SourceSpec:
    """A dataset `path` (absolute) read by loader `format` with `options` (JSON values), or `sim`:
    a simulated campus "PRESET:SEED". Exactly one of path and sim is set. poses: "source" (the
    source's own) or "odometry" (computed by the client; see the module docstring)."""

    path: str | None = None
    format: str = "auto"
    options: dict[str, Any] = field(default_factory=dict)
    sim: str | None = None
    poses: str = "source"

    @classmethod
    def from_cli(
        cls, path: Path | None, sim: str | None, format: str = "auto", options: Mapping[str, Any] | None = None
    ) -> SourceSpec:
        """The spec of `terra map`'s arguments: a folder (format detected now, so every worker uses the
        same loader) or `--sim PRESET[:SEED]`."""
        if sim is not None and path is None:
            preset, _, seed = sim.partition(":")
            if seed and not seed.isdigit():
                raise TerraError(f"--sim {sim!r}: the seed must be a non-negative integer")
            return cls(sim=f"{preset}:{int(seed) if seed else 0}")
        if path is None or sim is not None:
            raise TerraError("give either a DATASET folder or --sim PRESET[:SEED]")
        absolute = Path(path).absolute()
        if format == "auto" and absolute.exists():
            from terra.datasets.registry import detect_format

            format = detect_format(absolute) or "auto"  # unknown: open_dataset names the choices
        plain = {k: str(Path(v).absolute()) if isinstance(v, Path) else v for k, v in (options or {}).items()}
        return cls(path=str(absolute), format=format, options=plain)

    def open(self) -> Dataset:
        """The dataset (TerraError, one line, when it cannot be opened)."""
        if self.sim is not None:
            return _simulate(self.sim)
        if self.path is None:
            raise TerraError("the source names neither a dataset path nor --sim")
        from terra.datasets.registry import open_dataset

        # With poses from odometry the loader opens without its own (which may be missing or broken).
        return open_dataset(self.path, self.format, self.options or None, poses=self.poses)

    def with_odometry(self) -> SourceSpec:
        """This spec for a source whose poses the client computes with odometry."""
        return replace(self, poses="odometry")

    def open_for_perception(self) -> Dataset:
        """The dataset as a worker perceives it: with identity poses when the client computes them."""
        dataset = self.open()
        return PoselessView(dataset) if self.poses == "odometry" else dataset

    def describe(self) -> str:
        """The source in words, for messages: the path, or `--sim PRESET:SEED`."""
        return self.path if self.path is not None else f"--sim {self.sim}"

    def to_json(self) -> dict:
        return {
            "path": self.path,
            "format": self.format,
            "options": dict(self.options),
            "sim": self.sim,
            "poses": self.poses,
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> SourceSpec:
        return cls(
            data.get("path"),
            data.get("format", "auto"),
            dict(data.get("options") or {}),
            data.get("sim"),
            data.get("poses", "source"),
        )


class PoselessView:
    """`dataset`'s frames with T_map_lidar the identity: what perception needs of a source whose poses
    are missing (or replaced by the client's odometry), so no frame is skipped for its pose."""

    def __init__(self, dataset: Dataset) -> None:
        self.dataset = dataset
        self.name = dataset.name
        self.classes = dataset.classes

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, index: int) -> Frame:
        frame = self.dataset[index]
        frame.T_map_lidar = np.eye(4)
        return frame

    def global_map(self) -> None:
        """None: the source's own map lies in the frame of the poses this view drops."""
        return None


def _simulate(spec: str) -> Dataset:
    preset, _, seed = spec.partition(":")
    try:
        from terra.sim import simulate
    except ImportError:
        raise TerraError("--sim needs the simulator (terra.sim), which is not available") from None
    try:
        return simulate(preset, seed=int(seed) if seed else 0)
    except ValueError as exc:
        raise TerraError(f"--sim {spec!r}: {exc}") from None
