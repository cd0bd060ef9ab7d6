"""A map that grows while the robot drives: frames in one at a time, consistent snapshots out.

`Session` owns the live map: one `Mapper` (the same incremental Phase 1 as `terra map`) and the
bundle it commits to. `add_frame` checks a frame (one line naming the field for anything wrong,
counted, never fused) and fuses it; `snapshot()` commits the map with its fusion state as the
bundle's next version, rebuilds the scene graph on it and returns a read view (`Snapshot`) that
stays valid while later versions are written. A session over an existing bundle (`resume=True`)
continues its kept fusion state, exactly as `terra map --append` does, so a drive fed live gives
the same map, byte for byte, as the same frames mapped in one batch.

Threads: `add_frame` and the map commit of `snapshot` take the mapper's lock; a snapshot's graph
rebuild runs beside new frames (one snapshot at a time). Readers use the `latest` snapshot, which
is replaced, never changed.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from terra.bundle import MANIFEST, Bundle, BundleWriter, recover, wait_for_reclaims
from terra.datasets.base import CameraFrame, ClassTable, Frame
from terra.errors import TerraError
from terra.live.frames import LiveFrameError, check_live_frame
from terra.loaded import LoadedBundle
from terra.mapping.align import Alignment
from terra.mapping.chunk_views import forget as forget_view
from terra.mapping.chunks import CHUNK_ROWS
from terra.mapping.config import MappingConfig
from terra.mapping.fusion import MapFusion
from terra.mapping.mapper import Mapper
from terra.mapping.semantic_map import MetricSemanticMap
from terra.mapping.state import (
    append_base,
    check_run,
    restore_mapper,
    run_description,
    wgs84_anchor,
    write_fused,
    write_live,
)
from terra.mapping.storage import load_map
from terra.perception.base import Perception

__all__ = ["LiveFrameError", "Session", "Snapshot"]


@dataclass(frozen=True)
class Snapshot:
    """One committed version of a live map. `map_time`: the stamp (s) of the last frame fused into
    it; `graph_note`: why the version has no scene graph yet (e.g. too little ground seen), or ''."""

    version: int
    frames: int
    map_time: float | None
    bundle: LoadedBundle
    graph_note: str = ""
    seconds: dict[str, float] = field(default_factory=dict)  # commit stages: map, graph, load
    graph_update: dict = field(default_factory=dict)  # what the graph update did (terra.graph.update.UpdateStats)


@dataclass
class RefusedFrames:
    """Frames `add_frame` refused, by reason, with the first line of each."""

    counts: dict[str, int] = field(default_factory=dict)
    notes: dict[str, str] = field(default_factory=dict)

    def add(self, reason: str, message: str) -> None:
        self.counts[reason] = self.counts.get(reason, 0) + 1
        self.notes.setdefault(reason, message)


class Session:
    """The live map written to the bundle folder `out`.

    classes: the source's label vocabulary (the `labels` backend embeds its names; models
    backends need only its terrain classes). config: Phase 1 settings (default MappingConfig()).
    build: Phase 2 settings for the graph of each snapshot (default BuildConfig()); graph=False
    commits maps only. resume: continue the map already in `out` (its classes, config and embedder
    must match); otherwise an existing bundle at `out` is refused unless overwrite.
    global_map: a prior map (M, 3) metres in the map frame (e.g. the source's own, as `terra map`
    uses a dataset's): scan points then take their nearest prior point within fusion.gate instead
    of accumulating voxels.
    join: this drive is a new session of the map already in `out` (terra/mapping/sessions.py): its frames'
    T_map_lidar are in its own frame and are moved by T_map_session, given as an Alignment (e.g. from
    `plan_join` over a recording of the drive) or as a 4x4 array (then listed as given by the caller); its
    LiDAR returns are counted apart.
    chunk_rows: rows per chunk of the per-point arrays of a snapshot's version (terra/mapping/chunks.py):
    a snapshot writes again only the chunks in which a point changed.
    """

    def __init__(
        self,
        out: str | Path,
        classes: ClassTable,
        config: MappingConfig | None = None,
        *,
        build=None,
        graph: bool = True,
        perception: Perception | None = None,
        resume: bool = False,
        overwrite: bool = False,
        name: str = "live",
        global_map: np.ndarray | None = None,
        join: Alignment | np.ndarray | None = None,
        chunk_rows: int = CHUNK_ROWS,
    ):
        from terra.perception.registry import get_perception

        self.out = Path(out)
        self.name = name
        self.classes = classes
        self.config = config if config is not None else MappingConfig()
        self.build = build
        self.graph = graph
        if chunk_rows < 1:
            raise TerraError(f"chunk_rows: expected at least 1 row per chunk, got {chunk_rows}")
        self.chunk_rows = int(chunk_rows)
        self.perception = perception or get_perception(self.config.perception, classes)
        recover(self.out)
        self._base = _open_base(self.out, resume or join is not None, overwrite)
        prior = _prior_map(global_map) if global_map is not None and self.config.fusion.use_global_map else None
        fusion = MapFusion(self.config, self.perception.terrain_classes, self.perception.dim, prior)
        self.mapper = Mapper(self.config, self.perception, fusion)
        self._run = run_description(self.config, self.perception)
        if self._base is not None and (resume or join is not None):
            check_run(self._base, self._run)
            restore_mapper(self._base, self.mapper)
        self._join = _join_record(self._base, join, self.mapper) if join is not None else None
        self._first_frame = self.mapper.next_frame
        self.refused = RefusedFrames()
        self._lock = threading.Lock()  # the mapper: add_frame and the map commit
        self._snapshot_lock = threading.Lock()  # the bundle: one snapshot at a time
        self._latest: Snapshot | None = None
        self._closed = False  # close() committed the last version and let go of the fusion state
        self._updater = None  # terra.graph.update.GraphUpdater, made at the first graph commit
        self.last_frame_at: float | None = None  # time.monotonic() of the last accepted frame

    # -- frames in --------------------------------------------------------------------------

    def add_frame(
        self,
        points: np.ndarray,
        T_map_lidar: np.ndarray,
        stamp: float,
        times: np.ndarray | None = None,
        images: Sequence[CameraFrame] = (),
        intensity: np.ndarray | None = None,
        labels: np.ndarray | None = None,
        instances: np.ndarray | None = None,
    ) -> bool:
        """Fuse one LiDAR scan: points (N, 3) metres in the LiDAR frame, T_map_lidar its 4x4 pose
        in the map frame, stamp seconds (increasing), times (N,) seconds from `stamp` per point,
        images the camera frames taken with it, labels / instances (N,) per-point ids of `classes`.
        Returns whether it was fused (False: skipped as `terra map` skips, e.g. no finite point);
        LiveFrameError (one line naming the field; counted in `refused`) for a malformed frame."""
        with self._lock:
            self._check_open()
            last = self.mapper.last_stamp
            if self._join is not None and self.mapper.next_frame == self._first_frame:
                last = None  # a joined drive keeps its own clock
            try:
                frame = check_live_frame(
                    points, T_map_lidar, stamp, times, images, intensity, labels, instances, last_stamp=last
                )
            except LiveFrameError as exc:
                self.refused.add(exc.reason, str(exc))
                raise
            if self._join is not None:
                frame.T_map_lidar = np.asarray(self._join["T_map_session"]) @ frame.T_map_lidar
            fused = self.mapper.add(frame)
            self.last_frame_at = time.monotonic()
            return fused

    def add(self, frame: Frame) -> bool:
        """`add_frame` for a ready Frame (e.g. from a dataset or a bag being recorded)."""
        return self.add_frame(
            frame.points,
            frame.T_map_lidar,
            frame.stamp,
            frame.point_times,
            frame.cameras,
            frame.intensity,
            frame.point_labels,
            frame.point_instances,
        )

    # -- snapshots out ----------------------------------------------------------------------

    @property
    def latest(self) -> Snapshot | None:
        """The last committed snapshot (None before the first)."""
        return self._latest

    @property
    def frames(self) -> int:
        """Frames offered to the map so far, over every session of the bundle."""
        return self.mapper.next_frame

    def snapshot(self, full: bool = False) -> Snapshot:
        """Commit everything fused so far as the bundle's next version (map, fusion state and, with
        graph=True, the scene graph updated on it) and return its read view. Frames wait only while
        the map is written: the graph is updated (and the view loaded) while they keep fusing.

        The graph is rebuilt only around what changed since the previous snapshot
        (terra.graph.update); full=True rebuilds it whole, as `terra build` does (`close`)."""
        return self._snapshot(full, closing=False)

    def _snapshot(self, full: bool, closing: bool) -> Snapshot:
        """snapshot(); `closing`: the last one, after which the fusion state is let go of before the
        whole-map build, so the build's working set does not sit beside it."""
        with self._snapshot_lock:  # one commit at a time
            seconds: dict[str, float] = {}
            start = time.perf_counter()
            with self._lock:
                self._check_open()
                if self.mapper.stats.counts.get("frames_fused", 0) == 0:
                    raise TerraError(f"{self.out}: no frame fused yet; nothing to commit")
                frames, map_time = self.mapper.next_frame, self.mapper.last_stamp
                committed = self._commit_map(finished=full)
                if closing:
                    self._closed = True
                    self.mapper.fusion.release()
                    forget_view(self.out)
                    self._latest = None  # a reader holding it keeps it; the session needs it no more
                # The graph update reads the map as fused (full: as `terra build` reads it, below).
                msm = self.mapper.finish() if self.graph and not full else None
            seconds["map"] = time.perf_counter() - start
            if full and self.graph:
                # As `terra build` reads it (e.g. the bank rounded to float16): the batch graph exactly,
                # one copy of the map beside the whole-map build.
                msm = load_map(Bundle(self.out), max_ids=False)
            note, update = self._commit_graph(msm, full) if msm is not None else ("graph off", {})
            seconds["graph"] = time.perf_counter() - start - seconds["map"]
            bundle = Bundle(self.out) if msm is not None and not note else committed  # a graph version came after
            self._base = bundle
            loaded = LoadedBundle(bundle)
            loaded.require_map()  # read now: the view answers from this version whatever follows
            _ = loaded.graph
            seconds["load"] = time.perf_counter() - start - seconds["map"] - seconds["graph"]
            snapshot = Snapshot(bundle.version, frames, map_time, loaded, note, seconds, update)
            self._latest = snapshot
            return snapshot

    def close(self) -> Snapshot | None:
        """End the drive: a last snapshot with the graph built in full, so the session's final graph
        is the batch graph of its map (`terra build` on the bundle gives the same). None when no
        frame was fused. The fusion state is let go of before that build (it would double the peak
        memory of a large map); a closed session fuses nothing more, and a second close() returns
        the same snapshot."""
        if self._closed:
            return self._latest
        if self.mapper.stats.counts.get("frames_fused", 0) == 0:
            return None
        snapshot = self._snapshot(full=True, closing=True)
        wait_for_reclaims()  # the folder holds the closing version alone when close returns
        return snapshot

    def _check_open(self) -> None:
        if self._closed:
            raise TerraError(f"{self.out}: the session is closed; a new Session(..., resume=True) continues the drive")

    def _commit_map(self, finished: bool) -> Bundle:
        """Commit the map and its fusion state as the bundle's next version: in row chunks shared with
        the version before (terra/mapping/chunks.py), or `finished`, in the flat layout batch runs write.
        Returns the committed version."""
        fingerprint = f"live:{self.name}:{self._first_frame}"  # one entry per session, updated per snapshot
        source = {"name": self.name, "fingerprint": fingerprint, "frames": self.mapper.next_frame}
        sources = _sources(self._base, source, self._first_frame)
        if self._join is not None:
            sources[-1].update(self._join)
        writer = BundleWriter(self.out, base=self._base, drop_components=("map",))
        try:
            anchor = wgs84_anchor(self._base)
            args = (writer, self.mapper, self._run, self.name, self.classes, sources, anchor)
            if finished:
                write_fused(*args)
            else:
                write_live(*args, chunk_rows=self.chunk_rows)
            committed = writer.commit(reclaim_in_background=True)  # the replaced version is deleted off the hot path
        except BaseException:
            writer.abort()
            raise
        self.mapper.fusion.untouch()  # the next version starts from this one
        return committed

    def _commit_graph(self, msm: MetricSemanticMap, full: bool) -> tuple[str, dict]:
        """Update the scene graph on the committed map `msm` (with `full`, the map as stored) and commit it:
        ('' when built, else why not, the map being too young for places: the version keeps the map alone;
        what the update did)."""
        from terra.graph.pipeline import commit_graph, previous_graph
        from terra.graph.update import GraphUpdater

        if self._updater is None:  # the bundle's graph (resume): its ids and saved objects are kept
            self._updater = GraphUpdater(self.build, previous_graph(self._base) if self._base is not None else None)
        try:
            result = self._updater.update(msm, full=full)
        except TerraError as exc:
            return str(exc), {}
        update = result.update.to_json()
        commit_graph(Bundle(self.out), result, self._updater.config, update=update)
        return "", update


