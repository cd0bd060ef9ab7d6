"""Bags written by the simulator (ROS 1 .bag and ROS 2 mcap) beside the folder of the same drive,
and a helper that writes small hand-made bags for the bad-input tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

FRAMES = 5


@pytest.fixture(scope="session")
def sim_sources(tmp_path_factory) -> dict[str, Path]:
    """The tiny campus's first FRAMES frames as terra-folder, rosbag1 and rosbag2 (mcap, JPEG images)."""
    from terra.sim import simulate
    from terra.sim.config import SimConfig
    from terra.sim.writer import write_dataset

    root = tmp_path_factory.mktemp("ros_sources")
    config = SimConfig.model_validate({"route": {"max_frames": FRAMES}})
    dataset = simulate("tiny", 0, config)
    out = {}
    for fmt in ("terra-folder", "rosbag1", "rosbag2"):
        out[fmt] = write_dataset(dataset, root / fmt, format=fmt, progress=False)
    out["dataset"] = dataset
    return out


def write_test_bag(
    path: Path, messages: list[tuple[str, str, int, object]], ros1: bool = False, sqlite: bool = False
) -> Path:
    """A bag of (topic, msgtype, stamp ns, message built by MessageFactory) rows: `path` is a .bag
    file (ros1) or a ROS 2 bag folder (mcap, or sqlite3 with `sqlite`)."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    factory = factory_for(store, ros1)
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(
            path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.SQLITE3 if sqlite else StoragePlugin.MCAP
        )
    with writer:
        conns = {}
        for topic, msgtype, ns, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(conns[topic], ns, factory.serialize(msg, msgtype))
    return path


def factory_for(store=None, ros1: bool = False):
    from rosbags.typesys import Stores, get_typestore

    from terra.datasets.ros.messages import MessageFactory

    store = store or get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    return MessageFactory(store, ros1)


def scan(n: int = 200, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(0, 5, (n, 3)).astype(np.float32)
