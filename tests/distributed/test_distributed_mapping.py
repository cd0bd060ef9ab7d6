"""Phase 1 on a Dask cluster (terra/distributed): the bundle of `terra map --workers 2` and of
`--scheduler` equals the serial bundle byte for byte; a worker killed mid-run costs only its frames;
a worker that cannot open the source stops the run with one line (exit 2); Ctrl-C stops the cluster
Terra started and leaves a checkpoint that resumes to the same bytes; and the checks each worker makes
of its view of the run (source, frame count, backend, shared cache folder).

The source is the simulated tiny campus cut to 8 frames and written as a terra-folder, so workers
read frames as they would on a cluster; perception is the labels backend (the cache, off for it by
default, is the hand-over from the workers and is removed after a successful run).
"""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from terra.cli import run
from terra.distributed.cluster import ClusterConfig, cluster_config, connect, worker_environment
from terra.distributed.job import PerceptionJob
from terra.distributed.source import SourceSpec
from terra.distributed.worker import prepare_task
from terra.errors import TerraError
from terra.mapping.config import MappingConfig
from terra.perception.cache import CachedPerception, PerceptionCache, cache_identity
from terra.perception.registry import get_perception
from tests.cli.signals import ctrl_c_default
from tests.mapping.fixtures import folder_digest
from tests.perception.fixtures import models_section

pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[2]
FRAMES = 8


@pytest.fixture(scope="module")
def tiny_folder(tmp_path_factory) -> Path:
    """simulate('tiny', 0) cut to 8 frames, written as a terra-folder dataset."""
    from terra.sim import SimConfig, simulate
    from terra.sim.writer import write_dataset

    config = SimConfig()
    config = config.model_copy(update={"route": config.route.model_copy(update={"max_frames": FRAMES})})
    return write_dataset(simulate("tiny", 0, config), tmp_path_factory.mktemp("tinydata") / "tiny", progress=False)


@pytest.fixture(scope="module")
def serial_digest(tiny_folder, tmp_path_factory, text_embedder) -> dict[str, str]:
    out = tmp_path_factory.mktemp("serial") / "map.terra"
    assert run(["map", str(tiny_folder), "--out", str(out), "-q"]) == 0
    return folder_digest(out)


@pytest.fixture(scope="module")
def dask_cluster():
    """A 2-worker local cluster started by the test, as a user would start one for --scheduler."""
    from distributed import Client, LocalCluster

    with (
        LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
            silence_logs=logging.CRITICAL,
        ) as cluster,
        Client(cluster, set_as_default=False) as client,
    ):
        yield client


def _children() -> set[int]:
    """Live child processes, but multiprocessing's resource tracker (it lives as long as this process)."""
    import psutil

    return {
        p.pid
        for p in psutil.Process().children(recursive=True)
        if p.status() != psutil.STATUS_ZOMBIE and "resource_tracker" not in " ".join(p.cmdline())
    }


# -------------------------------------------------------------------------------- whole runs


def test_two_local_workers_give_the_serial_bundle(tiny_folder, serial_digest, tmp_path, capsys):
    before, environ = _children(), dict(os.environ)
    out = tmp_path / "map.terra"
    assert run(["map", str(tiny_folder), "--out", str(out), "--workers", "2"]) == 0
    assert dict(os.environ) == environ  # the workers' environment did not leak into this process
    text = capsys.readouterr().out
    assert folder_digest(out) == serial_digest
    assert f"perception on a local cluster of 2 worker processes: {FRAMES} frames by" in text
    # The client computed nothing: every image came back from the workers' cache entries, which were
    # then removed (the labels backend keeps no cache by default).
    assert f"perception cache: {FRAMES} images read back, 0 computed (removed" in text
    assert not (tmp_path / "map.terra.work").exists() and not (tmp_path / "map.terra.partial").exists()
    assert _children() <= before  # the cluster Terra started is gone


