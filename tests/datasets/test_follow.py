"""`terra map BAG --follow`: a ROS 2 bag read while a writer thread is still appending to it gives,
when the writer closes it, the map of the finished bag byte for byte; a writer that stalls ends by
--idle; frames are handed on while the bag is still being written. The writer is rosbags' own
(mcap and sqlite3), copying the simulator's bag message by message with pauses between them."""

from __future__ import annotations

import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from terra.cli import run
from terra.datasets.ros.follow import FollowedBag
from terra.datasets.rosbag import RosbagDataset
from terra.datasets.stream import DatasetSource, FrameSource, as_source
from terra.errors import TerraError
from terra.live.follow import follow
from terra.mapping.config import MappingConfig
from tests.live.test_session import map_files

NAME = "sim-tiny-seed0"  # the simulated recording's name: the copy keeps it, so map/meta.json agrees


def bag_messages(folder: Path, until_ns: int | None = None) -> list[tuple[str, str, int, bytes]]:
    """(topic, type, log ns, raw) of every message of a finished bag, in log-time order (rosbags' reader)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    with AnyReader([folder], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        rows = [(c.topic, c.msgtype, int(ns), bytes(raw)) for c, ns, raw in reader.messages()]
    return [r for r in rows if until_ns is None or r[2] <= until_ns]


def start_recording(
    source: Path, folder: Path, pause: float, sqlite: bool = False
) -> tuple[threading.Thread, threading.Event]:
    """A thread writing the messages of the bag `source` into the new bag `folder` with rosbags'
    Writer, sleeping `pause` s after each; the event is set once the writer has closed the bag."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    messages = bag_messages(source)
    store = get_typestore(Stores.ROS2_HUMBLE)
    plugin = StoragePlugin.SQLITE3 if sqlite else StoragePlugin.MCAP
    opened, closed = threading.Event(), threading.Event()

    def write() -> None:  # in the thread: a sqlite3 connection serves the thread that made it
        writer = Writer(folder, version=Writer.VERSION_LATEST, storage_plugin=plugin)
        writer.open()
        shutil.copy(source / "classes.json", folder / "classes.json")
        opened.set()
        connections = {}
        for topic, msgtype, ns, raw in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], ns, raw)
            time.sleep(pause)
        writer.close()
        closed.set()

    thread = threading.Thread(target=write, daemon=True)
    thread.start()
    assert opened.wait(30)
    return thread, closed


@pytest.fixture(scope="module")
def batch_map(sim_sources, tmp_path_factory) -> dict[str, str]:
    """The map files of `terra map` on the finished simulated bag."""
    out = tmp_path_factory.mktemp("follow_batch") / "batch.terra"
    assert run(["map", str(sim_sources["rosbag2"]), "--out", str(out), "-q"]) == 0
    return map_files(out)


class Watched(FollowedBag):
    """A followed bag that notes, at each frame it hands on, whether the writer had closed the bag."""

    def __init__(self, path: Path, closed: threading.Event, **options) -> None:
        super().__init__(path, **options)
        self.closed, self.after_close = closed, []

    def frames(self):
        for frame in super().frames():
            self.after_close.append(self.closed.is_set())
            yield frame


def test_follow_a_bag_being_written_equals_the_batch_map(sim_sources, batch_map, tmp_path, capsys):
    folder = tmp_path / NAME
    thread, closed = start_recording(sim_sources["rosbag2"], folder, pause=0.05)
    out = tmp_path / "follow.terra"
    assert run(["map", str(folder), "--out", str(out), "--follow"]) == 0
    thread.join(30)
    assert closed.is_set()
    text = capsys.readouterr().out
    assert "followed until closed" in text  # the mcap's end record, read before metadata.yaml
    assert map_files(out) == batch_map
    # The finished copy, mapped in one batch, is the same map: the copy holds the same messages.
    assert run(["map", str(folder), "--out", str(tmp_path / "copy.terra"), "-q"]) == 0
    assert map_files(tmp_path / "copy.terra") == batch_map


def test_frames_are_fused_while_the_bag_is_written(sim_sources, batch_map, tmp_path):
    folder = tmp_path / NAME
    thread, closed = start_recording(sim_sources["rosbag2"], folder, pause=0.15)
    source = Watched(folder, closed, poll=0.05, settle=0.0)
    result = follow(source, tmp_path / "live.terra", MappingConfig(), snapshot_every=0.0)
    thread.join(60)
    frames = len(RosbagDataset(sim_sources["rosbag2"], show_progress=False))
    assert result.session.frames == frames == len(source.after_close)
    assert not source.after_close[0]  # the first frame was fused while the writer was still writing
    assert len(result.versions) >= 2 and result.versions == sorted(result.versions)
    assert source.ended_by == "closed"
    assert map_files(tmp_path / "live.terra") == batch_map


def test_follow_a_sqlite_bag_until_its_metadata_is_written(sim_sources, batch_map, tmp_path, capsys):
    folder = tmp_path / NAME
    thread, closed = start_recording(sim_sources["rosbag2"], folder, pause=0.01, sqlite=True)
    out = tmp_path / "follow.terra"
    assert run(["map", str(folder), "--out", str(out), "--follow"]) == 0
    thread.join(30)
    assert "followed until metadata.yaml" in capsys.readouterr().out
    assert map_files(out) == batch_map


def stalled_copy(bag: Path, folder: Path) -> None:
    """`bag` as a writer leaves it that stopped after its last message: the mcap's data section
    without its end record, summary and footer, and no metadata.yaml."""
    mcap = next(bag.glob("*.mcap"))
    data = mcap.read_bytes()
    summary_start = int.from_bytes(data[-37 + 9 : -37 + 17], "little")
    assert data[summary_start - 13] == 0x0F  # the data-end record comes right before the summary
    folder.mkdir()
    (folder / mcap.name).write_bytes(data[: summary_start - 13])
    shutil.copy(bag / "classes.json", folder / "classes.json")


