"""Robot poses along a route: the base sits on the ground, tilted with it, heading along the route."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terra.geometry import make_pose, yaw_rotation
from terra.sim.heightfield import Heightfield


@dataclass
class Trajectory:
    """stamps (F,) seconds; T_map_base (F, 4, 4) ground-truth poses of the robot base;
    T_map_base_odom (F, 4, 4) the poses the robot believes (with drift; equal when drift is off)."""

    stamps: np.ndarray
    T_map_base: np.ndarray
    T_map_base_odom: np.ndarray

    def __len__(self) -> int:
        return int(self.stamps.shape[0])


def _interp(route: np.ndarray, cum: np.ndarray, s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, cum[-1])
    return np.stack([np.interp(s, cum, route[:, 0]), np.interp(s, cum, route[:, 1])], axis=1)


def sample_trajectory(
    route: np.ndarray,
    ground: Heightfield,
    spacing: float,
    speed: float,
    rng: np.random.Generator,
    max_frames: int | None = None,
    drift_xy_per_m: float = 0.0,
    drift_yaw_per_m: float = 0.0,
    look: float = 2.0,
) -> Trajectory:
    """One frame every `spacing` metres along `route` (K, 2); heading from the route `look` metres
    ahead and behind; drift as a random walk (metres and radians per sqrt(metre))."""
    seg = np.linalg.norm(np.diff(route, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    count = int(np.floor(cum[-1] / spacing + 1e-9)) + 1
    if max_frames is not None:
        count = min(count, max_frames)
    s = np.arange(count) * spacing
    xy = _interp(route, cum, s)
    ahead, behind = _interp(route, cum, s + look), _interp(route, cum, s - look)
    heading = ahead - behind
    weak = np.linalg.norm(heading, axis=1) < 0.5 * look  # at a turn-around, look only ahead
    heading[weak] = (ahead - xy)[weak]
    weak = np.linalg.norm(heading, axis=1) < 1e-6
    heading[weak] = (xy - behind)[weak]
    heading /= np.maximum(np.linalg.norm(heading, axis=1, keepdims=True), 1e-12)

    up = ground.normal(xy)
    fwd = np.concatenate([heading, np.zeros((count, 1))], axis=1)
    fwd -= np.einsum("ij,ij->i", fwd, up)[:, None] * up
    fwd /= np.linalg.norm(fwd, axis=1, keepdims=True)
    left = np.cross(up, fwd)
    T = np.tile(np.eye(4), (count, 1, 1))
    T[:, :3, 0], T[:, :3, 1], T[:, :3, 2] = fwd, left, up
    T[:, :2, 3] = xy
    T[:, 2, 3] = ground.height(xy)

    stamps = np.round(s / speed, 6)
    odom = T.copy()
    if drift_xy_per_m > 0 or drift_yaw_per_m > 0:
        steps = np.diff(s, prepend=0.0)
        err_xy = np.cumsum(rng.normal(0.0, 1.0, (count, 2)) * drift_xy_per_m * np.sqrt(steps)[:, None], axis=0)
        err_yaw = np.cumsum(rng.normal(0.0, 1.0, count) * drift_yaw_per_m * np.sqrt(steps))
        p0 = T[0, :3, 3]
        for k in range(count):
            shift = make_pose(yaw_rotation(err_yaw[k]), p0 + np.array([err_xy[k, 0], err_xy[k, 1], 0.0]))
            odom[k] = shift @ make_pose(np.eye(3), -p0) @ T[k]
    return Trajectory(stamps, T, odom)
