"""Incremental Phase 1: frames fused one at a time, as they arrive, by one `Mapper`.

Every way frames come in goes through this class: `terra map` over a random-access dataset
(terra/mapping/pipeline.py), `terra map --append` continuing a bundle, and the live API
(terra/live). Each frame is checked (finite scan, rigid finite pose), perceived and fused; a frame
that cannot be used is counted by reason with a first example line and never fused. The frame's
position in the drive (`Mapper.next_frame`) seeds its perception noise, so a drive fed frame by
frame, in one batch, or in two parts joined by `--append` gives the same map, byte for byte.
"""

from __future__ import annotations

import numpy as np

from terra.datasets.base import CameraFrame, Frame
from terra.mapping.config import MappingConfig
from terra.mapping.fusion import FusionStats, MapFusion
from terra.mapping.semantic_map import MetricSemanticMap
from terra.perception.base import ImagePerception, Perception, PerceptionSkip
from terra.progress import StageTimer

POINTS_STREAM = 1 << 20  # noise stream number of per-point labels (camera streams are 0, 1, ...)


class Mapper:
    """The fusion of one drive, frame by frame. `fusion` holds the whole state (`state()` /
    `restore()` resume it exactly); `next_frame` is the index the next frame takes."""

    def __init__(
        self, config: MappingConfig, perception: Perception, fusion: MapFusion, timer: StageTimer | None = None
    ):
        self.config = config
        self.perception = perception
        self.fusion = fusion
        self.timer = timer if timer is not None else StageTimer()
        self.next_frame = 0
        self.first_stamp: float | None = None
        self.last_stamp: float | None = None
        self.run_first_stamp: float | None = None  # first stamp fused by this run (not restored)

    @property
    def stats(self) -> FusionStats:
        return self.fusion.stats

    def add(self, frame: Frame) -> bool:
        """Check and fuse `frame` as frame `next_frame` of the drive; False when it was skipped
        (counted in `stats`). Its `index` is set to its position in the drive."""
        i = self.next_frame
        self.next_frame += 1
        frame.index = i
        checked = check_frame(frame, i, self.stats)
        if checked is None:
            return False
        fuse_frame(checked, i, self.config, self.perception, self.fusion, self.timer)
        stamp = float(checked.stamp)
        self.first_stamp = stamp if self.first_stamp is None else self.first_stamp
        self.run_first_stamp = stamp if self.run_first_stamp is None else self.run_first_stamp
        self.last_stamp = stamp
        return True

    def skip(self, counter: str, message: str) -> None:
        """Count frame `next_frame` as unusable (e.g. unreadable in its file) without fusing it."""
        self.next_frame += 1
        self.stats.add(counter)
        self.stats.note(counter, message)

    def finish(self) -> MetricSemanticMap:
        """The map of every frame fused so far (the fusion state is kept: more frames may follow)."""
        with self.timer.stage("finish"):
            return self.fusion.finish(self.perception.embedder, self.perception.terrain_embeddings())

    def time_span(self) -> tuple[float, float] | None:
        """(first, last) stamp of the fused frames, seconds; None before the first."""
        if self.first_stamp is None or self.last_stamp is None:
            return None
        return self.first_stamp, self.last_stamp


def check_frame(frame: Frame, i: int, stats: FusionStats) -> Frame | None:
    """`frame` with non-finite points dropped, or None (counted) for a per-frame fault."""
    where = f"frame {i} (t = {float(frame.stamp):.3f} s)"
    points = np.asarray(frame.points)
    if points.ndim != 2 or points.shape[1] < 3:
        stats.add("frames_skipped_bad_points")
        stats.note("frames_skipped_bad_points", f"{where}: points must be (N, 3) metres, got shape {points.shape}")
        return None
    pose = np.asarray(frame.T_map_lidar, dtype=np.float64)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        stats.add("frames_skipped_bad_pose")
        stats.note("frames_skipped_bad_pose", f"{where}: T_map_lidar must be a finite 4x4 pose, got shape {pose.shape}")
        return None
    finite = np.isfinite(points[:, :3]).all(axis=1)
    if not finite.all():
        stats.add("points_dropped_nonfinite", int(np.count_nonzero(~finite)))
        frame.points = points[finite, :3]
        for name in ("point_labels", "point_instances", "intensity", "point_times"):
            values = getattr(frame, name)
            if values is not None:
                setattr(frame, name, np.asarray(values)[finite])
    frame.points = np.asarray(frame.points, dtype=np.float32)[:, :3]
    if frame.points.shape[0] == 0:
        stats.add("frames_skipped_empty")
        stats.note("frames_skipped_empty", f"{where}: no finite point in the scan")
        return None
    return frame


