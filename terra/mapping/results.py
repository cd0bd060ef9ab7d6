"""What Phase 1 returns to `terra map`: `MapResult` (a map written into a bundle) and
`PerceptionResult` (`--perception-only`: the perception cache filled), with the parts both share.
`to_json()` is the command's `--json` output and `from_json` reads it back into an equal result;
text rendering lives in terra/cli/render.py."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:  # results are read without the mapping modules
    from terra.progress import StageTimer


@runtime_checkable
class CountsSkips(Protocol):
    """A source that counts what it will not use (e.g. a bag: scans without a pose, images it
    cannot decode), by reason, with a first example of each."""

    skipped: dict[str, int]
    skipped_notes: dict[str, str]


@runtime_checkable
class NamesPoseSource(Protocol):
    """A source that says where its poses come from, in words ("tf map -> os_lidar", ...)."""

    pose_source: str


def source_faults(source: object) -> tuple[dict[str, int], dict[str, str]]:
    """The skip counters and first notes of a source that keeps them (empty for the others)."""
    if isinstance(source, CountsSkips):
        return dict(source.skipped), dict(source.skipped_notes)
    return {}, {}


def pose_source(source: object) -> str | None:
    """Where `source`'s poses come from, when it says."""
    return source.pose_source if isinstance(source, NamesPoseSource) and source.pose_source else None


@dataclass
class CacheSummary:
    """The perception cache of a run: its folder, images read back (hits) and computed; `removed`
    when it was a temporary cache deleted at the end (the config keeps none)."""

    folder: str
    hits: int
    computed: int
    removed: bool = False

    def to_json(self) -> dict[str, Any]:
        data: dict[str, Any] = {"folder": self.folder, "hits": self.hits, "computed": self.computed}
        if self.removed:
            data["removed"] = True
        return data

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> CacheSummary:
        return cls(str(data["folder"]), int(data["hits"]), int(data["computed"]), bool(data.get("removed", False)))