def test_scheduler_option_uses_a_running_cluster(tiny_folder, serial_digest, dask_cluster, tmp_path, capsys):
    address = dask_cluster.scheduler.address
    out = tmp_path / "map.terra"
    assert run(["map", str(tiny_folder), "--out", str(out), "--scheduler", address, "--in-flight", "3"]) == 0
    text = capsys.readouterr().out
    assert folder_digest(out) == serial_digest
    assert f"perception on the Dask cluster at {address}: {FRAMES} frames" in text and "up to 3 in flight" in text
    assert len(dask_cluster.nthreads()) == 2  # a cluster Terra joined keeps running
    # A scheduler file (what `dask scheduler --scheduler-file` writes; Dask reads its "address") names it too.
    scheduler_file = tmp_path / "scheduler.json"
    scheduler_file.write_text(json.dumps({"type": "Scheduler", "address": address}))
    with connect(cluster_config(None, str(scheduler_file), environ={})) as joined:
        assert not joined.started and joined.worker_addresses() == sorted(dask_cluster.nthreads())
        assert joined.description == f"the Dask cluster at {address}"


def test_odometry_poses_on_the_cluster_give_the_serial_bundle(tiny_folder, dask_cluster, tmp_path, capsys):
    """With --poses odometry the client registers the scans (KISS-ICP) and the workers perceive the frames
    without poses: the same bundle and trajectory as a serial run, every image perceived by a worker."""
    pytest.importorskip("kiss_icp")
    serial, clustered = tmp_path / "serial" / "map.terra", tmp_path / "cluster" / "map.terra"
    assert run(["map", str(tiny_folder), "--out", str(serial), "--poses", "odometry", "-q"]) == 0
    address = dask_cluster.scheduler.address
    assert run(["map", str(tiny_folder), "--out", str(clustered), "--poses", "odometry", "--scheduler", address]) == 0
    text = capsys.readouterr().out
    assert folder_digest(clustered) == folder_digest(serial)
    for name in ("map_poses_kitti.txt", "map_poses_tum.txt"):
        assert (clustered.parent / name).read_bytes() == (serial.parent / name).read_bytes()
    assert f"perception cache: {FRAMES} images read back, 0 computed" in text and "poses: odometry" in text


def test_perception_only_on_the_cluster_named_by_the_environment(
    tiny_folder, dask_cluster, tmp_path, monkeypatch, capsys
):
    config = tmp_path / "terra.yaml"
    config.write_text("mapping:\n  perception:\n    cache:\n      mode: 'on'\n")
    monkeypatch.setenv("TERRA_DASK_SCHEDULER", dask_cluster.scheduler.address)
    out = tmp_path / "map.terra"
    assert run(["map", str(tiny_folder), "--out", str(out), "--config", str(config), "--perception-only"]) == 0
    text = capsys.readouterr().out
    assert f"perception cache: {FRAMES} images of {FRAMES} frames, 0 already cached, {FRAMES} computed" in text
    assert not out.exists()
    monkeypatch.delenv("TERRA_DASK_SCHEDULER")
    assert run(["map", str(tiny_folder), "--out", str(out), "--config", str(config)]) == 0  # serial: reads them back
    assert f"perception cache: {FRAMES} images read back, 0 computed" in capsys.readouterr().out


