"""KITTI's OXTS RT3003 GPS/IMU packets and the poses the raw-data devkit derives from them.

A packet is one text line of 30 numbers (devkit `dataformat.txt`): lat, lon (degrees), alt
(metres), roll, pitch, yaw (radians; roll positive = left side up, pitch positive = front down,
yaw 0 = east, counter-clockwise), vn, ve, vf, vl, vu (m/s), ax, ay, az, af, al, au (m/s^2,
gravity included), wx, wy, wz, wf, wl, wu (rad/s), pos_accuracy (m), vel_accuracy (m/s), then five
integers: navstat, numsats, posmode, velmode, orimode.

Poses, in three steps (the devkit's `convertOxtsToPose`):
1. parse: `read_packet` / `read_packets` -> (N, 30) float64;
2. pose: `world_poses` -> T_world_imu (N, 4, 4): a Mercator projection with the scale
   cos(first latitude) (x east, y north, metres), altitude as z, and R = Rz(yaw) Ry(pitch) Rx(roll);
3. normalise: `normalise_poses` moves the origin to the first packet's position (axes stay east,
   north, up: a gravity-aligned map) or, as the devkit does, makes the first pose the identity.
The IMU frame is x forward, y left, z up. `packets_from_poses` inverts steps 1-2 (the simulator
writes OXTS this way, from a fixed geodetic origin).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from terra.errors import TerraError

FIELDS = (
    "lat",
    "lon",
    "alt",
    "roll",
    "pitch",
    "yaw",
    "vn",
    "ve",
    "vf",
    "vl",
    "vu",
    "ax",
    "ay",
    "az",
    "af",
    "al",
    "au",
    "wx",
    "wy",
    "wz",
    "wf",
    "wl",
    "wu",
    "pos_accuracy",
    "vel_accuracy",
    "navstat",
    "numsats",
    "posmode",
    "velmode",
    "orimode",
)
FIELD = {name: i for i, name in enumerate(FIELDS)}
INTEGER_FIELDS = FIELDS[-5:]
EARTH_RADIUS = 6378137.0  # metres, the devkit's (WGS84 equatorial radius)
GRAVITY = 9.81  # m/s^2, added to the simulated accelerations (the unit measures specific force)
Normalise = Literal["first-position", "first-pose"]


# ----------------------------------------------------------------------------------------- parse
def parse_packet(text: str, where: str) -> np.ndarray:
    """(30,) float64 of one packet's text; TerraError naming `where` unless it has 30 finite numbers."""
    words = text.split()
    if len(words) != len(FIELDS):
        raise TerraError(
            f"{where}: expected {len(FIELDS)} numbers ({', '.join(FIELDS[:6])}, ... {FIELDS[-1]}), got {len(words)}"
        )
    try:
        packet = np.array([float(w) for w in words])
    except ValueError:
        bad = next(w for w in words if not _is_number(w))
        raise TerraError(f"{where}: {FIELDS[words.index(bad)]} is not a number ({bad!r})") from None
    if not np.all(np.isfinite(packet[:6])):
        raise TerraError(f"{where}: lat, lon, alt, roll, pitch and yaw must be finite, got {packet[:6].tolist()}")
    if abs(packet[0]) >= 90.0 or abs(packet[1]) > 180.0:
        raise TerraError(f"{where}: latitude {packet[0]} / longitude {packet[1]} out of range (degrees)")
    return packet


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def read_packet(path: Path) -> np.ndarray:
    """The packet in one `oxts/data/NNNNNNNNNN.txt` file (a single line)."""
    from terra.fileio import read_text

    text = read_text(path, "OXTS packet", 1 << 20)
    lines = [line for line in text.splitlines() if line.strip()]
    if len(lines) != 1:
        raise TerraError(f"{path}: expected one line of {len(FIELDS)} numbers, got {len(lines)} lines")
    return parse_packet(lines[0], str(path))


def read_packets(paths: list[Path]) -> np.ndarray:
    """(N, 30) packets of N files, in the given order."""
    return np.array([read_packet(p) for p in paths]).reshape(-1, len(FIELDS))


def format_packet(packet: np.ndarray) -> str:
    """One packet as KITTI writes it: 25 real numbers (shortest exact text), then five integers."""
    reals = " ".join(repr(float(v)) for v in packet[:25])
    return reals + " " + " ".join(str(int(v)) for v in packet[25:])


# ------------------------------------------------------------------------------------------ pose
def mercator_scale(first_latitude: float) -> float:
    """The devkit's Mercator scale: cos(latitude of the first packet)."""
    return float(np.cos(np.radians(first_latitude)))


