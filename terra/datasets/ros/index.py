"""One pass over a bag's selected topics that remembers where every message is, not the message.

Per image or cloud topic: log time (ns), ordinal among same-log-time messages, and header stamp
(seconds), so any message can be fetched again by (topic, log ns, ordinal). /tf_static, /tf and
an odometry topic are small: their transforms go into a TfTree. The first raw message of every
topic is kept to validate layouts and read calibrations before mapping starts.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from terra.datasets.ros.bag import Bag, bag_errors, header_stamp, stamps_seconds, xyz_quat_of
from terra.datasets.ros.tf import TfTree
from terra.progress import TimeProgress


@dataclass
class Stream:
    """Messages of one topic, sorted by header stamp: stamps (K,) seconds, log_ns (K,) int64, ordinal (K,)."""

    stamps: np.ndarray
    log_ns: np.ndarray
    ordinal: np.ndarray

    def key(self, topic: str, k: int) -> tuple[str, int, int]:
        return topic, int(self.log_ns[k]), int(self.ordinal[k])

    def __len__(self) -> int:
        return int(self.stamps.shape[0])


@dataclass
class BagIndex:
    streams: dict[str, Stream]
    tf: TfTree
    odometry: TfTree | None
    first: dict[str, bytes] = field(default_factory=dict)
    odometry_frames: tuple[str, str] | None = None  # (parent, child) of the odometry topic


TF_TOPICS = ("/tf_static", "/tf", "tf_static", "tf")


def index_bag(bag: Bag, stamped: list[str], odometry_topic: str | None, show_progress: bool = True) -> BagIndex:
    """Index `stamped` topics (messages that start with a std_msgs/Header) and read the TF and
    odometry topics, in one pass in log-time order."""
    tf_topics = [t for t in TF_TOPICS if t in bag.topics]
    wanted = sorted(set(stamped) | set(tf_topics) | ({odometry_topic} if odometry_topic else set()))
    builder = IndexBuilder(bag, stamped, odometry_topic)
    bar = TimeProgress(bag.start_ns * 1e-9, bag.end_ns * 1e-9, "indexing bag", enabled=show_progress)
    try:
        for topic, log_ns, raw in bag.read(wanted):
            bar.update(log_ns * 1e-9)
            builder.add(topic, log_ns, raw)
    finally:
        bar.close()
    return builder.result()


class IndexBuilder:
    """`index_bag`'s pass one message at a time, so a recording that is still growing is indexed
    as its messages arrive (terra/datasets/ros/follow.py) and looked at whenever wanted (`result`).
    Messages of `stamped` topics are indexed, of the TF topics and `odometry_topic` read into TF
    trees; any other message is ignored."""

    def __init__(self, bag: Bag, stamped: list[str], odometry_topic: str | None) -> None:
        self.bag = bag
        self.rows: dict[str, list[tuple[float, int]]] = {t: [] for t in stamped}
        self.odometry_topic = odometry_topic
        self.tree, self.odometry = TfTree(), TfTree() if odometry_topic else None
        self.first: dict[str, bytes] = {}
        self.odometry_frames: tuple[str, str] | None = None

    def track(self, topic: str, odometry: bool = False) -> None:
        """Index `topic` from now on (a recording that grows shows its topics as they appear): its
        messages start with a std_msgs/Header, or, with `odometry`, it is the odometry topic (one)."""
        if odometry:
            if self.odometry_topic is None:
                self.odometry_topic, self.odometry = topic, TfTree()
        else:
            self.rows.setdefault(topic, [])

    def add(self, topic: str, log_ns: int, raw: bytes) -> None:
        """One message (log time ns, raw bytes), in log-time order."""
        bag, where = self.bag, f"{self.bag.path} {topic} at log time {log_ns * 1e-9:.3f} s"
        if topic in self.rows:
            self.first.setdefault(topic, raw)
            with bag_errors(where):
                self.rows[topic].append((header_stamp(raw, bag.ros2), log_ns))
        elif topic == self.odometry_topic and self.odometry is not None:
            self.first.setdefault(topic, raw)
            msg = bag.deserialize(raw, topic)
            frames = (msg.header.frame_id.lstrip("/"), msg.child_frame_id.lstrip("/"))
            self.odometry_frames = self.odometry_frames or frames
            self.odometry.add(
                msg.header.frame_id,
                msg.child_frame_id,
                xyz_quat_of(msg.pose.pose, where),
                stamps_seconds(msg.header.stamp),
            )
        elif topic in TF_TOPICS:
            self.first.setdefault(topic, raw)
            static = topic.lstrip("/") == "tf_static"
            for tr in bag.deserialize(raw, topic).transforms:
                self.tree.add(
                    tr.header.frame_id,
                    tr.child_frame_id,
                    xyz_quat_of(tr.transform, where),
                    None if static else stamps_seconds(tr.header.stamp),
                )

    def result(self) -> BagIndex:
        """The index of the messages added so far (the builder can take more afterwards)."""
        tree = self.tree.copy()
        tree.freeze()
        odom = self.odometry.copy() if self.odometry is not None else None
        if odom is not None:
            for child, (parent, T) in tree.static.items():
                odom.static.setdefault(child, (parent, T))
            odom.freeze()
        streams = {t: _stream(r) for t, r in self.rows.items()}
        return BagIndex(streams, tree, odom, dict(self.first), self.odometry_frames)


def _stream(rows: list[tuple[float, int]]) -> Stream:
    stamps = np.array([r[0] for r in rows], float)
    log_ns = np.array([r[1] for r in rows], np.int64)
    ordinal = np.zeros(len(rows), np.int64)
    for k in range(1, len(rows)):  # messages of one topic sharing a log time, in bag order
        if log_ns[k] == log_ns[k - 1]:
            ordinal[k] = ordinal[k - 1] + 1
    order = np.argsort(stamps, kind="stable")
    return Stream(stamps[order], log_ns[order], ordinal[order])
