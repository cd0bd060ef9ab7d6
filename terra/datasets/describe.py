"""`terra inspect`'s library side: a source's SourceInfo, as plain JSON-able data."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from terra.datasets.base import PosesUnavailable, SourceInfo
from terra.datasets.folder_io import calibration_to_json
from terra.datasets.registry import LOADERS, open_dataset
from terra.errors import TerraError

# How `terra inspect` states a source without poses of its own.
NO_POSES = "no poses: map with --poses odometry"


@runtime_checkable
class _Describable(Protocol):
    """A loaded source that reports what it holds (every built-in loader's dataset)."""

    def info(self) -> SourceInfo: ...


def describe_source(
    path: str | Path, format: str = "auto", options: Mapping[str, Any] | None = None, poses: str = "source"
) -> SourceInfo:
    """What the source at `path` holds. A bag whose topics the loader cannot choose by itself
    (two LiDAR topics, an image with no camera_info) is still described: its topics and TF tree,
    with the reason under details['problem']. A source without usable poses of its own (no
    poses.txt, no OXTS, a TF tree that does not reach the LiDAR) is described as opened for
    odometry, its pose_source saying so. poses: as open_dataset's."""
    path = Path(path)
    try:
        dataset = open_dataset(path, format, options, poses)
    except PosesUnavailable as exc:
        info = _describe(open_dataset(path, format, options, "odometry"), path, format)
        info.pose_source = f"{NO_POSES} ({exc.reason})"
        return info
    except TerraError as exc:
        from terra.datasets.ros.bag import is_bag

        if format in ("auto", "rosbag") and is_bag(path) and "unreadable bag" not in str(exc):
            from terra.datasets.ros.describe import describe_unopened

            return describe_unopened(path, str(exc))
        raise
    return _describe(dataset, path, format)


def _describe(dataset, path: Path, format: str) -> SourceInfo:
    if not isinstance(dataset, _Describable):
        raise TerraError(f"{path}: the {format} loader cannot describe its source (no info())")
    return dataset.info()


def source_json(info: SourceInfo) -> dict:
    """SourceInfo as one JSON document (calibrations with K, lens model, coefficients, T_cam_lidar)."""
    out = asdict(info)
    out["cameras"] = [calibration_to_json(c) for c in info.cameras]
    out["time_span"] = list(info.time_span) if info.time_span else None
    return out


def loader_descriptions() -> dict[str, str]:
    return {name: loader.description for name, loader in LOADERS.items()}
