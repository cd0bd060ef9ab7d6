"""Configuration of the simulator: world preset, robot route, LiDAR and cameras.

Frames: the robot base frame sits on the ground (x forward, y left, z up); sensors are mounted on
it. Camera frames are optical (z forward, x right, y down). Lengths in metres, angles in degrees
in the config (radians in code).
"""

from __future__ import annotations

from pydantic import Field, ValidationInfo, field_validator, model_validator

from terra.schemas import Section


class LidarConfig(Section):
    """A spinning LiDAR: `beams` rows evenly spread over the vertical field of view, `columns`
    azimuth steps per turn. Range noise is Gaussian along the ray (metres, 0 = exact)."""

    beams: int = Field(default=32, ge=1, le=256)
    columns: int = Field(default=1024, ge=16, le=8192)
    vertical_fov_deg: tuple[float, float] = (-22.5, 22.5)
    min_range: float = Field(default=0.5, ge=0.0)
    max_range: float = Field(default=100.0, gt=0.0)
    range_noise_m: float = Field(default=0.0, ge=0.0)
    height: float = Field(default=1.8, gt=0.0, description="LiDAR origin above the ground, metres")
    wobble_deg: float = Field(
        default=0.0,
        ge=0.0,
        le=10.0,
        description="per-scan tilt of the beam pattern (vibration, suspension), degrees: each scan's beams turn by "
        "a random angle within this bound about each axis; points stay in the LiDAR frame and poses exact. 0 = the "
        "same pattern every scan, whose ground rings point-to-point ICP (KISS-ICP) matches to themselves",
    )

    @model_validator(mode="after")
    def _check(self) -> LidarConfig:
        lo, hi = self.vertical_fov_deg
        if not (-90.0 <= lo < hi <= 90.0):
            raise ValueError(f"vertical_fov_deg must satisfy -90 <= low < high <= 90, got {self.vertical_fov_deg}")
        if self.max_range <= self.min_range:
            raise ValueError("max_range must exceed min_range")
        return self


class CameraConfig(Section):
    """A camera with a real lens model (`terra.lens`): `model` pinhole with 0, 4, 5, 8, 12 or 14
    OpenCV coefficients [k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y], or fisheye
    (equidistant) with 4 [k1, k2, k3, k4].

    Mount: position (metres) in the robot base frame, then yaw (left-positive about z), pitch
    (down-positive) and roll about the viewing axis, in degrees. cx/cy default to the image centre.
    """

    name: str = "cam0"
    width: int = Field(default=640, ge=8, le=8192)
    height: int = Field(default=480, ge=8, le=8192)
    fx: float = Field(default=420.0, gt=0.0)
    fy: float = Field(default=420.0, gt=0.0)
    cx: float | None = None
    cy: float | None = None
    model: str = Field(default="pinhole", description="lens model: pinhole (OpenCV) or fisheye (equidistant)")
    dist: list[float] = Field(default_factory=lambda: [-0.05, 0.01, 0.0, 0.0, 0.0])
    position: tuple[float, float, float] = (0.2, 0.0, 1.5)
    yaw_deg: float = 0.0
    pitch_deg: float = 5.0
    roll_deg: float = 0.0

    @field_validator("dist")
    @classmethod
    def _dist_len(cls, v: list[float], info: ValidationInfo) -> list[float]:
        import numpy as np

        from terra import lens

        lens.check_coefficients(info.data.get("model", lens.PINHOLE), np.asarray(v, dtype=np.float64))
        return v

    @field_validator("name")
    @classmethod
    def _name_ok(cls, v: str) -> str:
        if not v or not v.replace("_", "").replace("-", "").isalnum():
            raise ValueError(f"camera name must be a non-empty word (letters, digits, '-', '_'), got {v!r}")
        return v

    @model_validator(mode="after")
    def _lens_is_usable(self) -> CameraConfig:
        cx = (self.width - 1) / 2 if self.cx is None else self.cx
        cy = (self.height - 1) / 2 if self.cy is None else self.cy
        if not (0.0 <= cx < self.width and 0.0 <= cy < self.height):
            raise ValueError(f"principal point ({cx}, {cy}) must lie inside the {self.width}x{self.height} image")
        import numpy as np

        from terra import lens

        if self.model != lens.PINHOLE or lens.has_distortion(np.asarray(self.dist, dtype=np.float64)):
            _check_distortion_invertible(self.dist, self.model, self.width, self.height, self.fx, self.fy, cx, cy)
        return self


