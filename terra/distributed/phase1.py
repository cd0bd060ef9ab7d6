"""Phase 1 on a Dask cluster: workers perceive frames into the cache, the client fuses them in order.

`map_on_cluster` is `run_mapping` with a `ClusterFeed`: same checkpoints, same resume, same bundle,
byte for byte, as a serial run (perception is keyed and seeded per frame and camera, and fusion reads
every image back from the cache in frame order). The cache is the hand-over, so it is on for a
distributed run even where the config turns it off (the labels backend by default); it then lives in
OUT.work/cluster-perception, which only Terra writes, and is removed when the run succeeds (an
interrupted run keeps it, and its resume reads it back). `perceive_on_cluster` is `--perception-only` on the cluster.

What the workers need: the source at the same path (or the same `--sim` preset and seed), the model
files the config names at the same paths, the cache folder on a file system they share with the client,
and the same Terra. Each worker checks all of it before its first frame and stops the run with one
line when something differs.
"""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

from terra.datasets.base import Dataset
from terra.distributed.cluster import Cluster, ClusterConfig, connect
from terra.distributed.feed import ClusterFeed, WorkerTally
from terra.distributed.job import PerceptionJob
from terra.distributed.source import SourceSpec
from terra.errors import TerraError
from terra.mapping.config import MappingConfig
from terra.mapping.perceive import PerceptionRun
from terra.mapping.pipeline import MapRun, check_output, open_perception, run_mapping
from terra.mapping.results import CacheSummary
from terra.perception.cache import (
    CachedPerception,
    PerceptionCache,
    cache_enabled,
    cache_identity,
    cache_root,
)
from terra.perception.registry import get_perception
from terra.progress import StageTimer


@dataclass
class ClusterRun:
    """Where perception ran (`cluster`, in words), on how many `workers`, with how many frames in flight,
    and what the workers reported (`tally`)."""

    cluster: str
    workers: int
    in_flight: int
    tally: WorkerTally = field(default_factory=WorkerTally)

    def to_json(self) -> dict:
        return {"cluster": self.cluster, "workers": self.workers, "in_flight": self.in_flight, **self.tally.to_json()}


def map_on_cluster(
    source: SourceSpec,
    dataset: Dataset,
    config: MappingConfig,
    out: Path,
    cluster: ClusterConfig,
    show_progress: bool = True,
    accept: Callable[[dict, dict], None] | None = None,
) -> tuple[MapRun, ClusterRun]:
    """Map `dataset` (opened from `source`) into the bundle `out`, perception on the cluster
    (`accept` as run_mapping's)."""
    out = Path(out)
    timer = StageTimer()
    check_output(out)
    if len(dataset) == 0:
        raise TerraError(f"dataset {dataset.name!r} has no frames")
    with timer.stage("setup"):
        inner = get_perception(config.perception, dataset.classes)
        temporary = not cache_enabled(inner, config.perception.cache)
        root = (transient_cache_folder(out) if temporary else cache_root(config.perception.cache, out)).absolute()
        perception = CachedPerception(inner, PerceptionCache(root, cache_identity(inner)))
    job = PerceptionJob.for_run(source, dataset, config, perception)
    with ExitStack() as stack:
        with timer.stage("cluster"):
            connected = stack.enter_context(connect(cluster))
        with timer.stage("workers ready"):
            feed, summary = _start(connected, job, cluster, show_progress)
        run = run_mapping(
            dataset, config, out, show_progress, perception=perception, feed=feed, timer=timer, accept=accept
        )
    if temporary:
        _remove_transient_cache(root)
        run.cache = CacheSummary(str(root), 0, 0) if run.cache is None else run.cache
        run.cache.removed = True
    summary.tally = feed.tally
    return run, summary


def perceive_on_cluster(
    source: SourceSpec,
    dataset: Dataset,
    config: MappingConfig,
    out: Path,
    cluster: ClusterConfig,
    show_progress: bool = True,
) -> tuple[PerceptionRun, ClusterRun]:
    """`--perception-only` on the cluster: every frame perceived into the configured cache, nothing fused."""
    timer = StageTimer()
    if len(dataset) == 0:
        raise TerraError(f"dataset {dataset.name!r} has no frames")
    with timer.stage("setup"):
        perception = open_perception(config, dataset, Path(out))
    if not isinstance(perception, CachedPerception):
        raise TerraError(
            "--perception-only fills the perception cache, which mapping.perception.cache.mode: off "
            "switches off (use on, or auto with a model backend)"
        )
    job = PerceptionJob.for_run(source, dataset, config, perception)
    with ExitStack() as stack:
        with timer.stage("cluster"):
            connected = stack.enter_context(connect(cluster))
        with timer.stage("workers ready"):
            feed, summary = _start(connected, job, cluster, show_progress)
        with timer.stage("perception"):
            for _ in feed.frames(0, len(dataset)):
                pass
    tally = summary.tally = feed.tally
    run = PerceptionRun(
        perception.cache.folder, len(dataset), tally.images, tally.hits, tally.computed, tally.stats, tally.notes, timer
    )
    return run, summary


def _start(
    cluster: Cluster, job: PerceptionJob, config: ClusterConfig, show_progress: bool
) -> tuple[ClusterFeed, ClusterRun]:
    """Prepare every worker (source opened, backend built, views checked), then a feed of `job`."""
    workers = prepare_workers(cluster, job)
    in_flight = config.in_flight or max(4, 2 * len(workers))
    summary = ClusterRun(cluster.description, len(workers), in_flight)
    return ClusterFeed(cluster.client, job, in_flight, show_progress), summary


def prepare_workers(cluster: Cluster, job: PerceptionJob) -> list[str]:
    """Run `prepare_task` once on each worker now connected; the first worker's TerraError stops the run."""
    from terra.distributed.worker import prepare_task

    addresses = cluster.worker_addresses()
    text = job.to_text()
    futures = [
        cluster.client.submit(
            # Loosely pinned: if that worker dies meanwhile, another one runs the check.
            prepare_task,
            text,
            key=f"terra-prepare-{job.key[:16]}-{n}",
            workers=[address],
            allow_other_workers=True,
        )
        for n, address in enumerate(addresses)
    ]
    try:
        for future in futures:
            future.result()
    except ImportError as exc:  # the task itself, or a backend's dependency, cannot be loaded there
        raise TerraError(
            f"a worker cannot load what Terra needs ({exc}); install the same Terra, with the "
            "extras the config uses, on every worker"
        ) from None
    finally:
        cluster.client.cancel(futures)
    return addresses


def transient_cache_folder(out: Path) -> Path:
    """Where a cluster run keeps the cache that its config does not ask for: OUT.work/cluster-perception,
    a folder only Terra writes, removed when the run succeeds."""
    out = Path(out)
    return out.with_name(out.name + ".work") / "cluster-perception"


def _remove_transient_cache(root: Path) -> None:
    shutil.rmtree(root, ignore_errors=True)
    with contextlib.suppress(OSError):
        root.parent.rmdir()  # OUT.work, when nothing else is in it
