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

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from terra.bundle import MANIFEST, Bundle, BundleWriter, recover
from terra.datasets.base import Dataset, Frame
from terra.datasets.fingerprint import dataset_fingerprint
from terra.errors import TerraError
from terra.fileio import OutputError
from terra.mapping.checkpoint import Checkpoint, fingerprint
from terra.mapping.config import MappingConfig
from terra.mapping.fusion import FusionStats, MapFusion
from terra.mapping.mapper import Mapper, check_frame
from terra.mapping.results import CacheSummary, MapCounts
from terra.mapping.sessions import session_list
from terra.mapping.state import append_base, check_run, restore_mapper, run_description, wgs84_anchor, write_fused
from terra.mapping.storage import MAP_FORMAT
from terra.perception.base import Perception
from terra.perception.cache import CachedPerception, cached
from terra.perception.registry import get_perception
from terra.progress import StageTimer
from terra.progress import progress as progress_bar


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
    append: bool = False,
    accept: Callable[[dict, dict], None] | None = None,
    join: dict | None = None,
) -> MapRun:
    """`build_map` with its timings and counters (used by `terra map` for the summary). `feed` orders the
    frames (default `SerialFeed`); `timer` collects the stage timings (a new one by default). `append`:
    continue the map already in `out` from its kept fusion state, the frames of `dataset` following its
    own (the same bytes as one run over both sources); the scene graph, if any, is kept and marked stale.
    `accept` sees the finished map's counters and notes before anything is written: a TerraError it
    raises leaves `out` as it was and no checkpoint behind (`terra map --strict`). `join`: the frames are a new
    session of the map in `out` (as `append`, its poses already in the map's frame), described by this record
    (T_map_session, how it was found, its fit: terra/mapping/sessions.py); its returns are counted apart."""
    out = Path(out)
    timer = timer if timer is not None else StageTimer()
    feed = feed if feed is not None else SerialFeed(show_progress)
    recover(out)  # leftovers of an interrupted run: a killed final write, a swap cut short
    base = append_base(out) if append or join is not None else None
    if base is None:
        check_output(out)
    n_frames = len(dataset)
    if n_frames == 0:
        raise TerraError(f"dataset {dataset.name!r} has no frames")
    with timer.stage("setup"):
        perception = open_perception(config, dataset, out, perception)
        run = run_description(config, perception)
        mapper, global_map = _new_mapper(dataset, config, perception, timer, base, run)
        source = {"name": dataset.name, "fingerprint": dataset_fingerprint(dataset), "frames": n_frames}
        sources = _sources(base, source, mapper.next_frame)
    if join is not None:
        mapper.fusion.begin_session()
        sources[-1].update(join, session=len(session_list(sources[:-1])) + 1)
    key = _run_key(config, source, perception, global_map, base)
    key = key if join is None else fingerprint({"run": key, "join": join})
    checkpoint = Checkpoint(out)
    start = _resume(checkpoint, key, mapper)
    try:
        stats = _fuse_all(dataset, mapper, checkpoint, key, start, feed)
        if accept is not None:
            try:
                accept(stats, dict(mapper.stats.notes))
            except TerraError:
                checkpoint.discard()
                raise
        with timer.stage("write"):
            bundle = _write(out, mapper, run, dataset, sources, base)
    except OutputError as exc:
        raise OutputError(f"{exc}{_resume_hint(checkpoint)}") from None
    checkpoint.discard()
    notes = dict(mapper.stats.notes)
    return MapRun(bundle, map_counts(bundle), timer, stats, notes, start, cache_summary(perception))


def _new_mapper(
    dataset: Dataset, config: MappingConfig, perception: Perception, timer: StageTimer, base: Bundle | None, run: dict
) -> tuple[Mapper, np.ndarray | None]:
    """A fresh mapper for `dataset` (on its own global map when it has one), or the mapper of `base`'s map
    restored from its kept state (after checking it was fused the same way)."""
    global_map, dropped = _global_map(dataset, config) if base is None else (None, 0)
    fusion = MapFusion(config, perception.terrain_classes, perception.dim, global_map)
    mapper = Mapper(config, perception, fusion, timer)
    if base is None:
        fusion.stats.add("global_map_points_nonfinite", dropped)
        return mapper, global_map
    check_run(base, run)
    restore_mapper(base, mapper)
    return mapper, None


def _sources(base: Bundle | None, source: dict, first_frame: int) -> list[dict]:
    """The map's sources after this run: the base's (refusing a source already fused) and this one."""
    info = base.model.components.map if base is not None else None
    earlier = list(info.sources or ([info.dataset] if info.dataset else [])) if info is not None else []
    for old in earlier:
        if isinstance(old, dict) and old.get("fingerprint") == source["fingerprint"]:
            raise TerraError(
                f"{source['name']}: this source is already in the map (same content as {str(old.get('name')):.200}); "
                "nothing appended"
            )
    return [*earlier, {**source, "first_frame": int(first_frame)}]


