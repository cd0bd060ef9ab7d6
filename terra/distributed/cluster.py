"""Which Dask cluster a run uses, and a client connected to it.

`--workers N` starts a local cluster: a scheduler and N single-threaded worker processes (each under a
Dask nanny, which restarts it if it dies, and each with the machine's cores / N threads for the math
libraries its models use; see `worker_environment`), every one listening on 127.0.0.1 only; its HTTP endpoint
(health, metrics, and the dashboard when bokeh is installed) takes a free loopback port. `--scheduler`
(or the TERRA_DASK_SCHEDULER environment variable) connects to a cluster someone started, by address
(`tcp://HOST:PORT`) or by the JSON scheduler file `dask scheduler --scheduler-file` writes: reaching
beyond this machine is the user's explicit choice. A cluster Terra started is stopped when the run
ends, however it ends (Ctrl-C included); a cluster it joined is left running.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import Field, ValidationError, field_validator

from terra.errors import TerraError
from terra.schemas import Section

SCHEDULER_ENV = "TERRA_DASK_SCHEDULER"
# Loggers that report a cluster's shutdown (closed connections, cancelled tasks) as warnings.
_NOISY_LOGGERS = ("distributed", "asyncio", "tornado")


class ClusterConfig(Section):
    """Where Phase 1 perception runs: `workers` local processes, or the cluster at `scheduler`."""

    workers: int | None = Field(
        default=None, ge=1, le=1024, description="start a local cluster of this many worker processes"
    )
    scheduler: str | None = Field(
        default=None, description="address (tcp://HOST:PORT) or scheduler file (JSON) of a running Dask cluster"
    )
    in_flight: int | None = Field(
        default=None,
        ge=1,
        le=100_000,
        description="frames handed to the workers and not yet fused (default: 2 per worker, at least 4)",
    )
    threads: int | None = Field(
        default=None,
        ge=1,
        le=1024,
        description="math library threads per local worker (OMP/MKL/OpenBLAS; default: this machine's cores / workers)",
    )
    connect_timeout: float = Field(
        default=30.0, gt=0.0, description="seconds to wait for the scheduler and a first worker"
    )

    @field_validator("scheduler")
    @classmethod
    def _address_or_file(cls, value: str | None) -> str | None:
        if value is None:
            return None
        value = value.strip()
        if "://" not in value and not Path(value).is_file():
            raise ValueError("expected tcp://HOST:PORT or the path of a scheduler file")
        return value

    @property
    def enabled(self) -> bool:
        return self.workers is not None or self.scheduler is not None


def cluster_config(
    workers: int | None, scheduler: str | None, in_flight: int | None = None, environ: Mapping[str, str] | None = None
) -> ClusterConfig:
    """The cluster `terra map` options ask for; TERRA_DASK_SCHEDULER applies when neither option is given."""
    environ = os.environ if environ is None else environ
    if workers is not None and scheduler is not None:
        raise TerraError("give --workers (a local cluster) or --scheduler (a running one), not both")
    source = "--scheduler"
    if workers is None and scheduler is None and environ.get(SCHEDULER_ENV):
        scheduler, source = environ[SCHEDULER_ENV], SCHEDULER_ENV
    try:
        return ClusterConfig(workers=workers, scheduler=scheduler, in_flight=in_flight)
    except ValidationError as exc:
        error = exc.errors()[0]
        options = {"workers": "--workers", "scheduler": source, "in_flight": "--in-flight"}
        option = options.get(str(error["loc"][0]), "cluster")
        raise TerraError(f"{option}: {error['msg'].removeprefix('Value error, ')}") from None


@dataclass
class Cluster:
    """A connected client; `started` is True when Terra started the cluster (and will stop it)."""

    client: Any  # distributed.Client
    started: bool
    description: str

    def worker_addresses(self) -> list[str]:
        return sorted(self.client.nthreads())


@contextmanager
def connect(config: ClusterConfig) -> Iterator[Cluster]:
    """A client of the configured cluster, closed on exit (with the cluster, when Terra started it)."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise TerraError("--workers / --scheduler need Dask: pip install 'terra-3dsg[dask]'") from None
    if config.workers is not None:
        with _local_cluster(config.workers, config.threads) as cluster:
            yield cluster
    else:
        with _remote_cluster(config) as cluster:
            yield cluster


