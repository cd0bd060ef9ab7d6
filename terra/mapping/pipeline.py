"""Phase 1 end to end: dataset frames -> perception -> fusion -> bundle component `map/`.

Perception runs behind the per-frame perception cache (OUT.work/perception/ by default, on for
model backends; terra/perception/cache.py), so model inference is never repeated.
Resumable: the fusion state is checkpointed every `checkpoint_every` frames in `OUT.partial/`;
a rerun with the same dataset and config continues after the last checkpoint and produces the
same bytes as an uninterrupted run (noise is seeded per frame and camera, not by a running
stream). Frames are fused in order as a `FrameFeed` hands them over: `SerialFeed` (every frame at once,
perceived during fusion) or a feed that waits until other processes have perceived a frame into the
cache (terra/distributed). Per-frame faults (unreadable frame, bad pose, empty or non-finite scan, unmatched or
mis-sized image) are skipped and counted; structural faults raise TerraError before the old
bundle, if any, is touched.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from terra.bundle import Bundle, BundleWriter, recover
from terra.datasets.base import CameraFrame, Dataset, Frame
from terra.datasets.fingerprint import dataset_fingerprint
from terra.errors import TerraError
from terra.fileio import OutputError
from terra.mapping.checkpoint import Checkpoint, fingerprint
from terra.mapping.config import MappingConfig
from terra.mapping.fusion import FusionStats, MapFusion
from terra.mapping.results import CacheSummary, MapCounts
from terra.mapping.storage import MAP_FORMAT, write_map
from terra.perception.base import ImagePerception, Perception, PerceptionSkip
from terra.perception.cache import CachedPerception, cached
from terra.perception.registry import get_perception
from terra.progress import StageTimer
from terra.progress import progress as progress_bar

POINTS_STREAM = 1 << 20  # noise stream number of per-point labels (camera streams are 0, 1, ...)


@dataclass
class MapRun:
    """What `build_map` did: the bundle and its map's sizes, the stage timings and the fault
    counters; `cache`: the perception cache's folder, hits and computed images (None when the
    cache is off)."""

    bundle: Bundle
    counts: MapCounts
    timer: StageTimer
    stats: dict[str, int]
    notes: dict[str, str]  # first message of each kind of skipped frame
    resumed_from: int
    cache: CacheSummary | None = None


class FrameFeed(Protocol):
    """Hands frame indices to the fusion loop, in order: `frames(start, stop)` yields start, ..., stop - 1,
    each once the frame may be fused (for a distributed feed: once its perception is in the cache).
    Closing the iterator early (an error, Ctrl-C) must release whatever the feed holds."""

    def frames(self, start: int, stop: int) -> Iterator[int]: ...


@dataclass
class SerialFeed:
    """Every frame at once, with a progress bar: perception runs inside fusion, in this process."""

    show_progress: bool = True

    def frames(self, start: int, stop: int) -> Iterator[int]:
        return progress_bar(
            range(start, stop), desc="mapping", total=stop - start, enabled=self.show_progress, unit="frames"
        )


def build_map(dataset: Dataset, config: MappingConfig, out: Path, progress: bool = True) -> Bundle:
    """Build the metric-semantic map of `dataset` into the bundle folder `out` (atomic, resumable)."""
    return run_mapping(dataset, config, out, show_progress=progress).bundle


def run_mapping(
    dataset: Dataset,
    config: MappingConfig,
    out: Path,
    show_progress: bool = True,
    perception: Perception | None = None,
    feed: FrameFeed | None = None,
    timer: StageTimer | None = None,
) -> MapRun:
    """`build_map` with its timings and counters (used by `terra map` for the summary). `feed` orders the
    frames (default `SerialFeed`); `timer` collects the stage timings (a new one by default)."""
    out = Path(out)
    timer = timer if timer is not None else StageTimer()
    feed = feed if feed is not None else SerialFeed(show_progress)
    recover(out)  # leftovers of an interrupted run: a killed final write, a swap cut short
    check_output(out)
    n_frames = len(dataset)
    if n_frames == 0:
        raise TerraError(f"dataset {dataset.name!r} has no frames")
    with timer.stage("setup"):
        perception = open_perception(config, dataset, out, perception)
        global_map, dropped = _global_map(dataset, config)
        fusion = MapFusion(config, perception.terrain_classes, perception.dim, global_map)
        fusion.stats.add("global_map_points_nonfinite", dropped)
        source = {"name": dataset.name, "fingerprint": dataset_fingerprint(dataset), "frames": n_frames}
    key = _run_key(config, source, perception, global_map)
    checkpoint = Checkpoint(out)
    start = _resume(checkpoint, key, fusion)
    try:
        msm, stats = _fuse_all(dataset, config, perception, fusion, checkpoint, key, start, feed, timer)
        with timer.stage("write"):
            bundle = _write(out, msm, config, stats, dataset, perception, source)
    except OutputError as exc:
        raise OutputError(f"{exc}{_resume_hint(checkpoint)}") from None
    checkpoint.discard()
    notes = dict(fusion.stats.notes)
    return MapRun(bundle, map_counts(bundle), timer, stats, notes, start, cache_summary(perception))


def map_counts(bundle: Bundle) -> MapCounts:
    """The sizes of the map stored in `bundle` (as its manifest lists them)."""
    info = bundle.model.components.map
    sizes = (info.points, info.observed_points, info.bank, info.images) if info is not None else (None,)
    if info is None or any(n is None for n in sizes):
        raise TerraError(f"{bundle.path}/manifest.json: components.map lacks the map's sizes")
    return MapCounts(int(info.points or 0), int(info.observed_points or 0), int(info.bank or 0), int(info.images or 0))


def _fuse_all(
    dataset: Dataset,
    config: MappingConfig,
    perception: Perception,
    fusion: MapFusion,
    checkpoint: Checkpoint,
    key: str,
    start: int,
    feed: FrameFeed,
    timer: StageTimer,
):
    """Frames `start`.. fused in the order `feed` hands them over (checkpointed every
    `checkpoint_every`), then the finished map and stats."""
    n_frames = len(dataset)
    for i in feed.frames(start, n_frames):
        with timer.stage("load"):
            frame = load_frame(dataset, i, fusion.stats)
        if frame is not None:
            _fuse_frame(frame, i, config, perception, fusion, timer)
        done = i + 1
        if done % config.checkpoint_every == 0 and done < n_frames:
            with timer.stage("checkpoint"):
                arrays, meta = fusion.state()
                checkpoint.save(key, done, arrays, meta)

    stats = fusion.stats.to_json()
    if stats.get("frames_fused", 0) == 0:
        checkpoint.discard()  # nothing to resume: a rerun would meet the same frames
        first = next(iter(fusion.stats.notes.values()), "")
        raise TerraError(
            f"dataset {dataset.name!r}: none of its {n_frames} frames could be used ({_fault_summary(stats)})"
            + (f"; first: {first}" if first else "")
        )
    with timer.stage("finish"):
        msm = fusion.finish(perception.embedder, perception.terrain_embeddings())
    return msm, stats


def _write(
    out: Path, msm, config: MappingConfig, stats: dict, dataset: Dataset, perception: Perception, source: dict
) -> Bundle:
    with BundleWriter(out) as writer:
        write_map(
            writer,
            msm,
            config=config.model_dump(mode="json"),
            stats=stats,
            dataset=dataset.name,
            classes=dataset.classes.to_json(),
        )
        writer.update_component("map", dataset=source)
        writer.set_perception(perception.describe())
    return Bundle(out)


def _resume_hint(checkpoint: Checkpoint) -> str:
    """What a rerun will do after a write failure: resume from the last checkpoint, if there is one."""
    if checkpoint.exists():
        return f"; rerun the same command to resume from the checkpoint in {checkpoint.folder}"
    return ""


def _run_key(config: MappingConfig, source: dict, perception: Perception, global_map: np.ndarray | None) -> str:
    """What a checkpoint must match to be resumed: everything that changes the map's bytes. `source`: the
    dataset's name, content fingerprint and frame count."""
    return fingerprint(
        {
            "format": MAP_FORMAT,
            # Where the perception cache lives changes no output.
            "config": config.model_dump(mode="json", exclude={"perception": {"cache"}}),
            # What the dataset holds, not where it lives: a renamed copy resumes the checkpoint.
            "dataset": source["fingerprint"],
            "frames": source["frames"],
            "embedder": [perception.embedder, perception.dim],
            "global_map": None
            if global_map is None
            else [int(global_map.shape[0]), float(np.asarray(global_map, np.float64).sum())],
        }
    )