def lat_lon_to_mercator(lat: np.ndarray, lon: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Mercator x (east) and y (north), metres, of latitudes and longitudes in degrees."""
    x = scale * np.radians(lon) * EARTH_RADIUS
    y = scale * EARTH_RADIUS * np.log(np.tan(np.radians(90.0 + np.asarray(lat)) / 2.0))
    return x, y


def mercator_to_lat_lon(x: np.ndarray, y: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of `lat_lon_to_mercator`: degrees from Mercator metres."""
    lon = np.degrees(np.asarray(x) / (scale * EARTH_RADIUS))
    lat = 2.0 * np.degrees(np.arctan(np.exp(np.asarray(y) / (scale * EARTH_RADIUS)))) - 90.0
    return lat, lon


def rotation_from_rpy(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(N, 3, 3) R = Rz(yaw) Ry(pitch) Rx(roll) (radians): IMU frame -> east-north-up."""
    roll, pitch, yaw = (np.atleast_1d(np.asarray(a, np.float64)) for a in (roll, pitch, yaw))
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    R = np.empty((roll.size, 3, 3))
    R[:, 0] = np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], 1)
    R[:, 1] = np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], 1)
    R[:, 2] = np.stack([-sp, cp * sr, cp * cr], 1)
    return R


def rpy_from_rotation(R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(roll, pitch, yaw) radians with R = Rz(yaw) Ry(pitch) Rx(roll), pitch in [-pi/2, pi/2]."""
    R = np.asarray(R).reshape(-1, 3, 3)
    pitch = np.arcsin(np.clip(-R[:, 2, 0], -1.0, 1.0))
    roll = np.arctan2(R[:, 2, 1], R[:, 2, 2])
    yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    return roll, pitch, yaw


def world_poses(packets: np.ndarray) -> np.ndarray:
    """(N, 4, 4) T_world_imu: Mercator metres (scale from the first latitude), altitude, roll/pitch/yaw."""
    packets = np.asarray(packets, np.float64).reshape(-1, len(FIELDS))
    if len(packets) == 0:
        return np.zeros((0, 4, 4))
    scale = mercator_scale(packets[0, FIELD["lat"]])
    x, y = lat_lon_to_mercator(packets[:, FIELD["lat"]], packets[:, FIELD["lon"]], scale)
    T = np.tile(np.eye(4), (len(packets), 1, 1))
    T[:, :3, :3] = rotation_from_rpy(packets[:, FIELD["roll"]], packets[:, FIELD["pitch"]], packets[:, FIELD["yaw"]])
    T[:, :3, 3] = np.stack([x, y, packets[:, FIELD["alt"]]], axis=1)
    return T


def normalise_poses(T_world_imu: np.ndarray, mode: Normalise = "first-position") -> np.ndarray:
    """Poses relative to the first: 'first-position' subtracts its position (the map keeps the east,
    north, up axes, so z is up); 'first-pose' left-multiplies by its inverse, as the devkit does."""
    T = np.array(T_world_imu, dtype=np.float64, copy=True)
    if len(T) == 0:
        return T
    if mode == "first-pose":
        return np.linalg.inv(T[0]) @ T
    T[:, :3, 3] -= T[0, :3, 3]
    return T


# ----------------------------------------------------------------------------- simulated packets
def packets_from_poses(T_map_imu: np.ndarray, stamps: np.ndarray, origin: tuple[float, float, float]) -> np.ndarray:
    """(N, 30) packets whose `world_poses`, normalised to 'first-position', are T_map_imu minus the
    first position: the first pose lies at geodetic `origin` (lat, lon degrees, alt metres), map x
    is east, y north, z up. Velocities, accelerations (gravity included) and angular rates come
    from finite differences over `stamps` (seconds)."""
    T = np.asarray(T_map_imu, np.float64).reshape(-1, 4, 4)
    n = len(T)
    lat0, lon0, alt0 = origin
    scale = mercator_scale(lat0)  # the reader takes the scale from the first latitude: this one
    x0, y0 = lat_lon_to_mercator(np.array([lat0]), np.array([lon0]), scale)
    offset = T[:, :3, 3] - T[0, :3, 3]
    lat, lon = mercator_to_lat_lon(x0[0] + offset[:, 0], y0[0] + offset[:, 1], scale)
    roll, pitch, yaw = rpy_from_rotation(T[:, :3, :3])
    packets = np.zeros((n, len(FIELDS)))
    packets[:, :6] = np.stack([lat, lon, alt0 + offset[:, 2], roll, pitch, yaw], axis=1)
    packets[:, 6:25] = _motion(T, np.asarray(stamps, np.float64), yaw)
    packets[:, 25:] = [4, 10, 4, 4, 0]  # navstat, numsats, posmode, velmode, orimode of a good RTK fix
    return packets


def _motion(T: np.ndarray, stamps: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(N, 19) vn ve vf vl vu, ax ay az af al au, wx wy wz wf wl wu, pos_accuracy, vel_accuracy."""
    n = len(T)
    out = np.zeros((n, 19))
    out[:, 17:] = [0.02, 0.02]
    if n < 2:  # at rest: the accelerometer measures gravity alone
        out[:, 7] = out[:, 10] = GRAVITY
        return out
    p = T[:, :3, 3]
    v = np.gradient(p, stamps, axis=0)
    a = np.gradient(v, stamps, axis=0) + [0.0, 0.0, GRAVITY]
    heading = _heading_frames(yaw)  # level frames: forward, left, up
    R = T[:, :3, :3]
    omega_world = _angular_velocity(R, stamps)
    v_level = np.einsum("nji,nj->ni", heading, v)
    out[:, 0:5] = np.stack([v[:, 1], v[:, 0], v_level[:, 0], v_level[:, 1], v[:, 2]], axis=1)
    out[:, 5:8] = np.einsum("nji,nj->ni", R, a)  # body axes
    out[:, 8:11] = np.einsum("nji,nj->ni", heading, a)
    out[:, 11:14] = np.einsum("nji,nj->ni", R, omega_world)
    out[:, 14:17] = np.einsum("nji,nj->ni", heading, omega_world)
    return out


def _heading_frames(yaw: np.ndarray) -> np.ndarray:
    return rotation_from_rpy(np.zeros_like(yaw), np.zeros_like(yaw), yaw)


def _angular_velocity(R: np.ndarray, stamps: np.ndarray) -> np.ndarray:
    """(N, 3) world-frame angular velocity (rad/s) from consecutive rotations (central where possible)."""
    from scipy.spatial.transform import Rotation

    steps = Rotation.from_matrix(np.einsum("nij,nkj->nik", R[1:], R[:-1])).as_rotvec() / np.diff(stamps)[:, None]
    omega = np.zeros((len(R), 3))
    omega[0], omega[-1] = steps[0], steps[-1]
    omega[1:-1] = 0.5 * (steps[:-1] + steps[1:])
    return omega