@dataclass
class MapCounts:
    """Sizes of a stored map: points, those with object observations, bank entries, images."""

    points: int
    observed_points: int
    bank: int
    images: int

    def to_json(self) -> dict[str, int]:
        return {
            "points": self.points,
            "observed_points": self.observed_points,
            "bank": self.bank,
            "images": self.images,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> MapCounts:
        return cls(int(data["points"]), int(data["observed_points"]), int(data["bank"]), int(data["images"]))


@dataclass
class ClusterSummary:
    """Perception on a Dask cluster: where, how many frames in flight at most, and what the workers
    did (frames, workers used, images computed and read back, seconds of worker time)."""

    cluster: str
    in_flight: int
    frames: int
    workers_used: int
    computed: int
    hits: int
    seconds: float

    def to_json(self) -> dict[str, Any]:
        return {
            "cluster": self.cluster,
            "in_flight": self.in_flight,
            "frames": self.frames,
            "workers_used": self.workers_used,
            "computed": self.computed,
            "hits": self.hits,
            "seconds": self.seconds,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> ClusterSummary:
        return cls(
            str(data["cluster"]),
            int(data["in_flight"]),
            int(data["frames"]),
            int(data["workers_used"]),
            int(data["computed"]),
            int(data["hits"]),
            float(data["seconds"]),
        )


@dataclass
class OdometrySummary:
    """KISS-ICP's run: scans registered, their rate, scans deskewed, the trajectory files written
    (KITTI, TUM), and, against the source's own poses when it has them, the errors (ate_rmse_m,
    final_error_m, drift_percent, distance_m)."""

    scans: int
    scans_per_second: float
    deskewed: int
    trajectory: tuple[Path, Path]
    errors: dict[str, float] | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "scans": self.scans,
            "scans_per_second": self.scans_per_second,
            "deskewed": self.deskewed,
            "trajectory": [str(p) for p in self.trajectory],
            "errors": dict(self.errors) if self.errors is not None else None,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> OdometrySummary:
        kitti, tum = data["trajectory"]
        errors = data.get("errors")
        return cls(
            int(data["scans"]),
            float(data["scans_per_second"]),
            int(data["deskewed"]),
            (Path(kitti), Path(tum)),
            {str(k): float(v) for k, v in errors.items()} if errors is not None else None,
        )


@dataclass
class MapResult:
    """What `terra map` did: the bundle and its map's sizes, the frame it resumed after (0: none),
        the perception cache, the counters of fusion and of the source (faults among them: `skipped`
    and `dropped_nonfinite` counters) with a first note of each kind of fault,
        where the poses came from, the cluster and odometry runs when used, and stage timings.
        `timer` (calls per stage) serves the text summary only: not in the JSON, not compared."""

    bundle: Path
    counts: MapCounts
    resumed_from: int
    cache: CacheSummary | None
    stats: dict[str, int]
    notes: dict[str, str]
    seconds: dict[str, float]
    pose_source: str | None = None
    cluster: ClusterSummary | None = None
    odometry: OdometrySummary | None = None
    timer: StageTimer | None = field(default=None, compare=False, repr=False)
    session: dict[str, Any] | None = None  # a joined session: its number and alignment (terra/mapping/sessions.py)

    def to_json(self) -> dict[str, Any]:
        return {
            "bundle": str(self.bundle),
            **({"session": dict(self.session)} if self.session is not None else {}),
            **self.counts.to_json(),
            "resumed_from": self.resumed_from,
            "cache": self.cache.to_json() if self.cache is not None else None,
            "stats": dict(self.stats),
            "notes": dict(self.notes),
            "pose_source": self.pose_source,
            "cluster": self.cluster.to_json() if self.cluster is not None else None,
            "odometry": self.odometry.to_json() if self.odometry is not None else None,
            "seconds": dict(self.seconds),
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> MapResult:
        cache, cluster, odometry = data.get("cache"), data.get("cluster"), data.get("odometry")
        return cls(
            bundle=Path(data["bundle"]),
            counts=MapCounts.from_json(data),
            resumed_from=int(data["resumed_from"]),
            cache=CacheSummary.from_json(cache) if cache is not None else None,
            stats={str(k): int(v) for k, v in data["stats"].items()},
            notes={str(k): str(v) for k, v in data["notes"].items()},
            seconds={str(k): float(v) for k, v in data["seconds"].items()},
            pose_source=data.get("pose_source"),
            cluster=ClusterSummary.from_json(cluster) if cluster is not None else None,
            odometry=OdometrySummary.from_json(odometry) if odometry is not None else None,
            session=dict(data["session"]) if isinstance(data.get("session"), dict) else None,
        )


@dataclass
class PerceptionResult:
    """What `terra map --perception-only` did: the cache folder, frames and images seen, images read
    back (hits) and computed, counters with a first note of each fault, the cluster run when used, and
    stage timings (`timer` as in MapResult)."""

    folder: Path
    frames: int
    images: int
    hits: int
    computed: int
    stats: dict[str, int]
    notes: dict[str, str]
    seconds: dict[str, float]
    cluster: ClusterSummary | None = None
    timer: StageTimer | None = field(default=None, compare=False, repr=False)

    def to_json(self) -> dict[str, Any]:
        return {
            "folder": str(self.folder),
            "frames": self.frames,
            "images": self.images,
            "hits": self.hits,
            "computed": self.computed,
            "stats": dict(self.stats),
            "notes": dict(self.notes),
            "cluster": self.cluster.to_json() if self.cluster is not None else None,
            "seconds": dict(self.seconds),
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> PerceptionResult:
        cluster = data.get("cluster")
        return cls(
            folder=Path(data["folder"]),
            frames=int(data["frames"]),
            images=int(data["images"]),
            hits=int(data["hits"]),
            computed=int(data["computed"]),
            stats={str(k): int(v) for k, v in data["stats"].items()},
            notes={str(k): str(v) for k, v in data["notes"].items()},
            seconds={str(k): float(v) for k, v in data["seconds"].items()},
            cluster=ClusterSummary.from_json(cluster) if cluster is not None else None,
        )