def _resume(checkpoint: Checkpoint, key: str, fusion: MapFusion) -> int:
    """The first frame to fuse: after a matching checkpoint (restored into `fusion`), else 0 (any stale
    checkpoint removed)."""
    saved = checkpoint.load(key)
    if saved is None:
        checkpoint.discard()
        return 0
    start, arrays, meta = saved
    fusion.restore(arrays, meta)
    return start


def open_perception(
    config: MappingConfig, dataset: Dataset, out: Path, perception: Perception | None = None
) -> Perception:
    """The configured perception backend (or `perception`), behind the perception cache when it is on."""
    perception = perception or get_perception(config.perception, dataset.classes)
    if isinstance(perception, CachedPerception):
        return perception
    return cached(perception, config.perception.cache, out)


def cache_summary(perception: Perception) -> CacheSummary | None:
    """Folder, hits and computed images of a cached perception (None when uncached)."""
    if not isinstance(perception, CachedPerception):
        return None
    return CacheSummary(str(perception.cache.folder), perception.counts.hits, perception.counts.computed)


def check_output(out: Path) -> None:
    """Refuse, with or without --overwrite, to replace something that is not a bundle (a user's
    folder or file): the same rule and words as terra.bundle.check_output_folder."""
    from terra.bundle import MANIFEST, refuse_foreign

    if out.is_file():
        raise TerraError(f"{out}: exists and is not a Terra bundle (a file); choose another --out")
    # A manifest.json of any content marks the map's own output: a damaged bundle may be re-mapped.
    refuse_foreign(out, "Terra bundle", lambda folder: (folder / MANIFEST).is_file(), MANIFEST)