def test_a_model_backend_on_the_cluster_gives_the_serial_bundle(
    tiny_folder, tiny_models, dask_cluster, tmp_path, capsys
):
    """The `models` backend (tiny CLIP, constant-output ONNX segmenters): workers load the weight files
    themselves, agree with the client on its backend key (file contents), and fill the cache it keeps."""
    import yaml

    config = tmp_path / "terra.yaml"
    config.write_text(yaml.safe_dump({"mapping": {"perception": models_section(tiny_models)}}))
    serial, clustered = tmp_path / "serial.terra", tmp_path / "cluster.terra"
    assert run(["map", str(tiny_folder), "--out", str(serial), "--config", str(config), "-q"]) == 0
    address = dask_cluster.scheduler.address
    assert run(["map", str(tiny_folder), "--out", str(clustered), "--config", str(config), "--scheduler", address]) == 0
    text = capsys.readouterr().out
    assert f"{FRAMES} images computed, 0 read back" in text
    assert f"perception cache: {FRAMES} images read back, 0 computed ({tmp_path / 'cluster.terra.work'}" in text
    assert folder_digest(clustered) == folder_digest(serial)


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc/self/fd (Linux)")
def test_a_worker_that_cannot_open_the_source_stops_the_run_with_one_line(tiny_folder, dask_cluster, tmp_path, capsys):
    # /proc/self/fd/N names this process's open folder: a path the client can read and no worker can.
    fd = os.open(tiny_folder, os.O_RDONLY)
    private = os.dup2(fd, 987)
    os.close(fd)
    try:
        out = tmp_path / "map.terra"
        address = dask_cluster.scheduler.address
        code = run(["map", f"/proc/self/fd/{private}", "--out", str(out), "--scheduler", address])
    finally:
        os.close(private)
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert err.startswith("terra: error: worker tcp://127.0.0.1:")
    assert f"cannot open the source /proc/self/fd/{private}" in err and "same path on every worker" in err
    assert not out.exists() and not (tmp_path / "map.terra.partial").exists()


def _slow_down(seconds: float) -> None:
    """Run in each worker process: sleep before every frame, so that a test can kill a worker mid-frame."""
    import terra.distributed.worker as worker
    from terra.mapping.perceive import perceive_frame

    def slow(*args, **kwargs):
        time.sleep(seconds)
        return perceive_frame(*args, **kwargs)

    worker.perceive_frame = slow


