"""Fixtures of the ground-geometry tests: a LiDAR-only ROS 1 bag of the simulated tiny campus (no
images, no labels), its map and scene graph through the command line, and in-memory maps of bare
points."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from terra.mapping.semantic_map import ImageTable, MetricSemanticMap

LIDAR_ONLY_FRAMES = 8


def write_lidar_only_bag(path: Path, frames: int = LIDAR_ONLY_FRAMES) -> Path:
    """A ROS 1 bag of the first `frames` frames of simulate('tiny', 0): /tf_static, /tf and
    PointCloud2 x y z intensity only (no label field, no camera)."""
    from terra.geometry import invert_pose
    from terra.sim import simulate
    from terra.sim.bag_writer import BASE, LIDAR, LIDAR_TOPIC, MAP
    from terra.sim.config import SimConfig
    from tests.datasets.fixtures_ros import factory_for, write_test_bag

    dataset = simulate("tiny", 0, SimConfig.model_validate({"route": {"max_frames": frames}, "cameras": []}))
    factory = factory_for(ros1=True)
    T_base_lidar = dataset.lidar.T_base_lidar
    rows: list[tuple[str, str, int, object]] = []
    for i in range(len(dataset)):
        frame = dataset[i]
        ns = int(round(float(frame.stamp) * 1e9)) + 1
        if i == 0:
            rows.append(("/tf_static", "tf2_msgs/msg/TFMessage", ns, factory.tf([(ns, BASE, LIDAR, T_base_lidar)])))
        T_map_base = frame.T_map_lidar @ invert_pose(T_base_lidar)
        rows.append(("/tf", "tf2_msgs/msg/TFMessage", ns, factory.tf([(ns, MAP, BASE, T_map_base)])))
        cloud = factory.pointcloud2(ns, LIDAR, frame.points, frame.intensity)
        rows.append((LIDAR_TOPIC, "sensor_msgs/msg/PointCloud2", ns, cloud))
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_test_bag(path, rows, ros1=True)


@pytest.fixture(scope="session")
def lidar_only_bundle(tmp_path_factory) -> Path:
    """`terra map` then `terra build` of the LiDAR-only bag: a bundle whose map has no terrain
    classes, no images and no embeddings."""
    from terra.cli import run

    root = tmp_path_factory.mktemp("lidar_only")
    bag = write_lidar_only_bag(root / "drive" / "drive.bag")
    out = root / "lidar.terra"
    assert run(["map", str(bag), "-o", str(out)]) == 0
    assert run(["build", str(out)]) == 0
    return out


def points_map(points: np.ndarray, dim: int = 8) -> MetricSemanticMap:
    """A map of bare points (N, 3) (map frame, metres), as a LiDAR-only log gives: no terrain
    classes, no embeddings, no images."""
    n = len(points)
    return MetricSemanticMap(
        points=np.asarray(points, dtype=np.float32),
        terrain_classes=[],
        terrain_votes=np.zeros((n, 0), dtype=np.uint16),
        terrain_embeddings=np.zeros((0, dim), dtype=np.float32),
        counts=sp.csr_matrix((n, 0), dtype=np.int32),
        bank=np.zeros((0, dim), dtype=np.float32),
        images=ImageTable(np.zeros(0), np.zeros(0, np.int16), np.zeros((0, 4, 4)), np.zeros((0, dim), np.float32)),
        embedder="none",
    )
