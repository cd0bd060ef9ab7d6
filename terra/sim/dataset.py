"""SimDataset: the simulated campus as a Dataset whose frames are rendered on demand."""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from terra.datasets.base import CameraFrame, ClassTable, Frame, SourceInfo
from terra.datasets.gnss import GnssFixes, anchor_fields
from terra.datasets.ground_truth import GroundTruth
from terra.datasets.terra_folder import image_name
from terra.errors import TerraError
from terra.geometry import CameraCalibration, invert_pose
from terra.progress import StageTimer
from terra.sim.classes import SIM_CLASSES
from terra.sim.config import SimConfig
from terra.sim.presets import get_preset
from terra.sim.revisit import RevisitTruth
from terra.sim.sensors import Camera, Lidar
from terra.sim.trajectory import Trajectory, sample_trajectory
from terra.sim.world import World


class SimDataset:
    """Frames of a robot driving through a World, rendered lazily and deterministically.

    Frame i: LiDAR scan (points in the LiDAR frame with per-point class and instance ids), one
    image set per camera (RGB, semantic, instance) at the same stamp, and T_map_lidar: the
    ground-truth pose, or the drifted odometry pose when drift is configured (ground truth stays
    available from `gt_T_map_lidar`).
    """

    def __init__(self, world: World, config: SimConfig, preset: str, seed: int) -> None:
        self.world = world
        self.config = config
        self.preset = preset
        self.seed = int(seed)
        self.name = world.name
        self.classes: ClassTable = SIM_CLASSES
        p = get_preset(preset)
        self.lidar = Lidar(config.lidar)
        self.cameras = [Camera(c, self.lidar.T_base_lidar) for c in config.cameras]
        rng = np.random.default_rng([self.seed, 7])
        spacing = config.route.frame_spacing or p.spacing
        max_frames = config.route.max_frames or p.max_frames
        self.trajectory: Trajectory = sample_trajectory(
            world.route,
            world.ground,
            spacing,
            config.route.speed,
            rng,
            max_frames,
            config.route.drift_xy_per_m,
            np.radians(config.route.drift_yaw_deg_per_m),
        )
        # A revisit reports its poses in its own frame: T_session_lidar = T_session_world @ T_world_lidar.
        self.revisit: RevisitTruth | None = None
        self.T_session_world = np.eye(4)
        if config.revisit is not None:
            from terra.sim.revisit import session_pose

            self.T_session_world = invert_pose(session_pose(config.revisit))
        self._cache: OrderedDict[int, Frame] = OrderedDict()
        self.timer: StageTimer | None = None  # when set, rendering time is recorded per sensor

    def __len__(self) -> int:
        return len(self.trajectory)

    @property
    def calibrations(self) -> list[CameraCalibration]:
        return [c.calibration for c in self.cameras]

    def gt_T_map_lidar(self, index: int) -> np.ndarray:
        """Ground-truth pose of the LiDAR at frame `index` (4x4, map <- lidar)."""
        return self.trajectory.T_map_base[index] @ self.lidar.T_base_lidar

    def __getitem__(self, index: int) -> Frame:
        if not isinstance(index, (int, np.integer)):
            raise TypeError("SimDataset indices are integers")
        index = int(index)
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range (0..{len(self) - 1})")
        if index in self._cache:
            self._cache.move_to_end(index)
            return self._cache[index]
        frame = self.render(index)
        if self.config.frame_cache > 0:
            self._cache[index] = frame
            while len(self._cache) > self.config.frame_cache:
                self._cache.popitem(last=False)
        return frame

    def render(self, index: int) -> Frame:
        """Render frame `index` (no caching)."""
        from threadpoolctl import threadpool_limits

        # The renderer's matrix products are tiny ((N, 3) by (3, 3)); BLAS threads only fight the
        # compiled kernels' threads for the cores (10x slower products on 2 busy cores).
        with threadpool_limits(1, user_api="blas"):
            return self._render(index)

    def _render(self, index: int) -> Frame:
        stamp = float(self.trajectory.stamps[index])
        T_true = self.gt_T_map_lidar(index)
        rng = np.random.default_rng([self.seed, index, 1])
        timer = self.timer or StageTimer()
        with timer.stage("render lidar"):
            scan = self.lidar.render(self.world, T_true, rng)
        cams = []
        with timer.stage("render cameras"):
            for n, cam in enumerate(self.cameras):
                T_map_cam = T_true @ invert_pose(cam.calibration.T_cam_lidar)
                img = cam.render(self.world, T_map_cam)
                cams.append(
                    CameraFrame(
                        cam.calibration,
                        stamp,
                        img["image"],
                        img["semantic"],
                        img["instance"],
                        name=image_name(n, stamp),
                    )
                )
        T_reported = self.T_session_world @ self.trajectory.T_map_base_odom[index] @ self.lidar.T_base_lidar
        return Frame(
            index, stamp, scan["points"], T_reported, cams, scan["intensity"], scan["labels"], scan["instances"]
        )

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    def ground_truth(self) -> GroundTruth:
        return self.world.ground_truth()

    def reported_positions(self) -> np.ndarray:
        """(F, 3) metres: the LiDAR's position in each frame's reported pose (the frame's T_map_lidar),
        without rendering."""
        T = self.T_session_world @ self.trajectory.T_map_base_odom @ self.lidar.T_base_lidar
        return T[:, :3, 3]

    def gnss_fixes(self) -> GnssFixes | None:
        """A fix per frame when `sim.gnss` is set (terra.sim.config.GnssConfig), else None. The noise
        is drawn from the seed and the visit (a revisit's receiver errs differently)."""
        gnss = self.config.gnss
        if gnss is None:
            return None
        from terra.schemas import Wgs84Anchor
        from terra.wgs84 import MapToWgs84

        visit = 0 if self.config.revisit is None else self.config.revisit.seed + 1
        rng = np.random.default_rng([self.seed, 11, visit])
        true = (self.trajectory.T_map_base @ self.lidar.T_base_lidar)[:, :3, 3]
        sigma = np.array([1.0, 1.0, 2.0])
        error = rng.normal(0.0, gnss.bias_m, 3) * sigma + rng.normal(0.0, gnss.noise_m, (len(true), 3)) * sigma
        world = Wgs84Anchor(lat=gnss.lat, lon=gnss.lon, alt=gnss.alt, source="simulator")
        lon_lat_alt = MapToWgs84(world).lon_lat_height(true + error)
        std = np.full(len(true), float(np.hypot(gnss.noise_m, gnss.bias_m)))
        return GnssFixes(self.trajectory.stamps.copy(), lon_lat_alt[:, 1], lon_lat_alt[:, 0], lon_lat_alt[:, 2], std)

    def wgs84_anchor(self) -> dict | None:
        """The anchor of the reported poses' frame fitted to the GNSS fixes (terra.interop.gnss), or
        None without a receiver."""
        fixes = self.gnss_fixes()
        if fixes is None:
            return None
        return anchor_fields(self.trajectory.stamps, self.reported_positions(), fixes, f"GNSS fixes of {self.name}")

    def global_map(self) -> np.ndarray | None:
        """The simulator ships no prebuilt global map (writers accumulate one from the scans)."""
        return None

    def info(self) -> SourceInfo:
        """What `terra inspect` reports for a simulated campus (nothing is skipped)."""
        route = self.config.route
        drift = route.drift_xy_per_m > 0 or route.drift_yaw_deg_per_m > 0
        stamps = self.trajectory.stamps
        lidar = self.config.lidar
        return SourceInfo(
            "sim",
            f"sim:{self.preset}:{self.seed}",
            len(self),
            (float(stamps[0]), float(stamps[-1])),
            list(self.calibrations),
            "simulated odometry with drift" if drift else "simulator ground truth",
            details={
                "preset": self.preset,
                "seed": self.seed,
                "world": self.name,
                "lidar": f"{lidar.beams} x {lidar.columns}, {lidar.min_range}-{lidar.max_range} m",
            },
        )


def simulate(preset: str = "small", seed: int = 0, config: SimConfig | None = None) -> SimDataset:
    """A simulated campus: `preset` in tiny, small, campus, large, huge; same arguments, same data."""
    from terra.sim.presets import generate_world

    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise TerraError(f"seed must be a non-negative integer, got {seed!r}")
    config = config or SimConfig()
    world = generate_world(preset, int(seed), config)
    if config.revisit is None:
        return SimDataset(world, config, preset, int(seed))
    from terra.sim.revisit import revisit_world

    world, truth = revisit_world(world, config.revisit)
    dataset = SimDataset(world, config, preset, int(seed))
    dataset.revisit = truth
    return dataset