def test_a_stalled_writer_ends_by_idle(sim_sources, tmp_path, capsys):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    stamps = sorted({ns for _, _, ns, _ in bag_messages(sim_sources["rosbag2"])})
    reference = tmp_path / "three" / NAME
    reference.parent.mkdir()
    store = get_typestore(Stores.ROS2_HUMBLE)
    with Writer(reference, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for topic, msgtype, ns, raw in bag_messages(sim_sources["rosbag2"], until_ns=stamps[2]):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], ns, raw)
    shutil.copy(sim_sources["rosbag2"] / "classes.json", reference / "classes.json")
    assert run(["map", str(reference), "--out", str(tmp_path / "batch.terra"), "-q"]) == 0
    stalled = tmp_path / "stalled" / NAME
    stalled.parent.mkdir()
    stalled_copy(reference, stalled)

    started = time.monotonic()
    assert run(["map", str(stalled), "--out", str(tmp_path / "follow.terra"), "--follow", "--idle", "1"]) == 0
    assert time.monotonic() - started >= 1.0
    assert "followed until idle" in capsys.readouterr().out
    assert map_files(tmp_path / "follow.terra") == map_files(tmp_path / "batch.terra")


def test_follow_refusals_are_one_line(tmp_path, capsys):
    not_mcap = tmp_path / "junk.mcap"
    not_mcap.write_bytes(b"this is no mcap file at all")
    assert run(["map", str(not_mcap), "--out", str(tmp_path / "a.terra"), "--follow", "--idle", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not an mcap file" in err
    ros1 = tmp_path / "drive.bag"
    ros1.write_bytes(b"#ROSBAG V1.2\n and more")
    assert run(["map", str(ros1), "--out", str(tmp_path / "b.terra"), "--follow"]) == 2
    assert "not a ROS 1 bag (its first bytes are not #ROSBAG V2.0)" in capsys.readouterr().err
    empty = tmp_path / "recording"
    empty.mkdir()
    assert run(["map", str(empty), "--out", str(tmp_path / "c.terra"), "--follow", "--idle", "0.2"]) == 2
    assert "no storage file (.mcap or .db3) appeared" in capsys.readouterr().err
    assert run(["map", str(empty), "--out", str(tmp_path / "d.terra"), "--idle", "1"]) == 2
    assert "--idle is for --follow" in capsys.readouterr().err
    for made in ("a.terra", "b.terra", "c.terra", "d.terra"):
        assert not (tmp_path / made).exists()


def test_every_dataset_is_a_frame_source(sim_sources):
    from tests.mapping.fixtures import BoxScene

    dataset = BoxScene()
    source = as_source(dataset)
    assert isinstance(source, DatasetSource) and isinstance(source, FrameSource)
    frames = list(source.frames())
    assert (
        [f.stamp for f in frames] == [dataset[i].stamp for i in range(len(dataset))] == sorted(f.stamp for f in frames)
    )
    assert np.array_equal(frames[2].points, dataset[2].points)
    assert [f.index for f in DatasetSource(dataset, start=3).frames()] == list(range(3, len(dataset)))
    with pytest.raises(TerraError, match="start frame must be >= 0"):
        DatasetSource(dataset, start=-1)
    followed = FollowedBag(sim_sources["rosbag2"])
    assert as_source(followed) is followed and followed.name == NAME


def test_ctrl_c_while_waiting_commits_what_was_handed_on(sim_sources, tmp_path):
    stalled = tmp_path / NAME
    stalled_copy(sim_sources["rosbag2"], stalled)

    def interrupt(seconds: float) -> None:
        raise KeyboardInterrupt

    source = FollowedBag(stalled, sleep=interrupt)
    run_ = follow(source, tmp_path / "live.terra", MappingConfig())
    stamps = [sim_sources["dataset"][i].stamp for i in range(len(sim_sources["dataset"]))]
    settled = sum(t <= stamps[-1] - source.horizon for t in stamps)  # the last frames could still change
    assert source.ended_by == "interrupted" and 0 < settled < len(stamps)
    assert run_.session.frames == settled and run_.versions == [1]
    from terra.bundle import Bundle

    info = Bundle(tmp_path / "live.terra").model.components.map
    assert info is not None and info.frames == settled


def test_follow_maps_any_other_dataset_frame_by_frame(tmp_path, capsys):
    from terra.sim.writer import write_dataset
    from tests.mapping.fixtures import BoxScene

    folder = write_dataset(BoxScene(), tmp_path / "box", format="terra-folder", progress=False)
    assert run(["map", str(folder), "--out", str(tmp_path / "follow.terra"), "--follow"]) == 2
    assert "set mapping.fusion.use_global_map: false to follow it" in capsys.readouterr().err
    voxels = tmp_path / "voxels.yaml"  # the folder ships a global map: accumulate the scans instead
    voxels.write_text("mapping:\n  fusion:\n    use_global_map: false\n")
    assert run(["map", str(folder), "--out", str(tmp_path / "batch.terra"), "-c", str(voxels), "-q"]) == 0
    assert run(["map", str(folder), "--out", str(tmp_path / "follow.terra"), "-c", str(voxels), "--follow"]) == 0
    assert "followed until the source's last frame" in capsys.readouterr().out
    assert map_files(tmp_path / "follow.terra") == map_files(tmp_path / "batch.terra")
