"""A hand-built dataset for the format tests: two distorted cameras, per-point labels and instances
(including ids above 255 and a class SemanticKITTI does not have), and hand-made ground truth.

Small enough that writing and reading it takes a fraction of a second.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from terra.datasets.base import CameraFrame, ClassTable, Frame, SemanticClass
from terra.datasets.ground_truth import GroundTruth, NamedRegion, ObjectBox, TerrainRaster
from terra.geometry import CameraCalibration, make_pose

CLASSES = ClassTable(
    [
        SemanticClass(0, "unlabeled", False, 0),
        SemanticClass(1, "sidewalk", True, 48),
        SemanticClass(3, "asphalt", True, 40),
        SemanticClass(20, "car", False, 10),
        SemanticClass(23, "bench", False, None),  # not in SemanticKITTI: written with an id >= 100
    ]
)
STAMPS = (100.0, 100.25, 100.625)  # exact with six decimals, as the reference layout writes them
WIDTH, HEIGHT = 64, 48

# Optical frame (z forward, x right, y down) from a LiDAR frame (x forward, y left, z up).
_LIDAR_TO_OPTICAL = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def calibrations() -> list[CameraCalibration]:
    """A forward camera and one looking left, both with radial-tangential distortion."""
    front = CameraCalibration(
        "front",
        WIDTH,
        HEIGHT,
        np.array([[52.0, 0.0, 31.5], [0.0, 51.0, 23.25], [0.0, 0.0, 1.0]]),
        np.array([-0.11, 0.023, 0.0012, -0.0021, 0.0004]),
        make_pose(
            Rotation.from_euler("x", 4.0, degrees=True).as_matrix() @ _LIDAR_TO_OPTICAL, np.array([0.01, 0.32, -0.21])
        ),
    )
    left = CameraCalibration(
        "left",
        WIDTH,
        HEIGHT,
        np.array([[47.0, 0.0, 30.0], [0.0, 47.5, 24.5], [0.0, 0.0, 1.0]]),
        np.array([0.05, -0.01, 0.0, 0.0, 0.0]),
        make_pose(
            _LIDAR_TO_OPTICAL @ Rotation.from_euler("z", -90.0, degrees=True).as_matrix(), np.array([0.1, -0.2, 0.05])
        ),
    )
    return [front, left]


def _image(rng: np.random.Generator, semantic: np.ndarray) -> np.ndarray:
    """Shaded class colours, like the simulator's images (smooth enough for JPEG)."""
    palette = rng.integers(30, 220, size=(int(semantic.max()) + 1, 3))
    shade = np.linspace(0.8, 1.0, semantic.shape[0])[:, None, None]
    return (palette[semantic] * shade).astype(np.uint8)


def hand_frames(seed: int = 3) -> list[Frame]:
    rng = np.random.default_rng(seed)
    ids = np.array([c.id for c in CLASSES])
    frames = []
    for i, t in enumerate(STAMPS):
        n = 150 + 40 * i
        points = rng.uniform(-30, 30, size=(n, 3)).astype(np.float32)
        pose = make_pose(
            Rotation.from_euler("zyx", [0.3 * i + 0.1, 0.02, -0.03]).as_matrix(),
            np.array([5.0 * i + 0.123, -2.0 * i, 0.5]),
        )
        cams = []
        for cal in calibrations():
            semantic = np.repeat(np.repeat(rng.choice(ids, size=(6, 8)), 8, 0), 8, 1).astype(np.int32)
            instance = np.where(semantic == 20, 300 + i, np.where(semantic == 23, 65535, 0)).astype(np.int32)
            cams.append(CameraFrame(cal, t, _image(rng, semantic), semantic, instance))
        frames.append(
            Frame(
                i,
                t,
                points,
                pose,
                cams,
                rng.uniform(0, 1, n).astype(np.float32),
                rng.choice(ids, n).astype(np.int32),
                rng.choice([0, 7, 300, 65535], n).astype(np.int32),
            )
        )
    return frames


def hand_ground_truth() -> GroundTruth:
    rng = np.random.default_rng(5)
    objects = [
        ObjectBox(7, 20, "car", np.array([12.5, -3.25, 0.75]), np.array([4.5, 1.8, 1.5]), 0.5),
        ObjectBox(300, 23, "bench", np.array([-1.0, 2.0, 0.4]), np.array([1.5, 0.5, 0.8]), -1.25),
    ]
    raster = TerrainRaster(
        rng.choice([1, 3], size=(6, 9)).astype(np.int32),
        rng.uniform(0, 2, (6, 9)).astype(np.float32),
        np.array([-10.0, -5.0]),
        0.5,
        {1: "sidewalk", 3: "asphalt"},
    )
    regions = [NamedRegion("lot", "a small parking lot", np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]]))]
    return GroundTruth(objects, raster, regions)


class HandDataset:
    """`hand_frames()` as a Dataset with ground truth."""

    name = "hand"
    classes = CLASSES

    def __init__(self) -> None:
        self.frames = hand_frames()
        self.gt = hand_ground_truth()

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, index: int) -> Frame:
        return self.frames[index]

    def global_map(self):
        return None

    def ground_truth(self) -> GroundTruth:
        return self.gt