def image_fault(frame: Frame, camera: CameraFrame, config: MappingConfig) -> tuple[str, str] | None:
    """Why an image cannot be fused: (stats counter name, one line naming the image), or None."""
    calib = camera.calibration
    name = camera.name or f"frame {frame.index} camera {calib.name}"
    offset = abs(float(camera.stamp) - float(frame.stamp))
    if offset > config.projection.max_time_offset:
        return "images_skipped_unmatched_stamp", (
            f"{name}: image stamp {float(camera.stamp):.3f} s is {offset:.3f} s "
            f"from its scan's {float(frame.stamp):.3f} s "
            f"(tolerance {config.projection.max_time_offset} s)"
        )
    shape = (calib.height, calib.width)
    for what, array in (
        ("image", camera.image),
        ("semantic labels", camera.semantic),
        ("instance labels", camera.instance),
    ):
        if array is not None and np.asarray(array).shape[:2] != shape:
            return (
                "images_skipped_bad_size",
                f"{name}: {what} of {np.asarray(array).shape[:2]} pixels, calibration says (height, width) {shape}",
            )
    return None


def perceive_image(
    perception: Perception, frame: Frame, i: int, c: int, config: MappingConfig, stats: FusionStats
) -> ImagePerception | None:
    """The perception of camera `c` of frame `i`, or None (counted in `stats`, with a first note) when the
    image cannot be used. The generator is seeded by (noise seed, frame, camera), so any process perceiving
    this image, in any order, draws the same numbers."""
    camera = frame.cameras[c]
    fault = image_fault(frame, camera, config)
    if fault is not None:
        stats.add(fault[0])
        stats.note(*fault)
        return None
    try:
        return perception.perceive(camera, np.random.default_rng([config.perception.noise.seed, i, c]))
    except PerceptionSkip as exc:  # any other exception is a failure of the backend: it propagates
        stats.add("images_skipped_no_labels")
        stats.note("images_skipped_no_labels", f"{camera.name or f'frame {i} camera {c}'}: {exc}")
        return None


def uses_images(frame: Frame, config: MappingConfig) -> bool:
    """Whether frame's semantics come from its images (else from per-point labels, when the source has them)."""
    source = config.perception.source
    return source == "images" or (source == "auto" and bool(frame.cameras))


def fuse_frame(
    frame: Frame, i: int, config: MappingConfig, perception: Perception, fusion: MapFusion, timer: StageTimer
) -> None:
    """Associate, perceive and fuse one checked frame (`i`: its index in the drive)."""
    seed = config.perception.noise.seed
    source = config.perception.source
    with timer.stage("fusion"):
        points_map, index = fusion.associate(frame.points, frame.T_map_lidar)
    fusion.stats.add("frames_fused")
    if uses_images(frame, config):
        for c, camera in enumerate(frame.cameras):
            with timer.stage("perception"):
                seen = perceive_image(perception, frame, i, c, config, fusion.stats)
            if seen is None:
                continue
            with timer.stage("fusion"):
                fusion.integrate_image(
                    frame.points, points_map, index, frame.T_map_lidar, camera.calibration, camera.stamp, seen
                )
    elif source in ("auto", "points"):
        with timer.stage("perception"):
            seen_points = perception.perceive_points(frame, np.random.default_rng([seed, i, POINTS_STREAM]))
        if seen_points is not None:
            with timer.stage("fusion"):
                fusion.integrate_points(points_map, index, seen_points)
            fusion.stats.add("scans_fused_from_point_labels")