def map_counts(bundle: Bundle) -> MapCounts:
    """The sizes of the map stored in `bundle` (as its manifest lists them)."""
    info = bundle.model.components.map
    sizes = (info.points, info.observed_points, info.bank, info.images) if info is not None else (None,)
    if info is None or any(n is None for n in sizes):
        raise TerraError(f"{bundle.path}/manifest.json: components.map lacks the map's sizes")
    return MapCounts(int(info.points or 0), int(info.observed_points or 0), int(info.bank or 0), int(info.images or 0))


def _fuse_all(dataset: Dataset, mapper: Mapper, checkpoint: Checkpoint, key: str, start: int, feed: FrameFeed):
    """Frames `start`.. of `dataset` fused in the order `feed` hands them over (checkpointed every
    `checkpoint_every`), then the stats."""
    n_frames = len(dataset)
    fused_before = mapper.stats.counts.get("frames_fused", 0)
    every = mapper.config.checkpoint_every
    for i in feed.frames(start, n_frames):
        with mapper.timer.stage("load"):
            frame = read_frame(dataset, i, mapper)
        if frame is not None:
            mapper.add(frame)
        done = i + 1
        if done % every == 0 and done < n_frames:
            with mapper.timer.stage("checkpoint"):
                arrays, meta = mapper.fusion.state()
                stamps = [mapper.first_stamp, mapper.last_stamp, mapper.run_first_stamp]
                meta["mapper"] = {"next_frame": mapper.next_frame, "stamps": stamps}
                checkpoint.save(key, done, arrays, meta)

    stats = mapper.stats.to_json()
    if stats.get("frames_fused", 0) == fused_before:
        checkpoint.discard()  # nothing to resume: a rerun would meet the same frames
        first = next(iter(mapper.stats.notes.values()), "")
        raise TerraError(
            f"dataset {dataset.name!r}: none of its {n_frames} frames could be used ({_fault_summary(stats)})"
            + (f"; first: {first}" if first else "")
        )
    return stats


def read_frame(dataset: Dataset, i: int, mapper: Mapper) -> Frame | None:
    """Frame i of `dataset`, or None (counted as the mapper's next frame) when its file cannot be read."""
    try:
        return dataset[i]
    except TerraError as exc:
        mapper.skip("frames_skipped_unreadable", str(exc))
        return None


def _write(
    out: Path,
    mapper: Mapper,
    run: dict,
    dataset: Dataset,
    sources: list[dict],
    base: Bundle | None,
) -> Bundle:
    """The map, its fusion state and its sources as the bundle's next version (`base`'s other
    components kept, the scene graph then stale until rebuilt)."""
    name = dataset.name if base is None else _first_name(base, dataset)
    with BundleWriter(out, base=base, drop_components=("map",)) as writer:
        write_fused(writer, mapper, run, name, dataset.classes, sources, wgs84_anchor(base, dataset))
    return Bundle(out)


def _first_name(base: Bundle, dataset: Dataset) -> str:
    """map/meta.json keeps the name of the first source mapped (later ones are listed in the manifest)."""
    from terra.schemas import MapMeta

    return str(base.document("map/meta.json", MapMeta).dataset or dataset.name)


def _resume_hint(checkpoint: Checkpoint) -> str:
    """What a rerun will do after a write failure: resume from the last checkpoint, if there is one."""
    if checkpoint.exists():
        return f"; rerun the same command to resume from the checkpoint in {checkpoint.folder}"
    return ""


def _run_key(
    config: MappingConfig, source: dict, perception: Perception, global_map: np.ndarray | None, base: Bundle | None
) -> str:
    """What a checkpoint must match to be resumed: everything that changes the map's bytes. `source`: the
    dataset's name, content fingerprint and frame count; `base`: the bundle an append continues."""
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
            # An append continues one exact map: its files' checksums.
            "append_to": None
            if base is None
            else {name: entry.sha256 for name, entry in base.files.items() if name.startswith("map/")},
        }
    )


def _resume(checkpoint: Checkpoint, key: str, mapper: Mapper) -> int:
    """The first dataset frame to fuse: after a matching checkpoint (restored into `mapper`), else 0 (any
    stale checkpoint removed)."""
    saved = checkpoint.load(key)
    if saved is None:
        checkpoint.discard()
        return 0
    start, arrays, meta = saved
    mapper.fusion.restore(arrays, meta)
    progress = meta.get("mapper", {})
    mapper.next_frame = int(progress.get("next_frame", start))
    stamps = progress.get("stamps", [None, None])
    mapper.first_stamp, mapper.last_stamp = stamps[0], stamps[1]
    mapper.run_first_stamp = stamps[2] if len(stamps) > 2 else None
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
    from terra.bundle import refuse_foreign

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
    return check_frame(frame, i, stats)


def _fault_summary(stats: dict[str, int]) -> str:
    faults = {k: v for k, v in stats.items() if "skipped" in k}
    return ", ".join(f"{k}={v}" for k, v in faults.items()) or "no frames"