def _global_map(dataset: Dataset, config: MappingConfig) -> tuple[np.ndarray | None, int]:
    """The dataset's own global map (finite rows only) when configured and present."""
    if not config.fusion.use_global_map:
        return None, 0
    points = dataset.global_map()
    if points is None:
        return None, 0
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] < 3 or not np.issubdtype(points.dtype, np.number):
        raise TerraError(
            f"dataset {dataset.name!r}: global map must be an (M, 3) array of metres, got shape {points.shape}"
        )
    points = points[:, :3].astype(np.float32)
    finite = np.isfinite(points).all(axis=1)
    if not finite.any():
        raise TerraError(f"dataset {dataset.name!r}: global map has no finite point")
    return points[finite], int(np.count_nonzero(~finite))


def load_frame(dataset: Dataset, i: int, stats: FusionStats) -> Frame | None:
    """Frame i with non-finite points dropped, or None (counted) for a per-frame fault."""
    try:
        frame = dataset[i]
    except TerraError as exc:
        stats.add("frames_skipped_unreadable")
        stats.note("frames_skipped_unreadable", str(exc))
        return None
    where = f"frame {i} (t = {float(frame.stamp):.3f} s)"
    points = np.asarray(frame.points)
    if points.ndim != 2 or points.shape[1] < 3:
        stats.add("frames_skipped_bad_points")
        stats.note("frames_skipped_bad_points", f"{where}: points must be (N, 3) metres, got shape {points.shape}")
        return None
    pose = np.asarray(frame.T_map_lidar, dtype=np.float64)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        stats.add("frames_skipped_bad_pose")
        stats.note("frames_skipped_bad_pose", f"{where}: T_map_lidar must be a finite 4x4 pose, got shape {pose.shape}")
        return None
    finite = np.isfinite(points[:, :3]).all(axis=1)
    if not finite.all():
        stats.add("points_dropped_nonfinite", int(np.count_nonzero(~finite)))
        frame.points = points[finite, :3]
        if frame.point_labels is not None:
            frame.point_labels = np.asarray(frame.point_labels)[finite]
        if frame.point_instances is not None:
            frame.point_instances = np.asarray(frame.point_instances)[finite]
        if frame.intensity is not None:
            frame.intensity = np.asarray(frame.intensity)[finite]
        if frame.point_times is not None:
            frame.point_times = np.asarray(frame.point_times)[finite]
    frame.points = np.asarray(frame.points, dtype=np.float32)[:, :3]
    if frame.points.shape[0] == 0:
        stats.add("frames_skipped_empty")
        stats.note("frames_skipped_empty", f"{where}: no finite point in the scan")
        return None
    return frame


