"""Session fixtures of the mapping stage (see tests/conftest.py), and a hand-built scene.

`tiny_bundle` / `small_bundle`: noise-free maps of the simulated tiny / small campus, built once
per session with the default MappingConfig via terra.mapping.pipeline.build_map.
`tiny_mapped` / `small_mapped`: the same bundles with the simulator's truth recorded while they
were built (TruthRecorder), so end-to-end checks need not render the frames again.

`BoxScene`: a scene small enough to reason about by hand (flat ground split into grass and
asphalt, a few axis-aligned boxes), ray-cast exactly for a LiDAR and a pinhole camera, so the
mapping tests do not depend on the simulator.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from terra.datasets.base import CameraFrame, ClassTable, Frame, SemanticClass
from terra.geometry import CameraCalibration, invert_pose, make_pose, pixel_rays, transform_points


def in_point_order(msm):
    """`msm` with its rows sorted by point (x, then y, then z): a live version's map (rows in
    creation order) and the batch map of the same frames (in voxel-key order) become equal."""
    import dataclasses

    order = np.lexsort(msm.points.T[::-1])
    sorted_points = msm.points[order]
    assert not np.any(np.all(sorted_points[1:] == sorted_points[:-1], axis=1)), "two rows at one point"
    return dataclasses.replace(
        msm,
        points=sorted_points,
        terrain_votes=msm.terrain_votes[order],
        counts=msm.counts[order],
        fusion_rows=None,
        _avg_norm=None if msm._avg_norm is None else msm._avg_norm[order],
        _max_id=None if msm._max_id is None else msm._max_id[order],
    )


def assert_same_map(a, b, any_order: bool = False) -> None:
    """The maps `a` and `b` (bundle paths, read by `load_map`, or MetricSemanticMaps) are equal: every
    array, the MS-Avg norms and MS-Max ids included. any_order: the same rows in any order (a live
    version beside a batch map)."""
    from terra.bundle import Bundle
    from terra.mapping.semantic_map import MetricSemanticMap
    from terra.mapping.storage import load_map

    x, y = (m if isinstance(m, MetricSemanticMap) else load_map(Bundle(m)) for m in (a, b))
    if any_order:
        x, y = in_point_order(x), in_point_order(y)
    for name in ("points", "terrain_votes", "terrain_embeddings", "bank"):
        np.testing.assert_array_equal(getattr(x, name), getattr(y, name), err_msg=name)
        assert getattr(x, name).dtype == getattr(y, name).dtype, name
    for name in ("indptr", "indices", "data"):
        np.testing.assert_array_equal(getattr(x.counts, name), getattr(y.counts, name), err_msg=name)
    np.testing.assert_array_equal(x.ms_avg_norms(), y.ms_avg_norms())
    np.testing.assert_array_equal(x.ms_max_ids(), y.ms_max_ids())
    for name in ("stamp", "camera", "T_map_cam", "embedding"):
        np.testing.assert_array_equal(getattr(x.images, name), getattr(y.images, name), err_msg=name)
    assert x.visibility is not None and y.visibility is not None
    for name in ("cell_keys", "indptr", "images"):
        np.testing.assert_array_equal(getattr(x.visibility, name), getattr(y.visibility, name), err_msg=name)
    assert (x.embedder, x.terrain_classes, x.voxel_size) == (y.embedder, y.terrain_classes, y.voxel_size)


def folder_digest(path) -> dict[str, str]:
    """SHA-256 per file of a folder (relative path -> hex), to compare bundles byte for byte."""
    import hashlib
    from pathlib import Path

    path = Path(path)
    return {
        str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(path.rglob("*"))
        if p.is_file()
    }


# ---------------------------------------------------------------------------- session bundles


class TruthRecorder:
    """Wraps a dataset and, while the mapping pipeline reads each frame once, records the
    simulator's per-point labels per map voxel and, per image, the visible scan point nearest to
    its camera. The end-to-end tests check the map against these without rendering again."""

    def __init__(self, dataset, voxel_size: float):
        self._dataset, self.voxel_size = dataset, float(voxel_size)
        self.name, self.classes = dataset.name, dataset.classes
        self.label_pairs: dict[
            int, tuple[np.ndarray, np.ndarray, np.ndarray]
        ] = {}  # frame -> voxel keys, labels, counts
        self.nearest_seen: dict[tuple[int, int], np.ndarray] = {}  # (frame, camera) -> (3,) map frame

    def __len__(self) -> int:
        return len(self._dataset)

    def global_map(self):
        return self._dataset.global_map()

    def __getitem__(self, index: int) -> Frame:
        from terra.geometry import voxel_keys
        from terra.mapping.projection import visible_points

        frame = self._dataset[index]
        points_map = transform_points(frame.T_map_lidar, frame.points.astype(np.float64))
        labels = np.asarray(frame.point_labels, np.int64)
        self.label_pairs[index] = _count_pairs(voxel_keys(points_map, self.voxel_size), labels, np.ones(labels.size))
        for c, camera in enumerate(frame.cameras):
            seen = visible_points(frame.points, camera.calibration)
            self.nearest_seen[(index, c)] = points_map[seen.index[np.argmin(seen.distance)]]
        return frame

    def point_truth(self) -> np.ndarray:
        """Majority simulator label of the scan points in each occupied voxel, in voxel-key order
        (the order in which an accumulated map stores its points)."""
        frames = [self.label_pairs[i] for i in sorted(self.label_pairs)]
        voxel, label, votes = _count_pairs(*(np.concatenate(column) for column in zip(*frames)))
        # Per voxel, the label with the most votes (ties: lowest label).
        order = np.lexsort((label, -votes, voxel))
        first = np.ones(order.size, dtype=bool)
        first[1:] = voxel[order[1:]] != voxel[order[:-1]]
        return label[order[first]]


def _count_pairs(
    keys: np.ndarray, labels: np.ndarray, weights: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unique (key, label) pairs, sorted, with their summed weights."""
    if keys.size == 0:
        return keys, labels, weights
    order = np.lexsort((labels, keys))
    keys, labels = keys[order], labels[order]
    start = np.flatnonzero(np.r_[True, (keys[1:] != keys[:-1]) | (labels[1:] != labels[:-1])])
    return keys[start], labels[start], np.add.reduceat(weights[order], start)


