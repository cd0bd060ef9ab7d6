"""The client side of distributed Phase 1: frames handed to Dask workers, handed on to fusion in order.

`ClusterFeed` is a `FrameFeed` (terra.mapping.pipeline): it submits one `perceive_task` per frame, at
most `in_flight` frames ahead of the frame being fused, collects results as they complete (in any
order) and yields frame i once its perception is in the cache, so the client fuses frames in order
while the workers run ahead. Memory stays bounded on both sides: a result is a few numbers, and no
more than `in_flight` tasks exist at a time. When a worker dies, Dask reschedules the frames it held
on another worker; the feed only sees them complete later. Closing the feed (an error, Ctrl-C)
cancels the tasks still pending.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from terra.distributed.job import PerceptionJob
from terra.distributed.worker import perceive_task
from terra.errors import TerraError


@dataclass
class WorkerTally:
    """What the workers reported: frames perceived, images (computed and read back from the cache),
    seconds of perception summed over workers (wall and CPU), frames per worker, fault counters and
    first notes, and when each frame finished (Unix time, in the order the client collected them)."""

    frames: int = 0
    images: int = 0
    computed: int = 0
    hits: int = 0
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    by_worker: dict[str, int] = field(default_factory=dict)
    stats: dict[str, int] = field(default_factory=dict)
    notes: dict[str, str] = field(default_factory=dict)
    finished: list[float] = field(default_factory=list)

    def add(self, result: dict[str, Any]) -> None:
        self.frames += 1
        self.images += int(result["images"])
        self.computed += int(result["computed"])
        self.hits += int(result["hits"])
        self.seconds += float(result["seconds"])
        self.cpu_seconds += float(result["cpu_seconds"])
        self.finished.append(float(result["finished"]))
        self.by_worker[result["worker"]] = self.by_worker.get(result["worker"], 0) + 1
        for name, count in result["stats"].items():
            self.stats[name] = self.stats.get(name, 0) + int(count)
        for name, note in result["notes"].items():
            self.notes.setdefault(name, note)

    def to_json(self) -> dict:
        return {
            "frames": self.frames,
            "images": self.images,
            "computed": self.computed,
            "hits": self.hits,
            "seconds": round(self.seconds, 6),
            "cpu_seconds": round(self.cpu_seconds, 6),
            "by_worker": dict(sorted(self.by_worker.items())),
        }


class ClusterFeed:
    """Frames perceived by the workers of `client`, handed to fusion in order (see the module docstring)."""

    def __init__(self, client: Any, job: PerceptionJob, in_flight: int, show_progress: bool = True):
        if in_flight < 1:
            raise ValueError("in_flight must be at least 1")
        self.client = client
        self.job = job
        self.job_text = job.to_text()
        self.in_flight = int(in_flight)
        self.show_progress = show_progress
        self.tally = WorkerTally()
        self.outstanding = 0  # frames submitted and not yet handed to fusion

    def frames(self, start: int, stop: int) -> Iterator[int]:
        from distributed import as_completed

        held: dict[str, tuple[int, Any]] = {}  # task key -> (frame index, future), until its result is in
        perceived: set[int] = set()  # frames whose result is in and which fusion has not taken yet
        completed = as_completed(loop=self.client.loop)
        submitted = start
        bars = _Bars(stop - start, self.show_progress)
        try:
            for i in range(start, stop):
                while submitted < stop and submitted - i < self.in_flight:
                    future = self._submit(submitted)
                    held[future.key] = (submitted, future)
                    completed.add(future)
                    submitted += 1
                self.outstanding = submitted - i
                while i not in perceived:
                    future = next(completed)
                    index, _ = held.pop(future.key)
                    self.tally.add(_result(future, index))
                    future.release()
                    perceived.add(index)
                    bars.perceived()
                perceived.discard(i)
                yield i
                bars.fused()
        finally:
            bars.close()
            if held:
                self.client.cancel([future for _, future in held.values()])

    def _submit(self, index: int) -> Any:
        # Earlier frames first: fusion waits for them, later ones can wait in the queue.
        return self.client.submit(perceive_task, self.job_text, index, key=self.job.task_key(index), priority=-index)


def _result(future: Any, index: int) -> dict:
    """A finished task's result; a worker's TerraError as it is, a frame that kept killing workers as one."""
    from concurrent.futures import CancelledError

    from distributed import KilledWorker

    try:
        return future.result()
    except TerraError:
        raise
    except CancelledError:
        raise TerraError(f"frame {index}: the Dask scheduler cancelled its task (was the cluster restarted?)") from None
    except KilledWorker:
        raise TerraError(
            f"frame {index}: every worker that perceived it died (Dask stops retrying a task after "
            "distributed.scheduler.allowed-failures deaths); out of memory? see the workers' logs"
        ) from None


class _Bars:
    """Two progress bars on stderr: frames perceived (by the workers) and frames fused (here)."""

    def __init__(self, total: int, enabled: bool):
        from tqdm.auto import tqdm

        shown = enabled and sys.stderr.isatty()
        options = {"total": total, "leave": False, "dynamic_ncols": True, "disable": not shown}
        self._perceived = tqdm(desc="perceived", position=0, **options)
        self._fused = tqdm(desc="fused    ", position=1, **options)

    def perceived(self) -> None:
        self._perceived.update(1)

    def fused(self) -> None:
        self._fused.update(1)

    def close(self) -> None:
        self._fused.close()
        self._perceived.close()