def _check_distortion_invertible(
    dist: list[float], model: str, width: int, height: int, fx: float, fy: float, cx: float, cy: float
) -> None:
    """ValueError when the lens model folds over inside the image: then pixels have no unique
    viewing ray and the rendered image would be wrong. Checked on a grid that includes the image
    border: on straight lines from the principal point to grid pixels, every pixel must have an
    undistorted ray and the undistorted radius must grow with the distorted one."""
    import numpy as np

    from terra import lens

    u, v = np.meshgrid(np.linspace(-0.5, width - 0.5, 17), np.linspace(-0.5, height - 0.5, 13))
    ends = np.stack([(u.ravel() - cx) / fx, (v.ravel() - cy) / fy], axis=1)
    ends = ends[np.hypot(*ends.T) > 0]
    steps = np.linspace(0.0, 1.0, 65)[1:]
    lines = (ends[:, None, :] * steps[None, :, None]).reshape(-1, 2)  # rays out from the principal point
    with np.errstate(all="ignore"):
        radius = np.hypot(*lens.undistort(lines, np.asarray(dist, dtype=np.float64), model).T).reshape(
            len(ends), len(steps)
        )
    if not (np.all(np.isfinite(radius)) and np.all(np.diff(radius, axis=1) > 0)):
        raise ValueError(
            f"distortion {list(dist)} cannot be inverted over the {width}x{height} image "
            "(the lens model folds over; use smaller coefficients)"
        )


class RouteConfig(Section):
    """The robot route: frames every `frame_spacing` metres along it at `speed` m/s.

    `length_m` caps the route (None = the preset's length). Odometry drift (0 = ground-truth poses
    in the frames): random-walk standard deviations per metre travelled.
    """

    frame_spacing: float | None = Field(default=None, gt=0.0, description="metres between frames; None = preset")
    length_m: float | None = Field(default=None, gt=0.0)
    speed: float = Field(default=1.5, gt=0.0)
    drift_xy_per_m: float = Field(default=0.0, ge=0.0)
    drift_yaw_deg_per_m: float = Field(default=0.0, ge=0.0)
    max_frames: int | None = Field(default=None, ge=1)


class RevisitConfig(Section):
    """A second visit of the same world (terra/sim/revisit.py): the route reversed from `start_fraction`
    of its length, poses reported in a frame whose origin lies at `frame` = (x, y metres, yaw degrees) in the
    first visit's map frame, after changes drawn from `seed` near the revisit's route: cars moved (along or
    across their length, by a distance in `move_distance` metres), removed and added, benches removed,
    `lawns_to_dirt` lawn squares of `patch_size` metres turned to dirt, `fences_added` fences put up across
    a sidewalk (its ground then blocked). All counts 0: a revisit with no change."""

    frame: tuple[float, float, float] = (50.0, 0.0, 90.0)
    start_fraction: float = Field(default=0.3, ge=0.0, lt=1.0)
    seed: int = Field(default=1, ge=0)
    cars_moved: int = Field(default=2, ge=0)
    cars_removed: int = Field(default=2, ge=0)
    cars_added: int = Field(default=2, ge=0)
    benches_removed: int = Field(default=1, ge=0)
    lawns_to_dirt: int = Field(default=1, ge=0)
    fences_added: int = Field(default=1, ge=0, description="fences put up across a sidewalk near the route")
    move_distance: tuple[float, float] = (3.0, 6.0)
    patch_size: float = Field(default=6.0, gt=0.0)


class GnssConfig(Section):
    """A GNSS receiver on the robot: one fix per frame at the LiDAR's true position, the world frame
    anchored at `lat`, `lon` (degrees) and `alt` (metres) with +x east. Horizontal error: a bias per
    drive (standard deviation `bias_m` metres per axis, as a receiver's slowly wandering error) plus
    white noise of `noise_m` metres per axis per fix; vertical: the same at twice the size.
    `terra sim` writes the fixes as gnss.csv (terra-folder)."""

    lat: float = Field(default=47.3769, ge=-89.0, le=89.0)
    lon: float = Field(default=8.5417, ge=-180.0, le=180.0)
    alt: float = 408.0
    noise_m: float = Field(default=2.0, ge=0.0)
    bias_m: float = Field(default=0.0, ge=0.0)