def image_fault(frame: Frame, camera: CameraFrame, config: MappingConfig) -> tuple[str, str] | None:
    """Why an image cannot be fused: (stats counter name, one line naming the image), or None."""
    calib = camera.calibration
    name = camera.name or f"frame {frame.index} camera {calib.name}"
    offset = abs(float(camera.stamp) - float(frame.stamp))
    if offset > config.projection.max_time_offset:
        return "images_skipped_unmatched_stamp", (
            f"{name}: image stamp {float(camera.stamp):.3f} s is {offset:.3f} s "
            f"from its scan's {float(frame.stamp):.3f} s "
            f"(tolerance {config.projection.max_time_offset} s)"
        )
    shape = (calib.height, calib.width)
    for what, array in (
        ("image", camera.image),
        ("semantic labels", camera.semantic),
        ("instance labels", camera.instance),
    ):
        if array is not None and np.asarray(array).shape[:2] != shape:
            return (
                "images_skipped_bad_size",
                f"{name}: {what} of {np.asarray(array).shape[:2]} pixels, calibration says (height, width) {shape}",
            )
    return None


def perceive_image(
    perception: Perception, frame: Frame, i: int, c: int, config: MappingConfig, stats: FusionStats
) -> ImagePerception | None:
    """The perception of camera `c` of frame `i`, or None (counted in `stats`, with a first note) when the
    image cannot be used. The generator is seeded by (noise seed, frame, camera), so any process perceiving
    this image, in any order, draws the same numbers."""
    camera = frame.cameras[c]
    fault = image_fault(frame, camera, config)
    if fault is not None:
        stats.add(fault[0])
        stats.note(*fault)
        return None
    try:
        return perception.perceive(camera, np.random.default_rng([config.perception.noise.seed, i, c]))
    except PerceptionSkip as exc:  # any other exception is a failure of the backend: it propagates
        stats.add("images_skipped_no_labels")
        stats.note("images_skipped_no_labels", f"{camera.name or f'frame {i} camera {c}'}: {exc}")
        return None


def uses_images(frame: Frame, config: MappingConfig) -> bool:
    """Whether frame's semantics come from its images (else from per-point labels, when the source has them)."""
    source = config.perception.source
    return source == "images" or (source == "auto" and bool(frame.cameras))


def _fuse_frame(
    frame: Frame, i: int, config: MappingConfig, perception: Perception, fusion: MapFusion, timer: StageTimer
) -> None:
    seed = config.perception.noise.seed
    source = config.perception.source
    with timer.stage("fusion"):
        points_map, index = fusion.associate(frame.points, frame.T_map_lidar)
    fusion.stats.add("frames_fused")
    if uses_images(frame, config):
        for c, camera in enumerate(frame.cameras):
            with timer.stage("perception"):
                seen = perceive_image(perception, frame, i, c, config, fusion.stats)
            if seen is None:
                continue
            with timer.stage("fusion"):
                fusion.integrate_image(
                    frame.points, points_map, index, frame.T_map_lidar, camera.calibration, camera.stamp, seen
                )
    elif source in ("auto", "points"):
        with timer.stage("perception"):
            seen_points = perception.perceive_points(frame, np.random.default_rng([seed, i, POINTS_STREAM]))
        if seen_points is not None:
            with timer.stage("fusion"):
                fusion.integrate_points(points_map, index, seen_points)
            fusion.stats.add("scans_fused_from_point_labels")


def _fault_summary(stats: dict[str, int]) -> str:
    faults = {k: v for k, v in stats.items() if "skipped" in k}
    return ", ".join(f"{k}={v}" for k, v in faults.items()) or "no frames"
