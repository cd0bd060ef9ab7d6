"""What the KITTI formats share (odometry / SemanticKITTI, raw drives, object and tracking labels):
calibration text files, date-time stamp files, projection matrices and the standard class table.

Calibration files are lines `KEY: v1 v2 ...` (raw `calib_*.txt`, odometry `calib.txt`) or
`KEY v1 v2 ...` (tracking `calib/NNNN.txt`: `R_rect`, `Tr_velo_cam`, `Tr_imu_velo`); `calib_time`
holds text (`09-Jan-2012 13:57:47`), every other key numbers. Matrices are row-major.
"""

from __future__ import annotations

import calendar
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.linalg import rq

from terra.datasets.base import ClassTable, SemanticClass
from terra.errors import TerraError
from terra.fileio import read_text
from terra.geometry import make_pose

TEXT_KEYS = frozenset({"calib_time"})
MAX_CALIB_BYTES = 1 << 20
# Metres: a sensor mount or a map frame spans at most a few hundred km (the bound of the query
# coordinates, terra.tasks.lookup); a calibration translation beyond it is a typo or an overflow.
MAX_TRANSLATION = 1.0e7

# SemanticKITTI's own label table: id -> (name, BGR colour as in semantic-kitti.yaml).
STANDARD_LABELS: dict[int, tuple[str, tuple[int, int, int]]] = {
    0: ("unlabeled", (0, 0, 0)),
    1: ("outlier", (0, 0, 255)),
    10: ("car", (245, 150, 100)),
    11: ("bicycle", (245, 230, 100)),
    13: ("bus", (250, 80, 100)),
    15: ("motorcycle", (150, 60, 30)),
    16: ("on-rails", (255, 0, 0)),
    18: ("truck", (180, 30, 80)),
    20: ("other-vehicle", (255, 0, 0)),
    30: ("person", (30, 30, 255)),
    31: ("bicyclist", (200, 40, 255)),
    32: ("motorcyclist", (90, 30, 150)),
    40: ("road", (255, 0, 255)),
    44: ("parking", (255, 150, 255)),
    48: ("sidewalk", (75, 0, 75)),
    49: ("other-ground", (75, 0, 175)),
    50: ("building", (0, 200, 255)),
    51: ("fence", (50, 120, 255)),
    52: ("other-structure", (0, 150, 255)),
    60: ("lane-marking", (170, 255, 150)),
    70: ("vegetation", (0, 175, 0)),
    71: ("trunk", (0, 60, 135)),
    72: ("terrain", (80, 240, 150)),
    80: ("pole", (150, 240, 255)),
    81: ("traffic-sign", (0, 0, 255)),
    99: ("other-object", (255, 255, 50)),
    252: ("moving-car", (245, 150, 100)),
    253: ("moving-bicyclist", (200, 40, 255)),
    254: ("moving-person", (30, 30, 255)),
    255: ("moving-motorcyclist", (90, 30, 150)),
    256: ("moving-on-rails", (255, 0, 0)),
    257: ("moving-bus", (250, 80, 100)),
    258: ("moving-truck", (180, 30, 80)),
    259: ("moving-other-vehicle", (255, 0, 0)),
}
STANDARD_TERRAIN = {40, 44, 48, 49, 72}


def standard_classes() -> ClassTable:
    """SemanticKITTI's own table (ids are SemanticKITTI ids; road, parking, sidewalk,
    other-ground and terrain are terrain classes). The vocabulary of real KITTI data."""
    return ClassTable([SemanticClass(i, n, i in STANDARD_TERRAIN, i) for i, (n, _) in STANDARD_LABELS.items()])


# ------------------------------------------------------------------------------ calibration files
@dataclass
class CalibFile:
    """The numeric entries of one KITTI calibration file, with the line each came from (1-based)."""

    path: Path
    values: dict[str, np.ndarray] = field(default_factory=dict)
    lines: dict[str, int] = field(default_factory=dict)
    text: dict[str, str] = field(default_factory=dict)

    def __contains__(self, key: str) -> bool:
        return key in self.values

    def keys(self) -> list[str]:
        return list(self.values)

    def where(self, key: str) -> str:
        """ "file:line" of `key` (the file alone when the key is absent)."""
        return f"{self.path}:{self.lines[key]}" if key in self.lines else str(self.path)

    def matrix(self, key: str, shape: tuple[int, ...], what: str = "") -> np.ndarray:
        """Entry `key` reshaped to `shape` (row-major); TerraError naming the file, line and key
        when it is missing or has another number of values."""
        size = int(np.prod(shape))
        label = f" ({what})" if what else ""
        if key not in self.values:
            raise TerraError(f"{self.path}: no {key} line; expected {size} numbers{label}")
        value = self.values[key]
        if value.size != size:
            raise TerraError(f"{self.where(key)}: {key} has {value.size} numbers, expected {size}{label}")
        if not np.all(np.isfinite(value)):
            raise TerraError(f"{self.where(key)}: {key} has non-finite numbers")
        return value.reshape(shape)

    def rigid(self, rotation_key: str, translation_key: str) -> np.ndarray:
        """4x4 pose from a 3x3 rotation entry and a 3-vector translation entry (metres); the
        rotation must be orthonormal to 1e-4 (KITTI writes six significant digits)."""
        R = self.matrix(rotation_key, (3, 3), "a 3x3 rotation, row-major")
        t = self.matrix(translation_key, (3,), "a translation in metres")
        check_rotation(R, f"{self.where(rotation_key)}: {rotation_key}")
        check_translation(t, f"{self.where(translation_key)}: {translation_key}")
        return make_pose(R, t)

    def pose_3x4(self, key: str) -> np.ndarray:
        """4x4 pose from a 3x4 [R | t] entry (Tr, Tr_velo_cam, ...)."""
        T = np.eye(4)
        T[:3] = self.matrix(key, (3, 4), "a 3x4 [R | t] transform, row-major")
        check_rotation(T[:3, :3], f"{self.where(key)}: {key}")
        check_translation(T[:3, 3], f"{self.where(key)}: {key}'s translation")
        return T