def _open_base(out: Path, resume: bool, overwrite: bool) -> Bundle | None:
    """The bundle a session continues (resume) or will replace (overwrite), after the same checks
    as `terra map` and `--append`."""
    from terra.mapping.pipeline import check_output

    if resume:
        return append_base(out)
    check_output(out)
    if (out / MANIFEST).is_file() and not overwrite:
        raise TerraError(f"{out}: a bundle exists; pass resume=True to continue it or overwrite=True to replace it")
    return None


def _sources(base: Bundle | None, source: dict, first_frame: int) -> list[dict]:
    """The map's sources: the base's, with this session's entry added (or updated on a later snapshot)."""
    info = base.model.components.map if base is not None else None
    earlier = list(info.sources or ([info.dataset] if info.dataset else [])) if info is not None else []
    earlier = [s for s in earlier if not (isinstance(s, dict) and s.get("fingerprint") == source["fingerprint"])]
    frames = source["frames"] - first_frame
    return [*earlier, {**source, "frames": frames, "first_frame": int(first_frame)}]


def _join_record(base: Bundle | None, join: Alignment | np.ndarray, mapper: Mapper) -> dict:
    """The source entry of a joined session (its number and alignment); its returns counted from now on."""
    from terra.mapping.sessions import session_list

    info = base.model.components.map if base is not None else None
    number = len(session_list(list(info.sources or []) if info is not None else [])) + 1
    if isinstance(join, Alignment):
        record = join.to_json()
    else:
        T = np.asarray(join, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all() or not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0]):
            raise TerraError(f"join: expected T_map_session as a 4x4 rigid pose, got shape {T.shape}")
        record = {"T_map_session": T.tolist(), "how": "given by the caller"}
    mapper.fusion.begin_session()
    return {**record, "session": number}


def _prior_map(points: np.ndarray) -> np.ndarray:
    """The finite rows of a prior map as (M, 3) float32 metres (TerraError when none is usable)."""
    array = np.asarray(points)
    if array.ndim != 2 or array.shape[1] < 3 or not np.issubdtype(array.dtype, np.number):
        raise TerraError(f"global_map: expected an (M, 3) array of metres, got shape {array.shape}")
    array = array[:, :3].astype(np.float32)
    finite = array[np.isfinite(array).all(axis=1)]
    if finite.shape[0] == 0:
        raise TerraError("global_map: no finite point")
    return finite
