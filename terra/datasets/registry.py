"""The dataset loaders: one module per source format, each exposing a `LOADER` (terra.registry).

A loader has a name, a cheap `detect(path)` used by `--format auto`, an `open(path, config)` and
the pydantic section of its options (topics, tolerances, ...), which a config file's `dataset`
section fills. Loaders are tried for detection in the order listed here, then plugins from the
`terra.datasets` entry-point group.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from terra.datasets.base import Dataset
from terra.errors import TerraError
from terra.registry import Registry
from terra.schemas import Section, validation_message


class NoOptions(Section):
    """A loader without options."""


@dataclass(frozen=True)
class Loader:
    """One source format: `open(path, options)` gives its frame stream; `options` is an instance of
    `config` (defaults unless the user's `dataset` section sets fields). `without_poses`: the
    options that open the source without its own poses (frames with NaN poses and `needs_odometry`
    set, for LiDAR odometry), applied by `--poses odometry` before the loader checks its poses."""

    name: str
    detect: Callable[[Path], bool]
    open: Callable[[Path, Any], Dataset]
    config: type[Section] = field(default=NoOptions)
    description: str = ""
    without_poses: Mapping[str, Any] = field(default_factory=dict)


LOADERS: Registry[Loader] = Registry(
    "dataset format",
    "terra.datasets",
    {
        "terra-folder": "terra.datasets.terra_folder:LOADER",
        "semantickitti": "terra.datasets.semantickitti:LOADER",
        "kitti-raw": "terra.datasets.kitti_raw:LOADER",
        "rosbag": "terra.datasets.rosbag:LOADER",
    },
)


def loader_names() -> list[str]:
    """Every dataset format name (built-ins and plugins), sorted."""
    return LOADERS.names()


def loader_options(loader: Loader, options: Mapping[str, Any] | None, source: str = "dataset options") -> Section:
    """`options` validated against the loader's config section; TerraError naming the field."""
    try:
        return loader.config.model_validate(dict(options or {}))
    except ValidationError as exc:
        raise TerraError(validation_message(f"{source} [{loader.name}]", exc)) from None


def detect_format(path: str | Path) -> str | None:
    """The name of the first loader that recognises `path`, or None."""
    return next((name for name, loader in LOADERS.items() if loader.detect(Path(path))), None)


def open_dataset(
    path: str | Path, format: str = "auto", options: Mapping[str, Any] | None = None, poses: str = "source"
) -> Dataset:
    """Open a dataset (folder or file); `format` is a loader name or 'auto' to detect it.

    `options` are the loader's settings (its config section's fields), e.g. from a config file's
    `dataset` section. poses: "source" (the source's own; PosesUnavailable when it has none that
    reach the LiDAR) or "odometry" (the loader's `without_poses` options override `options`: the
    frames come without poses, which LiDAR odometry then computes)."""
    from terra.bundle import recover

    if poses not in ("source", "odometry"):
        raise ValueError(f"poses must be 'source' or 'odometry', got {poses!r}")
    path = Path(path)
    recover(path)  # a dataset folder whose replacement (`terra sim --overwrite`) was cut short
    if not path.exists():
        raise TerraError(f"{path}: dataset does not exist")
    if format != "auto":
        return _open_with(LOADERS.get(format), path, options, poses)
    for _, loader in LOADERS.items():
        if loader.detect(path):
            return _open_with(loader, path, options, poses)
    raise TerraError(f"{path}: not a recognised dataset{_kind_note(path)}. Recognised formats: {recognised_formats()}")


def _open_with(loader: Loader, path: Path, options: Mapping[str, Any] | None, poses: str) -> Dataset:
    if poses == "odometry":
        options = {**(options or {}), **loader.without_poses}
    return loader.open(path, loader_options(loader, options))


# Files people reach for that no loader reads, and what they are.
_UNREAD_KINDS = {
    ".pcap": "raw sensor packets, which need the sensor's driver: record its PointCloud2 into a bag",
    ".pcapng": "raw sensor packets, which need the sensor's driver: record its PointCloud2 into a bag",
    ".pcd": "one point cloud without poses or images",
    ".ply": "one point cloud without poses or images",
    ".las": "one point cloud without poses or images",
    ".laz": "one point cloud without poses or images",
    ".bin": "one scan; a KITTI sequence is the folder above velodyne/",
}


def _kind_note(path: Path) -> str:
    kind = _UNREAD_KINDS.get(path.suffix.lower()) if path.is_file() else None
    return f" (a {path.suffix.lower()} file is {kind})" if kind else ""


def recognised_formats() -> str:
    """Every loader's name with what it reads, for messages: 'rosbag: ROS 1 .bag, ...; semantickitti: ...'."""
    return "; ".join(
        f"{name}: {loader.description}" if loader.description else name for name, loader in LOADERS.items()
    )