@dataclass
class MappedCampus:
    """A session map of a simulated campus and what the simulator said while it was built."""

    bundle: object  # terra.bundle.Bundle
    truth: TruthRecorder


def _build_bundle(dataset, tmp_path_factory, name: str) -> MappedCampus:
    from terra.mapping.config import MappingConfig
    from terra.mapping.pipeline import build_map

    config = MappingConfig()
    recorder = TruthRecorder(dataset, config.fusion.voxel_size)
    out = tmp_path_factory.mktemp(name) / "map.terra"
    return MappedCampus(build_map(recorder, config, out, progress=False), recorder)


@pytest.fixture(scope="session")
def tiny_mapped(tiny_campus, tmp_path_factory) -> MappedCampus:
    """The noise-free map of simulate('tiny', 0) (default MappingConfig) and its recorded truth."""
    return _build_bundle(tiny_campus, tmp_path_factory, "tiny_bundle")


@pytest.fixture(scope="session")
def small_mapped(small_campus, tmp_path_factory) -> MappedCampus:
    """The noise-free map of simulate('small', 0) (default MappingConfig) and its recorded truth."""
    return _build_bundle(small_campus, tmp_path_factory, "small_bundle")


@pytest.fixture(scope="session")
def tiny_bundle(tiny_mapped):
    """Bundle (terra.bundle.Bundle) with the noise-free map of simulate('tiny', 0)."""
    return tiny_mapped.bundle


@pytest.fixture(scope="session")
def small_bundle(small_mapped):
    """Bundle (terra.bundle.Bundle) with the noise-free map of simulate('small', 0)."""
    return small_mapped.bundle


# ---------------------------------------------------------------------------- hand-built scene

BOX_CLASSES = ClassTable(
    [
        SemanticClass(0, "unlabeled"),
        SemanticClass(1, "grass", terrain=True),
        SemanticClass(2, "asphalt", terrain=True),
        SemanticClass(10, "car"),
        SemanticClass(11, "bench"),
        SemanticClass(12, "building"),
    ]
)


