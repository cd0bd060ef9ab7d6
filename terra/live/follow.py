"""Any frame source into a live map: frames fused as they come, a version committed every few
seconds (`terra map SOURCE --follow`).

The session is opened on the first frame (a recording still to start has no name yet); each
`snapshot_every` seconds with new frames (in row chunks shared between versions), and once more
at the end (as `Session.close`, in the flat layout batch runs write), the map and its fusion state
are committed as the bundle's next version, so readers (`terra serve`, `terra find`) see the map
grow and a crash keeps the last version. Frames reach `Session.add` exactly as `terra map` hands
them to its mapper, so the final map equals the batch map of the same frames byte for byte.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from terra.datasets.stream import FrameSource, WaitingSource
from terra.errors import TerraError
from terra.live.frames import LiveFrameError
from terra.live.session import Session
from terra.mapping.config import MappingConfig


@dataclass
class FollowRun:
    """What `follow` did: the session (its mapper's counters and timings), the bundle versions
    committed, the frames fused, and how many of those were fused since the last version."""

    session: Session
    versions: list[int] = field(default_factory=list)
    pending: int = 0


def follow(
    source: FrameSource,
    out: Path,
    config: MappingConfig,
    *,
    resume: bool = False,
    overwrite: bool = False,
    snapshot_every: float = 5.0,
    clock: Callable[[], float] = time.monotonic,
) -> FollowRun:
    """Fuse every frame of `source` into the bundle `out`, committing a version at most every
    `snapshot_every` seconds (and at the end). resume: continue the map in `out` (`--append`);
    overwrite: replace a bundle there. TerraError when the source gave no frame."""
    run: FollowRun | None = None
    last = clock()

    def commit(due: bool) -> None:
        nonlocal last
        if run is None or not run.pending or not run.session.mapper.stats.counts.get("frames_fused", 0):
            return  # nothing new, or nothing fused yet (a version needs a map)
        if not due or clock() - last >= snapshot_every:
            run.versions.append(run.session.snapshot().version)
            run.pending, last = 0, clock()

    if isinstance(source, WaitingSource):
        source.on_wait = lambda: commit(due=True)
    for frame in source.frames():
        if run is None:
            session = Session(
                out, source.classes, config, graph=False, resume=resume, overwrite=overwrite, name=source.name
            )
            run = FollowRun(session)
        try:
            run.session.add(frame)
        except LiveFrameError:
            continue  # counted in run.session.refused (e.g. a stamp equal to the last one), never fused
        run.pending += 1
        commit(due=True)
    if run is None:
        raise TerraError(f"{source.name}: the source gave no frame; nothing mapped")
    # The recording ended: the last version in the flat layout batch runs write (the versions before
    # it share row chunks, terra/mapping/chunks.py), so the bundle is the batch map's, file for file.
    closed = run.session.close()
    if closed is not None:
        run.versions.append(closed.version)
    return run
