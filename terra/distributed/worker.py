"""What runs inside a Dask worker process: open the source and the models once, perceive frames.

`perceive_task(job_text, index)` is the unit of work (terra.mapping.perceive.perceive_frame into the
shared cache), `prepare_task(job_text)` runs once per worker at the start of a run so every worker
opens the source, loads its models and checks its view of the run before any frame is handed out.

Models are loaded once per worker process, not once per frame: the process keeps the last opened
dataset and the last loaded backend, keyed by what they depend on, and a later job with the same
source or the same perception settings reuses them (a long-lived cluster serving several runs). This
per-process cache is filled lazily from the task thread, not from a Dask WorkerPlugin, whose setup
would load the models on the worker's event loop and stall its heartbeats for as long as that takes.
Tasks of one process run one at a time (a lock): loaders and backends are not promised to be
thread-safe, and model backends use every core through their own thread pools anyway; give a Dask
worker one thread and as many processes as you like.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import terra
from terra.datasets.base import Dataset
from terra.distributed.job import PerceptionJob, classes_fingerprint
from terra.errors import TerraError
from terra.mapping.checkpoint import fingerprint
from terra.mapping.config import MappingConfig
from terra.mapping.fusion import FusionStats
from terra.mapping.perceive import perceive_frame
from terra.perception.base import Perception
from terra.perception.cache import CachedPerception, PerceptionCache, backend_key, cache_identity
from terra.perception.registry import get_perception

_LOCK = threading.Lock()
_SLOTS: dict[str, tuple[str, Any]] = {}  # "dataset" / "backend" -> (key, object): one of each per process

SAME_SOURCE = (
    "workers read frames themselves: the source must be at the same path on every worker (or on a shared file system)"
)


@dataclass
class WorkerState:
    """One job as a worker process holds it."""

    dataset: Dataset
    perception: CachedPerception
    config: MappingConfig


def prepare_task(job_text: str) -> dict:
    """Open the job's source and backend in this process and check them against the client's view."""
    start = time.perf_counter()
    with _LOCK:
        _state(PerceptionJob.from_text(job_text))
    return {"worker": worker_name(), "pid": os.getpid(), "seconds": time.perf_counter() - start}


def perceive_task(job_text: str, index: int) -> dict:
    """Perceive frame `index` into the shared cache; returns counts (images, computed, hits), the fault
    counters and first notes, the seconds it took (wall, and CPU of this process), when it finished (Unix
    time) and the worker's name."""
    job = PerceptionJob.from_text(job_text)
    with _LOCK:
        state = _state(job)
        start, cpu = time.perf_counter(), time.process_time()
        before = state.perception.counts.to_json()
        stats = FusionStats()
        images = perceive_frame(state.dataset, int(index), state.perception, state.config, stats)
        after = state.perception.counts.to_json()
        cpu = time.process_time() - cpu
    return {
        "frame": int(index),
        "images": images,
        "computed": after["computed"] - before["computed"],
        "hits": after["hits"] - before["hits"],
        "seconds": time.perf_counter() - start,
        "cpu_seconds": cpu,
        "finished": time.time(),
        "worker": worker_name(),
        "stats": stats.to_json(),
        "notes": dict(stats.notes),
    }


def worker_name() -> str:
    """This worker's address, or "process PID" outside a Dask worker."""
    try:
        from distributed import get_worker

        return f"worker {get_worker().address}"
    except (ImportError, ValueError):
        return f"process {os.getpid()}"


def _state(job: PerceptionJob) -> WorkerState:
    if job.expect["terra"] != terra.__version__:
        raise TerraError(
            f"{worker_name()} runs Terra {terra.__version__}, the client {job.expect['terra']}: install the same "
            "Terra on every worker"
        )
    config = job.mapping_config()
    dataset = _slot("dataset", fingerprint(job.source.to_json()), lambda: _open_source(job))
    _check_dataset(job, dataset)
    perception_json = config.perception.model_dump(mode="json", exclude={"cache"})
    # The client's backend key covers the weight files' contents: files replaced since this process
    # loaded them give another key, hence a fresh backend.
    backend_id = fingerprint(
        {"perception": perception_json, "classes": dataset.classes.to_json(), "expect": job.expect["backend"]}
    )
    inner = _slot("backend", backend_id, lambda: get_perception(config.perception, dataset.classes))
    return WorkerState(dataset, _cached(job, inner), config)


def _slot(name: str, key: str, build) -> Any:
    held = _SLOTS.get(name)
    if held is not None and held[0] == key:
        return held[1]
    _SLOTS.pop(name, None)  # free the previous one before building (models can be large)
    value = build()
    _SLOTS[name] = (key, value)
    return value


def _open_source(job: PerceptionJob) -> Dataset:
    try:
        return job.source.open_for_perception()
    except TerraError as exc:
        where = job.source.describe()
        raise TerraError(f"{worker_name()} cannot open the source {where} ({exc}); {SAME_SOURCE}") from None


def _check_dataset(job: PerceptionJob, dataset: Dataset) -> None:
    expect = job.expect
    seen = {"dataset": dataset.name, "frames": len(dataset), "classes": classes_fingerprint(dataset)}
    for what in ("dataset", "frames", "classes"):
        if seen[what] != expect[what]:
            found = "another class table" if what == "classes" else f"{what} {seen[what]!r}"
            found += "" if what == "classes" else f", the client's {expect[what]!r}"
            raise TerraError(f"{worker_name()} opened {job.source.describe()} and found {found}; {SAME_SOURCE}")


def _cached(job: PerceptionJob, inner: Perception) -> CachedPerception:
    identity = cache_identity(inner)
    key = backend_key(identity)
    if key != job.expect["backend"]:
        raise TerraError(
            f"{worker_name()} builds another perception backend than the client (backend key {key[:16]}, the "
            f"client's {job.expect['backend'][:16]}): workers need the same model files (compared by content), "
            "settings and Terra version"
        )
    root = Path(job.cache_root)
    if not (root / key[:16] / "backend.json").is_file():
        raise TerraError(
            f"{worker_name()} does not see the perception cache {root / key[:16]} that the client created: the cache "
            "folder must be on a file system the client and every worker share (choose it with --cache)"
        )
    return CachedPerception(inner, PerceptionCache(root, identity))