@dataclass
class Box:
    """Axis-aligned box in the map frame: min and max corners (metres), class id, instance id."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    class_id: int
    instance: int


def default_boxes() -> list[Box]:
    return [
        Box((9.0, -1.0, 0.0), (11.0, 0.8, 1.5), 10, 1),  # car, straddling grass / asphalt
        Box((9.0, 3.0, 0.0), (10.0, 4.5, 0.8), 11, 2),  # bench on the grass
        Box((24.0, -15.0, 0.0), (25.0, 15.0, 5.0), 12, 0),  # building wall (no instance)
    ]


def cast(origins: np.ndarray, dirs: np.ndarray, boxes: list[Box], max_range: float = 60.0):
    """Exact ray casting: (hit distance, class id, instance id) per ray; inf / 0 / 0 on a miss.

    Ground z = 0 is grass where y > 0 and asphalt elsewhere.
    """
    n = dirs.shape[0]
    origins = np.broadcast_to(origins, (n, 3))
    best = np.full(n, np.inf)
    cls = np.zeros(n, dtype=np.int32)
    inst = np.zeros(n, dtype=np.int32)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = np.where(dirs[:, 2] < 0, -origins[:, 2] / dirs[:, 2], np.inf)
        for box in boxes:
            t1 = (np.asarray(box.lo) - origins) / dirs
            t2 = (np.asarray(box.hi) - origins) / dirs
            t_near = np.nanmax(np.minimum(t1, t2), axis=1)
            t_far = np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (t_near <= t_far) & (t_near > 0) & (t_near < best)
            best[hit] = t_near[hit]
            cls[hit] = box.class_id
            inst[hit] = box.instance
    ground = (t_ground < best) & np.isfinite(t_ground)
    best[ground] = t_ground[ground]
    y = origins[:, 1] + best * dirs[:, 1]
    cls[ground] = np.where(y[ground] > 0, 1, 2)
    inst[ground] = 0
    far = best > max_range
    best[far], cls[far], inst[far] = np.inf, 0, 0
    return best, cls, inst


def box_camera(
    width: int = 160, height: int = 120, focal: float = 100.0, dist=(0.0, 0.0, 0.0, 0.0, 0.0)
) -> CameraCalibration:
    """A forward-looking camera (optical z = LiDAR +x) 0.2 m above and 0.1 m ahead of the LiDAR."""
    R = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # rows: cam x, y, z in LiDAR axes
    T_cam_lidar = make_pose(R, -R @ np.array([0.1, 0.0, 0.2]))
    K = np.array([[focal, 0, (width - 1) / 2], [0, focal, (height - 1) / 2], [0, 0, 1]])
    return CameraCalibration("front", width, height, K, np.asarray(dist), T_cam_lidar)


def lidar_directions(beams: int = 16, columns: int = 360, lo_deg: float = -20.0, hi_deg: float = 5.0) -> np.ndarray:
    elev = np.deg2rad(np.linspace(lo_deg, hi_deg, beams))
    azim = np.deg2rad(np.arange(columns) * 360.0 / columns)
    e, a = np.meshgrid(elev, azim, indexing="ij")
    return np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1).reshape(-1, 3)


@dataclass
class BoxScene:
    """A Dataset: the LiDAR (1.8 m above ground) drives along +x from x = -6 m, looking +x."""

    boxes: list[Box] = field(default_factory=default_boxes)
    n_frames: int = 6
    step: float = 1.5
    camera: CameraCalibration = field(default_factory=box_camera)
    with_cameras: bool = True
    name: str = "box-scene"
    classes: ClassTable = field(default_factory=lambda: BOX_CLASSES)

    def __len__(self) -> int:
        return self.n_frames

    def pose(self, i: int) -> np.ndarray:
        return make_pose(np.eye(3), np.array([-6.0 + self.step * i, 0.0, 1.8]))

    def __getitem__(self, index: int) -> Frame:
        if not 0 <= index < self.n_frames:
            raise IndexError(index)
        T = self.pose(index)
        dirs = lidar_directions()
        dist, cls, inst = cast(T[:3, 3], dirs, self.boxes)
        ok = np.isfinite(dist)
        points = (dirs[ok] * dist[ok, None]).astype(np.float32)  # LiDAR frame (no rotation)
        cameras = [self.render(T, float(index))] if self.with_cameras else []
        return Frame(index, float(index), points, T, cameras, point_labels=cls[ok], point_instances=inst[ok])

    def render(self, T_map_lidar: np.ndarray, stamp: float) -> CameraFrame:
        cam = self.camera
        T_map_cam = T_map_lidar @ invert_pose(cam.T_cam_lidar)
        rays = pixel_rays(cam) @ T_map_cam[:3, :3].T
        _, cls, inst = cast(T_map_cam[:3, 3], rays, self.boxes)
        shape = (cam.height, cam.width)
        image = np.zeros((*shape, 3), dtype=np.uint8)
        image[..., 0] = (cls.reshape(shape) * 20) % 256
        return CameraFrame(cam, stamp, image, cls.reshape(shape), inst.reshape(shape), "front")

    def global_map(self):
        return None

    def points_map(self, i: int) -> np.ndarray:
        """Scan i in the map frame (float64) and its labels, for reference computations."""
        frame = self[i]
        return transform_points(frame.T_map_lidar, frame.points.astype(np.float64))
