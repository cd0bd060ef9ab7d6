"""What a bag holds, as `terra inspect` reports it: every topic (type, count, rate, time span),
the TF tree, the LiDAR layout, and a ready-to-edit `dataset` config section."""

from __future__ import annotations

from pathlib import Path

from terra.datasets.base import SourceInfo
from terra.datasets.ros.bag import Bag
from terra.datasets.ros.index import index_bag


def topic_table(bag: Bag) -> list[dict]:
    """Per topic: type, message count, first / last log time (s), rate (Hz) - one pass over the
    bag's log times (message bodies are read but not decoded)."""
    span: dict[str, list[int]] = {}
    for topic, log_ns, _ in bag.read(list(bag.topics)):
        first_last = span.setdefault(topic, [log_ns, log_ns])
        first_last[1] = log_ns
    rows = []
    for name, t in bag.topics.items():
        first, last = span.get(name) or (None, None)
        duration = (last - first) * 1e-9 if first is not None and last is not None else 0.0
        rows.append(
            {
                "topic": name,
                "type": t.msgtype,
                "count": t.count,
                "first": None if first is None else first * 1e-9,
                "last": None if last is None else last * 1e-9,
                "rate_hz": round((t.count - 1) / duration, 3) if duration > 0 else None,
            }
        )
    return rows


def dataset_section(dataset) -> dict:
    """The `dataset:` config section that reproduces what the loader chose (ready to edit)."""
    poses = (
        "odometry"
        if dataset.needs_odometry
        else ("topic" if dataset.pose_source.startswith("odometry topic") else "tf")
    )
    section = {"lidar_topic": dataset.lidar_topic, "lidar_frame": dataset.lidar_frame, "poses": poses}
    if dataset.map_frame and poses == "tf":
        section["map_frame"] = dataset.map_frame
    if poses == "topic":
        section["odometry_topic"] = dataset.pose_source.split()[2]
    cameras = []
    for cam in dataset.camera_topics:
        row = {"name": cam.name, "image_topic": cam.image, "info_topic": cam.info}
        row.update({k: v for k, v in (("semantic_topic", cam.semantic), ("instance_topic", cam.instance)) if v})
        cameras.append(row)
    section["cameras"] = cameras
    section["max_gap"] = dataset.config.max_gap
    if dataset.gnss_topic is not None:
        section["gnss_topic"] = dataset.gnss_topic
    return {"dataset": section}


def bag_details(bag: Bag, tf_edges: list[dict]) -> dict:
    return {
        "storage": bag.storage,
        "files": [str(p) for p in bag.paths],
        "start": bag.start_ns * 1e-9,
        "end": bag.end_ns * 1e-9,
        "duration_s": max(bag.end_ns - bag.start_ns, 0) * 1e-9,
        "topics": topic_table(bag),
        "tf": tf_edges,
    }


def describe_dataset(dataset) -> SourceInfo:
    """SourceInfo of an opened RosbagDataset."""
    frames = dataset._frames
    details = bag_details(dataset.bag, dataset.index.tf.edges())
    details["lidar"] = {
        "topic": dataset.lidar_topic,
        "frame": dataset.lidar_frame,
        "fields": dataset.cloud_fields,
        "scans": len(dataset.index.streams[dataset.lidar_topic]),
    }
    if dataset.index.tf.conflicts:
        details["tf_conflicts"] = dataset.index.tf.conflicts
    details.update(dataset_section(dataset))
    return SourceInfo(
        "rosbag",
        str(dataset.path),
        len(frames),
        (frames[0].stamp, frames[-1].stamp) if frames else None,
        list(dataset.calibrations),
        dataset.pose_source,
        dict(dataset.skipped),
        dict(dataset.skipped_notes),
        details,
    )


def describe_unopened(path: Path, reason: str) -> SourceInfo:
    """SourceInfo of a bag the loader cannot map as configured (e.g. two LiDAR topics): its topics
    and TF tree, and the reason, so the user can write the dataset section."""
    bag = Bag(path)
    try:
        tf = index_bag(bag, [], None, show_progress=False).tf
        details = bag_details(bag, tf.edges())
    finally:
        bag.close()
    details["problem"] = reason
    return SourceInfo("rosbag", str(path), 0, None, [], "unknown", {}, {}, details)
