"""`terra map BAG --follow` on a ROS 1 .bag that a writer thread (rosbags' rosbag1 Writer) is still
appending to: the recording ends when the writer writes its index, and the map equals the batch
map of the finished bag byte for byte."""

from __future__ import annotations

import threading
import time
from pathlib import Path

from terra.cli import run
from tests.live.test_session import map_files


def start_ros1_recording(source: Path, bag: Path, pause: float) -> tuple[threading.Thread, threading.Event]:
    """A thread copying the messages of the ROS 1 bag `source` into the new bag `bag`, one by one."""
    from rosbags.rosbag1 import Reader, Writer

    with Reader(source) as reader:
        connections = list(reader.connections)
        messages = [(c.id, ns, bytes(raw)) for c, ns, raw in reader.messages()]
    writer = Writer(bag)
    writer.open()
    closed = threading.Event()

    def write() -> None:
        made = {}
        for cid, ns, raw in messages:
            if cid not in made:
                c = connections[cid]
                made[cid] = writer.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
            writer.write(made[cid], ns, raw)
            time.sleep(pause)
        writer.close()
        closed.set()

    thread = threading.Thread(target=write, daemon=True)
    thread.start()
    return thread, closed


def test_follow_a_ros1_bag_being_written(sim_sources, tmp_path, capsys):
    import shutil

    source = next(Path(sim_sources["rosbag1"]).glob("*.bag"))
    folder = tmp_path / "recording"
    folder.mkdir()
    shutil.copy(source.parent / "classes.json", folder / "classes.json")
    bag = folder / source.name
    thread, closed = start_ros1_recording(source, bag, pause=0.05)
    assert run(["map", str(bag), "--out", str(tmp_path / "follow.terra"), "--follow"]) == 0
    thread.join(30)
    assert closed.is_set() and "followed until closed" in capsys.readouterr().out
    assert run(["map", str(bag), "--out", str(tmp_path / "batch.terra"), "-q"]) == 0
    assert map_files(tmp_path / "follow.terra") == map_files(tmp_path / "batch.terra")