def check_rotation(R: np.ndarray, where: str, tolerance: float = 1e-4) -> None:
    """TerraError naming `where` unless R is a rotation (orthonormal, determinant +1)."""
    # Entries of a rotation lie in [-1, 1]: checked first, so a huge entry cannot overflow the product.
    if (
        not np.all(np.abs(R) <= 1.0 + tolerance)
        or np.abs(R @ R.T - np.eye(3)).max() > tolerance
        or np.linalg.det(R) < 0
    ):
        raise TerraError(f"{where} is not a rotation matrix (rows must be orthonormal with determinant +1)")


def check_translation(t: np.ndarray, where: str) -> None:
    """TerraError naming `where` unless every coordinate of t lies within +-MAX_TRANSLATION metres."""
    if not np.all(np.abs(t) <= MAX_TRANSLATION):
        raise TerraError(
            f"{where} must be within +-{MAX_TRANSLATION:g} m per axis, got {np.abs(t).max():g} m "
            "(a typo or an overflow)"
        )


def read_calib_file(path: Path) -> CalibFile:
    """Parse a KITTI calibration file; TerraError naming the file, line and key on a malformed line."""
    path = Path(path)
    text = read_text(path, "calibration file", MAX_CALIB_BYTES)
    calib = CalibFile(path)
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        if ":" in line:
            key, rest = line.split(":", 1)
        else:
            key, _, rest = line.strip().partition(" ")
        key = key.strip()
        if not key or " " in key:
            raise TerraError(f"{path}:{number}: expected 'KEY: numbers', got {line.strip()[:60]!r}")
        if key in TEXT_KEYS:
            calib.text[key] = rest.strip()
            continue
        try:
            calib.values[key] = np.array([float(v) for v in rest.split()], dtype=np.float64)
        except ValueError:
            raise TerraError(
                f"{path}:{number}: {key} has a value that is not a number ({rest.strip()[:60]!r})"
            ) from None
        calib.lines[key] = number
    return calib


def decompose_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """K (3x3, positive diagonal) and T_cam_ref (4x4) with P = K [R | t] for a 3x4 projection
    matrix that maps reference-frame points (metres) to pixels. KITTI's rectified P2/P3 give R = I."""
    scale = np.abs(P[:, :3]).max() if np.all(np.isfinite(P)) else 0.0
    if not scale or abs(np.linalg.det(P[:, :3] / scale)) < 1e-12:
        raise ValueError("is not a camera projection (its left 3x3 block must be finite and invertible)")
    K, R = rq(P[:, :3])
    signs = np.diag(np.sign(np.where(np.diag(K) == 0, 1.0, np.diag(K))))
    K, R = K @ signs, signs @ R  # signs @ signs = I: flip so focal lengths are positive
    if np.linalg.det(R) < 0:  # P is only defined up to scale: take the scale that makes R a rotation
        K, R = -K, -R
    t = np.linalg.solve(K, P[:, 3])
    scale = K[2, 2]
    return K / scale, make_pose(R, t)


# ------------------------------------------------------------------------------------ time stamps
def parse_timestamp(text: str) -> float:
    """Seconds since 1970 of a KITTI raw stamp `YYYY-MM-DD HH:MM:SS.fffffffff` (nanoseconds; the
    recording clock is read as UTC). ValueError when the text is not one."""
    text = text.strip()
    whole, dot, fraction = text.partition(".")
    parsed = time.strptime(whole, "%Y-%m-%d %H:%M:%S")
    if dot and not (fraction.isdigit() and len(fraction) <= 9):
        raise ValueError(f"bad fraction of a second {fraction!r}")
    return float(calendar.timegm(parsed)) + (int(fraction) / 10 ** len(fraction) if dot else 0.0)


def format_timestamp(seconds: float, base: int = 0) -> str:
    """`YYYY-MM-DD HH:MM:SS.fffffffff` (UTC) of `base + seconds` since 1970, as KITTI raw writes
    stamps (a whole `base` keeps the nanoseconds of small `seconds` exact)."""
    whole = int(np.floor(seconds))
    nanos = int(round((seconds - whole) * 1e9))
    whole += int(base)
    if nanos == 1_000_000_000:
        whole, nanos = whole + 1, 0
    return time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(whole)) + f".{nanos:09d}"


def read_timestamps(path: Path) -> np.ndarray:
    """(N,) seconds since 1970 of a KITTI raw `timestamps.txt`; TerraError naming the file and line."""
    path = Path(path)
    lines = read_text(path, "time stamp file").splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    stamps = np.empty(len(lines))
    for number, line in enumerate(lines, start=1):
        try:
            stamps[number - 1] = parse_timestamp(line)
        except ValueError:
            raise TerraError(
                f"{path}:{number}: expected a stamp like 2011-09-26 13:02:25.964389445, got {line.strip()[:40]!r}"
            ) from None
    return stamps
