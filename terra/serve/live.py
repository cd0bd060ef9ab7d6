"""The live side of `terra serve --live`: one terra.live.Session fed by pushed frames, committed
by a background thread every `update_every` seconds (or `update_frames` frames), and the counters
GET /live reports.

Queries take `current()` once and answer from that Snapshot alone: a snapshot is replaced, never
changed, so an answer's map and graph always belong to the version it names, whatever is committed
while it runs. Frames and snapshots are serialised by the session's own lock (one writer).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from dataclasses import dataclass, field

from terra.bundle import Bundle
from terra.errors import TerraError
from terra.geometry import CameraCalibration
from terra.live.frames import LiveFrameError
from terra.live.session import Session, Snapshot
from terra.live.wire import decode_frame, parse_cameras
from terra.loaded import LoadedBundle
from terra.mapping.chunks import is_chunked
from terra.serve.config import LiveConfig

log = logging.getLogger("terra.serve")


class NotReady(TerraError):
    """A query to a live service that has no committed version yet (503)."""


@dataclass
class Counters:
    """What the service has done with the frames pushed to it."""

    received: int = 0  # POST /frames bodies read
    skipped: int = 0  # accepted but not fused (e.g. no finite point), as `terra map` skips
    updates: int = 0  # snapshots committed by this process
    last_update_s: float | None = None  # wall time of the last snapshot
    last_error: str = ""  # why the last snapshot failed, '' after a good one
    started: float = field(default_factory=time.monotonic)


class LiveService:
    """The session on `session.out` and its update thread (start() / close())."""

    def __init__(self, session: Session, settings: LiveConfig | None = None):
        self.session = session
        self.settings = settings or LiveConfig()
        self.cameras: dict[int, CameraCalibration] = {}
        self.counters = Counters()
        self._latest: Snapshot | None = _resumed_snapshot(session)
        # Whether the latest version is final (flat map, whole graph): a resumed bundle that was
        # closed is; one a crash left chunked is not.
        self._final = self._latest is None or not is_chunked(self._latest.bundle.bundle)
        self._committed_fused = self._fused()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._update_lock = threading.Lock()  # one snapshot at a time (thread and POST /snapshot)
        self._frame_lock = threading.Lock()  # frames decoded and fused one at a time, in order

    # -- public interface -------------------------------------------------------------------

    def current(self) -> Snapshot:
        """The latest committed version (NotReady before the first)."""
        latest = self._latest
        if latest is None:
            raise NotReady("no version committed yet: push frames (POST /frames) and wait for the first update")
        return latest

    def set_cameras(self, document: object) -> list[int]:
        """Register calibrations ({"cameras": {"<c>": CALIBRATION}}); the camera numbers now known."""
        self.cameras = {**self.cameras, **parse_cameras(document)}
        return sorted(self.cameras)

    def add(self, body: bytes) -> bool:
        """Decode and fuse one pushed frame; LiveFrameError (counted by reason) when it is refused.
        Returns whether it was fused."""
        with self._frame_lock:
            self.counters.received += 1
            try:
                frame = decode_frame(body, self.cameras)
            except LiveFrameError as exc:
                self.session.refused.add(exc.reason, str(exc))
                raise
            fused = self.session.add_frame(**frame.arguments())  # counts its own refusals
            self.counters.skipped += not fused
        pending = self._fused() - self._committed_fused
        if self.settings.update_frames is not None and pending >= self.settings.update_frames:
            self._wake.set()
        return fused

    def update(self, full: bool = False, closing: bool = False) -> Snapshot | None:
        """Commit the frames fused since the last version (None when there are none); full=True
        builds the graph whole (at close: the session's last graph is the batch graph of its map);
        `closing`: as the session's close(), the last version, the fusion state let go of first."""
        with self._update_lock:
            fused = self._fused()
            # At close, a version that is not yet final is written once more: in the flat layout
            # batch runs write (a live version keeps row chunks) with the graph built whole.
            if fused == self._committed_fused and not (full and self._latest is not None and not self._final):
                return None
            began = time.perf_counter()
            try:
                snapshot = self.session.close() if closing else self.session.snapshot(full=full)
            except Exception as exc:  # the service stays up; GET /live says why
                self.counters.last_error = " ".join(str(exc).split()) or type(exc).__name__
                log.error("live update failed: %s", self.counters.last_error, exc_info=not isinstance(exc, TerraError))
                raise
            self.counters.last_update_s = time.perf_counter() - began
            self.counters.updates += 1
            self.counters.last_error = ""
            self._committed_fused = fused
            self._latest, self._final = snapshot, full
            return snapshot

    def status(self) -> dict:
        """GET /live: frames received, fused, skipped and refused by reason; the latest version and
        its map time; seconds since the last accepted frame (None before one)."""
        latest = self._latest
        last = self.session.last_frame_at
        fused = self._fused()
        return {
            "bundle": str(self.session.out),
            "version": None if latest is None else latest.version,
            "map_time": None if latest is None else latest.map_time,
            "graph_note": "" if latest is None else latest.graph_note,
            "graph_update": {} if latest is None else latest.graph_update,
            "frames_received": self.counters.received,
            "frames_fused": fused,
            "frames_skipped": self.counters.skipped,
            "frames_refused": dict(self.session.refused.counts),
            "refused_notes": dict(self.session.refused.notes),
            "frames_pending": fused - self._committed_fused,
            "seconds_since_last_frame": None if last is None else round(time.monotonic() - last, 3),
            "seconds_up": round(time.monotonic() - self.counters.started, 3),
            "updates": self.counters.updates,
            "last_update_s": self.counters.last_update_s,
            "last_update_error": self.counters.last_error,
            "update_every": self.settings.update_every,
            "update_frames": self.settings.update_frames,
            "cameras": sorted(self.cameras),
        }

    def start(self) -> None:
        """Start the update thread."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="terra-live-update", daemon=True)
            self._thread.start()

    def close(self) -> None:
        """Stop the update thread and commit what was fused since the last version."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        with contextlib.suppress(Exception):  # logged by update; the last committed version stays intact
            self.update(full=True, closing=True)

    # -- private interface ------------------------------------------------------------------

    def _fused(self) -> int:
        return int(self.session.mapper.stats.counts.get("frames_fused", 0))

    def _run(self) -> None:
        every = self.settings.update_every
        due = time.monotonic() + every
        while not self._stop.is_set():
            self._wake.wait(max(0.0, due - time.monotonic()))
            self._wake.clear()
            if self._stop.is_set():
                return
            frames = self.settings.update_frames
            by_frames = frames is not None and self._fused() - self._committed_fused >= frames
            if time.monotonic() < due and not by_frames:
                continue
            with contextlib.suppress(Exception):  # logged and reported; the next interval tries again
                self.update()
            due = time.monotonic() + every


def _resumed_snapshot(session: Session) -> Snapshot | None:
    """The version a resumed session starts from, as a snapshot queries can be answered on."""
    from terra.bundle import MANIFEST

    if not (session.out / MANIFEST).is_file() or session.frames == 0:
        return None
    bundle = Bundle(session.out)
    info = bundle.model.components.map
    span = info.time_span if info is not None else None
    loaded = LoadedBundle(session.out)
    loaded.require_map()
    _ = loaded.graph
    note = "" if loaded.has_graph else "no scene graph yet"
    return Snapshot(bundle.version, session.frames, None if not span else float(span[1]), loaded, note)