class GeometryConfig(Section):
    """Ground geometry beyond the smooth height field (terra/sim/geometry.py), built as step offsets
    on the terrain raster's cells. Off unless the `geometry` section is given.

    - curbs: everything that is not asphalt (sidewalks, lawns, plazas) stands `curb_height_m` above
      the asphalt of roads and parking lots; where a walkway (a path the robot drives, e.g. a
      crosswalk or a driveway) crosses a curb, a curb cut `curb_cut_width_m` wide climbs from the
      road at `curb_cut_grade` (rise over run; 1:12 as accessibility codes ask);
    - stairs_ramps: beside each flight of stairs, a ramp `ramp_width_m` wide climbs at `ramp_grade`
      along the building's front to the stairs' top;
    - steep_hill: one mound on the widest open lawn whose flank reaches `hill_slope_deg` (steeper
      than a wheelchair's 8 degrees), `hill_height_m` high where the lawn is wide enough (lower
      where it is not, keeping the slope); `sloped_lawns` gentler mounds (`lawn_slope_deg`,
      `lawn_height_m`) on the next widest lawns.
    """

    curbs: bool = True
    curb_height_m: float = Field(default=0.15, ge=0.05, le=0.3, description="curb height, metres")
    curb_cut_grade: float = Field(default=1 / 12, gt=0.0, le=0.5, description="curb cut rise over run")
    curb_cut_width_m: float = Field(default=3.0, gt=0.0, le=10.0, description="curb cut width, metres")
    stairs_ramps: bool = True
    ramp_grade: float = Field(default=1 / 12, gt=0.0, le=0.5, description="ramp rise over run beside stairs")
    ramp_width_m: float = Field(default=1.2, gt=0.0, le=5.0, description="ramp width, metres")
    steep_hill: bool = True
    hill_slope_deg: float = Field(default=14.0, gt=0.0, lt=60.0, description="steepest slope of the hill, degrees")
    hill_height_m: float = Field(default=1.0, gt=0.0, le=5.0, description="hill height, metres")
    sloped_lawns: int = Field(default=2, ge=0, le=20, description="gently sloped lawn mounds")
    lawn_slope_deg: float = Field(default=4.0, gt=0.0, lt=60.0, description="steepest slope of a lawn mound")
    lawn_height_m: float = Field(default=0.4, gt=0.0, le=5.0, description="lawn mound height, metres")


class SimConfig(Section):
    """Everything `simulate` needs besides the preset name and seed."""

    lidar: LidarConfig = Field(default_factory=LidarConfig)
    cameras: list[CameraConfig] = Field(default_factory=lambda: [CameraConfig()])
    route: RouteConfig = Field(default_factory=RouteConfig)
    ground_relief_m: float = Field(
        default=1.0, ge=0.0, le=5.0, description="amplitude scale of the smooth height field"
    )
    terrain_resolution: float | None = Field(
        default=None, gt=0.0, description="ground-truth raster cell, metres; None = preset"
    )
    frame_cache: int = Field(default=4, ge=0, description="rendered frames kept in memory")
    revisit: RevisitConfig | None = Field(
        default=None, description="drive the world again as a second visit, changed (`terra sim --revisit`)"
    )
    gnss: GnssConfig | None = Field(default=None, description="a GNSS receiver's fixes, one per frame (gnss.csv)")
    geometry: GeometryConfig | None = Field(
        default=None, description="curbs, curb cuts, ramps beside stairs, a steep hill and sloped lawns (off: None)"
    )

    @field_validator("cameras")
    @classmethod
    def _unique_names(cls, v: list[CameraConfig]) -> list[CameraConfig]:
        names = [c.name for c in v]
        if len(set(names)) != len(names):
            raise ValueError(f"camera names must be unique, got {names}")
        return v


def without_distortion(config: SimConfig) -> SimConfig:
    """`config` with ideal pinhole lenses (rectified images, as KITTI raw ships them)."""
    cameras = [c.model_copy(update={"model": "pinhole", "dist": []}) for c in config.cameras]
    return config.model_copy(update={"cameras": cameras})
