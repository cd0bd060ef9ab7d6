"""The common frame stream every data source turns into, and the class vocabulary of a source."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from terra.errors import TerraError
from terra.geometry import CameraCalibration

if TYPE_CHECKING:  # the fixes' module imports the WGS84 transforms, which only GNSS sources need
    from terra.datasets.gnss import GnssFixes

# What a message says to do when a source's own poses are missing or do not connect.
NO_POSES_REMEDY = "map with --poses odometry (or dataset.poses: odometry) to compute poses from the scans"


class PosesUnavailable(TerraError):
    """A source that can be read, but whose own poses cannot be had (no poses.txt, no OXTS, a TF
    tree or odometry topic that does not reach the LiDAR frame). Opened without its poses (the
    loader's `without_poses` options), LiDAR odometry can map it; `terra inspect` describes it."""

    def __init__(self, reason: str) -> None:
        super().__init__(f"{reason}; {NO_POSES_REMEDY}")
        self.reason = reason


@dataclass(frozen=True)
class SemanticClass:
    """One label of a source's vocabulary.

    id: the source's integer label. name: a plain English name, embedded as text by the labels
    backend ("bicycle rack", "asphalt"). terrain: whether it is a ground surface type that gets its
    own GVD. semantickitti_id: the id written to SemanticKITTI `.label` files (None = not written).
    """

    id: int
    name: str
    terrain: bool = False
    semantickitti_id: int | None = None


@dataclass
class ClassTable:
    """A source's label vocabulary. Label 0 is always 'unlabeled' (sky, nothing)."""

    classes: list[SemanticClass]

    def __post_init__(self) -> None:
        ids = [c.id for c in self.classes]
        if len(set(ids)) != len(ids):
            raise ValueError("class ids must be unique")
        self._by_id = {c.id: c for c in self.classes}
        self._by_name = {c.name: c for c in self.classes}

    def __iter__(self) -> Iterator[SemanticClass]:
        return iter(self.classes)

    def __len__(self) -> int:
        return len(self.classes)

    def by_id(self, class_id: int) -> SemanticClass:
        return self._by_id[class_id]

    def by_name(self, name: str) -> SemanticClass:
        return self._by_name[name]

    @property
    def terrain_classes(self) -> list[SemanticClass]:
        """Terrain classes in id order; their order defines terrain indices in maps and graphs."""
        return sorted((c for c in self.classes if c.terrain), key=lambda c: c.id)

    def lookup(self, max_id: int | None = None) -> np.ndarray:
        """Dense array id -> position in `self.classes` (-1 where unknown), for vectorized mapping."""
        size = (max(self._by_id) if max_id is None else max_id) + 1
        table = np.full(size, -1, dtype=np.int32)
        for i, c in enumerate(self.classes):
            if c.id < size:
                table[c.id] = i
        return table

    def to_json(self) -> list[dict]:
        return [
            {"id": c.id, "name": c.name, "terrain": c.terrain, "semantickitti_id": c.semantickitti_id}
            for c in self.classes
        ]

    @classmethod
    def from_json(cls, rows: list[dict]) -> ClassTable:
        return cls(
            [
                SemanticClass(int(r["id"]), str(r["name"]), bool(r.get("terrain", False)), r.get("semantickitti_id"))
                for r in rows
            ]
        )


@dataclass
class CameraFrame:
    """One camera image taken with a LiDAR scan.

    image: (H, W, 3) uint8 RGB. semantic: (H, W) int32 class ids of the source's ClassTable, or None.
    instance: (H, W) int32 instance ids (0 = no instance), or None. stamp: seconds.
    """

    calibration: CameraCalibration
    stamp: float
    image: np.ndarray
    semantic: np.ndarray | None = None
    instance: np.ndarray | None = None
    name: str = ""  # file name relative to the dataset root, when there is one


@dataclass
class Frame:
    """One LiDAR scan with its pose and synchronised camera images.

    points: (N, 3) float32, metres, LiDAR frame. intensity: (N,) float32 or None.
    T_map_lidar: 4x4 pose of the LiDAR in the map frame. point_labels / point_instances: (N,) int32
    per-point class and instance ids when the source has them (simulator, SemanticKITTI).
    point_times: (N,) float64 seconds from `stamp` at which each point was measured (a spinning
    LiDAR's sweep), when the source records it (bags); odometry deskews the scan with it.
    """

    index: int
    stamp: float
    points: np.ndarray
    T_map_lidar: np.ndarray
    cameras: list[CameraFrame] = field(default_factory=list)
    intensity: np.ndarray | None = None
    point_labels: np.ndarray | None = None
    point_instances: np.ndarray | None = None
    point_times: np.ndarray | None = None


@runtime_checkable
class Dataset(Protocol):
    """A source of frames. Frames are produced lazily, in time order."""

    name: str
    classes: ClassTable

    def __len__(self) -> int: ...

    def __getitem__(self, index: int) -> Frame: ...

    def global_map(self) -> np.ndarray | None:
        """The source's own global map (M, 3) in the map frame, metres, if it ships one."""
        ...


@dataclass
class SourceInfo:
    """What a source holds, as `terra inspect` reports it, without reading every frame.

    format: loader name. path: the file or folder. frames: scans that will be mapped.
    time_span: (first, last) scan stamp, seconds. cameras: the calibrations as read (intrinsics,
    lens model and coefficients, T_cam_lidar). pose_source: where T_map_lidar comes from, in
    words ("poses.txt", "tf map -> os_lidar", "odometry (KISS-ICP)", "OXTS", ...).
    skipped / skipped_notes: what will not be used, counted by reason, with a first example line.
    details: format-specific facts (bag topics, TF tree, a ready-to-edit dataset section, ...),
    plain JSON-able data.
    """

    format: str
    path: str
    frames: int
    time_span: tuple[float, float] | None
    cameras: list[CameraCalibration]
    pose_source: str
    skipped: dict[str, int] = field(default_factory=dict)
    skipped_notes: dict[str, str] = field(default_factory=dict)
    details: dict = field(default_factory=dict)


@runtime_checkable
class InspectableDataset(Dataset, Protocol):
    """A source that can describe itself cheaply (every built-in loader)."""

    def info(self) -> SourceInfo: ...


@runtime_checkable
class GeoreferencedDataset(Dataset, Protocol):
    """A source that may know where its map frame lies on the Earth (KITTI raw drives with OXTS)."""

    def wgs84_anchor(self) -> dict[str, Any] | None:
        """The fields of terra.schemas.Wgs84Anchor for the map frame of this source's poses, or None."""
        ...


@runtime_checkable
class GnssDataset(Dataset, Protocol):
    """A source that carries GNSS fixes of its drive (the simulator with `sim.gnss`), which writers keep."""

    def gnss_fixes(self) -> GnssFixes | None:
        """The drive's fixes (terra.datasets.gnss), or None."""
        ...