def _kill_a_busy_worker(client, pids: dict[str, int], cache: Path, killed: dict) -> None:
    """Once the first frame is in the cache, SIGKILL a worker that is perceiving a frame."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if any(cache.rglob("entry.json")):
            for address, keys in client.processing().items():
                keys = [key for key in keys if str(key).startswith("terra-perceive")]
                if keys and address in pids:
                    os.kill(pids[address], signal.SIGKILL)
                    killed.update(address=address, pid=pids[address], keys=keys)
                    return
        time.sleep(0.01)


def test_a_killed_worker_costs_only_its_frames(tiny_folder, serial_digest, dask_cluster, tmp_path, capsys):
    import psutil

    dask_cluster.run(_slow_down, 0.4)
    pids = dask_cluster.run(os.getpid)
    out = tmp_path / "map.terra"
    killed: dict = {}
    cache = tmp_path / "map.terra.work"
    killer = threading.Thread(target=_kill_a_busy_worker, args=(dask_cluster, pids, cache, killed))
    killer.start()
    try:
        code = run(["map", str(tiny_folder), "--out", str(out), "--scheduler", dask_cluster.scheduler.address])
    finally:
        killer.join()
    text = capsys.readouterr().out
    assert code == 0 and killed["keys"], killed
    assert not psutil.pid_exists(killed["pid"]) or psutil.Process(killed["pid"]).status() == psutil.STATUS_ZOMBIE
    assert folder_digest(out) == serial_digest
    assert f"{FRAMES} frames by" in text and f"perception cache: {FRAMES} images read back, 0 computed" in text
    dask_cluster.wait_for_workers(2, timeout=60)  # the nanny restarted it


@pytest.mark.slow
def test_ctrl_c_stops_the_cluster_and_resumes_to_the_same_bytes(tiny_folder, dask_cluster, tmp_path, capsys):
    config = tmp_path / "terra.yaml"
    config.write_text("mapping:\n  checkpoint_every: 1\n")
    out = tmp_path / "map.terra"
    argv = ["map", str(tiny_folder), "--out", str(out), "--config", str(config)]
    # A terminal's Ctrl-C: SIGINT to the whole process group, the worker processes included.
    child = subprocess.Popen(
        [sys.executable, "-m", "terra", *argv, "--workers", "2", "--in-flight", "1", "-q"],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,
        preexec_fn=ctrl_c_default,
    )
    import psutil

    state = tmp_path / "map.terra.partial" / "state" / "manifest.json"
    deadline = time.monotonic() + 240
    workers: dict[int, psutil.Process] = {}  # the cluster's processes (not multiprocessing's resource tracker)
    while not state.is_file() and child.poll() is None and time.monotonic() < deadline:
        for process in psutil.Process(child.pid).children(recursive=True):
            try:
                if "resource_tracker" not in " ".join(process.cmdline()):
                    workers.setdefault(process.pid, process)
            except psutil.NoSuchProcess:
                pass
        time.sleep(0.01)
    os.killpg(child.pid, signal.SIGINT)
    _, err = child.communicate(timeout=120)
    err = err.decode()
    assert child.returncode == 130, err  # as a serial run exits on Ctrl-C
    # No traceback from the client or the workers: the one interrupt line saying what was kept (and the
    # text embedder's loading bars) is all there is.
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("Loading weights")]
    assert len(lines) == 1 and lines[0].startswith("terra: interrupted; the map up to frame"), err
    assert "run the same command again to resume" in lines[0], err
    assert len(workers) >= 2
    _, alive = psutil.wait_procs(list(workers.values()), timeout=30)
    assert not alive
    assert state.is_file() and not out.exists()
    # Resume on a running cluster; the reference is a serial run with the same config.
    assert run([*argv, "--scheduler", dask_cluster.scheduler.address]) == 0
    assert "resumed after frame" in capsys.readouterr().out
    assert run([*argv[:3], str(tmp_path / "serial.terra"), *argv[4:], "-q"]) == 0
    assert folder_digest(out) == folder_digest(tmp_path / "serial.terra")


# -------------------------------------------------------------------------------- the pieces


def test_cluster_options():
    assert not cluster_config(None, None, environ={}).enabled
    remote = {"TERRA_DASK_SCHEDULER": "tcp://10.0.0.5:8786"}
    assert cluster_config(None, None, environ=remote).scheduler == "tcp://10.0.0.5:8786"
    assert cluster_config(3, None, environ=remote).workers == 3  # an option wins over the environment
    with pytest.raises(TerraError, match="not both"):
        cluster_config(2, "tcp://127.0.0.1:8786", environ={})
    with pytest.raises(TerraError, match="TERRA_DASK_SCHEDULER.*tcp://HOST:PORT"):
        cluster_config(None, None, environ={"TERRA_DASK_SCHEDULER": "no-such-scheduler-file.json"})
    with pytest.raises(TerraError, match="--workers"):
        cluster_config(0, None, environ={})
    # Local workers share the cores out for their math libraries and keep glibc's own trimming.
    environment = worker_environment(4, threads=3)
    assert environment["OMP_NUM_THREADS"] == environment["OPENBLAS_NUM_THREADS"] == "3"
    assert environment["MALLOC_TRIM_THRESHOLD_"] is None
    assert worker_environment(len(os.sched_getaffinity(0)) * 2)["OMP_NUM_THREADS"] == "1"


def test_an_unreachable_scheduler_is_one_line(tmp_path):
    import socket

    with socket.socket() as sock:  # a loopback port nobody listens on
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    with (
        pytest.raises(TerraError, match=f"cannot reach the Dask scheduler tcp://127.0.0.1:{port}"),
        connect(ClusterConfig(scheduler=f"tcp://127.0.0.1:{port}", connect_timeout=1.0)),
    ):
        pass


def test_source_spec_round_trip(tiny_folder, tmp_path, monkeypatch):
    monkeypatch.chdir(tiny_folder.parent)
    spec = SourceSpec.from_cli(Path(tiny_folder.name), None, "auto", {"camera_config": Path("cams.yaml")})
    assert spec.path == str(tiny_folder) and spec.format == "terra-folder"  # absolute, format fixed for workers
    assert spec.options == {"camera_config": str(tiny_folder.parent / "cams.yaml")}
    assert SourceSpec.from_json(spec.to_json()) == spec
    assert SourceSpec.from_cli(None, "tiny", "auto").sim == "tiny:0"
    with pytest.raises(TerraError, match="seed"):
        SourceSpec.from_cli(None, "tiny:x", "auto")
    with pytest.raises(TerraError, match="either"):
        SourceSpec.from_cli(tiny_folder, "tiny", "auto")


def test_workers_perceive_an_odometry_source_without_its_poses(tiny_folder):
    spec = SourceSpec.from_cli(tiny_folder, None).with_odometry()
    assert spec.poses == "odometry" and SourceSpec.from_json(spec.to_json()) == spec
    source, view = spec.open(), spec.open_for_perception()
    assert (view.name, len(view), view.classes) == (source.name, len(source), source.classes)
    frame, original = view[3], source[3]
    assert (frame.T_map_lidar == np.eye(4)).all() and not (original.T_map_lidar == np.eye(4)).all()
    assert (frame.cameras[0].semantic == original.cameras[0].semantic).all()  # what perception reads is untouched
    assert SourceSpec.from_cli(tiny_folder, None).open_for_perception()[3].T_map_lidar.tolist() == (
        original.T_map_lidar.tolist()
    )


@pytest.fixture(scope="module")
def job_parts(tiny_folder, tmp_path_factory, text_embedder):
    """A job for the tiny folder as a client would send it, and the cache root the client created."""
    spec = SourceSpec.from_cli(tiny_folder, None)
    dataset = spec.open()
    config = MappingConfig()
    inner = get_perception(config.perception, dataset.classes)
    root = tmp_path_factory.mktemp("cache")
    perception = CachedPerception(inner, PerceptionCache(root, cache_identity(inner)))
    return PerceptionJob.for_run(spec, dataset, config, perception), root


def _variant(job: PerceptionJob, **changes) -> str:
    fields = {"source": job.source, "config": job.config, "cache_root": job.cache_root, "expect": dict(job.expect)}
    expect = changes.pop("expect", {})
    fields.update(changes)
    fields["expect"].update(expect)
    return PerceptionJob(**fields).to_text()


def test_each_worker_checks_its_view_of_the_run(job_parts, tmp_path):
    job, root = job_parts
    assert prepare_task(job.to_text())["worker"].startswith("process ")  # outside Dask: this process
    with pytest.raises(TerraError, match=f"found frames {FRAMES}, the client's {FRAMES + 1}; workers read frames"):
        prepare_task(_variant(job, expect={"frames": FRAMES + 1}))
    with pytest.raises(TerraError, match="runs Terra .*, the client 0.0.1: install the same Terra"):
        prepare_task(_variant(job, expect={"terra": "0.0.1"}))
    with pytest.raises(TerraError, match="another class table"):
        prepare_task(_variant(job, expect={"classes": "0" * 64}))
    with pytest.raises(TerraError, match="another perception backend .* same model files"):
        prepare_task(_variant(job, expect={"backend": "f" * 64}))
    with pytest.raises(TerraError, match="does not see the perception cache .* every worker share"):
        prepare_task(_variant(job, cache_root=str(tmp_path / "elsewhere")))
    missing = SourceSpec(path=str(tmp_path / "gone"), format="terra-folder")
    with pytest.raises(TerraError, match=f"cannot open the source {tmp_path / 'gone'} .*does not exist"):
        prepare_task(_variant(job, source=missing))


def test_the_feed_hands_frames_over_in_order_within_its_window(job_parts, dask_cluster):
    from terra.distributed.feed import ClusterFeed

    job, _ = job_parts
    feed = ClusterFeed(dask_cluster, job, in_flight=3, show_progress=False)
    order, outstanding = [], []
    for i in feed.frames(2, FRAMES):
        order.append(i)
        outstanding.append(feed.outstanding)
    assert order == list(range(2, FRAMES))
    assert max(outstanding) == 3 and outstanding[-1] == 1  # never more than 3 frames out; the last alone
    assert feed.tally.frames == FRAMES - 2 and feed.tally.images == FRAMES - 2
    assert sum(feed.tally.by_worker.values()) == FRAMES - 2