@contextmanager
def _local_cluster(workers: int, threads: int | None) -> Iterator[Cluster]:
    import dask.config
    from distributed import Client, LocalCluster

    # A Dask nanny writes its workers' environment into this process's os.environ before each spawn;
    # the client is given its own back once the workers are up, and again when they are gone.
    environ = dict(os.environ)
    spawn_environ = {"distributed.nanny.pre-spawn-environ": worker_environment(workers, threads)}
    with _closing_quietly(), dask.config.set(spawn_environ):
        local = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
            # Workers report shutdown races (a heartbeat to a scheduler already closed) as errors; task
            # failures reach the client anyway, as exceptions or KilledWorker.
            silence_logs=logging.CRITICAL,
            # Ctrl-C in a terminal reaches every process of the group: the workers ignore it and the
            # client stops them, so an interrupted run ends with one line, not a traceback per worker.
            preload=["terra.distributed.preload"],
        )
    _restore(environ)
    try:
        client = Client(local, set_as_default=False)
        try:
            yield Cluster(client, True, f"a local cluster of {workers} worker process{'es' if workers > 1 else ''}")
        finally:
            with _closing_quietly():
                client.close()
    finally:
        with _closing_quietly():
            local.close()
        _restore(environ)


def worker_environment(workers: int, threads: int | None = None) -> dict[str, str | None]:
    """What a local worker process gets in its environment (None: left unset), before it imports anything.

    Math library threads: `threads`, or this machine's cores shared out (Dask's default is one each,
    which leaves most cores idle when there are fewer workers than cores). MALLOC_TRIM_THRESHOLD_ is
    left unset: Dask's 65536 makes glibc hand every freed block above 64 KiB back to the system and fixes
    its mmap threshold, so each frame's large tensors are mapped and unmapped anew, which cost CLIP
    30-40 % of its throughput here (benchmarks/RESULTS.md, issue 18). Variables set in this process's
    own environment win, as Dask has it."""
    if threads is None:
        try:
            cores = len(os.sched_getaffinity(0))
        except AttributeError:  # not on Linux
            cores = os.cpu_count() or 1
        threads = max(1, cores // workers)
    math = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
    return {**{name: str(threads) for name in math}, "MALLOC_TRIM_THRESHOLD_": None}


def _restore(environ: dict[str, str]) -> None:
    for name in set(os.environ) - set(environ):
        del os.environ[name]
    os.environ.update(environ)


@contextmanager
def _remote_cluster(config: ClusterConfig) -> Iterator[Cluster]:
    from distributed import Client

    address = config.scheduler
    if address is None:
        raise TerraError(f"no Dask scheduler to connect to (give --scheduler or set {SCHEDULER_ENV})")
    by_file = "://" not in address
    try:
        client = Client(
            None if by_file else address,
            scheduler_file=address if by_file else None,
            timeout=config.connect_timeout,
            set_as_default=False,
        )
    except (OSError, TimeoutError, ValueError) as exc:
        raise TerraError(f"cannot reach the Dask scheduler {address}: {_first_line(exc)}") from None
    try:
        try:
            client.wait_for_workers(1, timeout=config.connect_timeout)
        except (TimeoutError, OSError):
            raise TerraError(
                f"the Dask scheduler {address} has no worker (waited {config.connect_timeout:g} s)"
            ) from None
        scheduler = client.scheduler
        yield Cluster(client, False, f"the Dask cluster at {scheduler.address if scheduler is not None else address}")
    finally:
        with _closing_quietly():
            client.close()


@contextmanager
def _closing_quietly() -> Iterator[None]:
    """Raise Dask's loggers to ERROR while a cluster starts or stops: closed connections and cancelled
    tasks are expected then, and are not the user's business."""
    loggers = [logging.getLogger(name) for name in _NOISY_LOGGERS]
    levels = [log.level for log in loggers]
    for log in loggers:
        log.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for log, level in zip(loggers, levels):
            log.setLevel(level)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0]
