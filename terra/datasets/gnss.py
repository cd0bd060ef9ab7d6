"""GNSS fixes of a drive and the WGS84 anchor of its frame: how two sessions that both carry GNSS
start their alignment from a shared frame (issue 26).

A receiver's fixes (a terra-folder's `gnss.csv`, sensor_msgs/NavSatFix in a bag) are WGS84
positions over time; the drive's poses put the same sensor in its own frame (metres, x, y
horizontal). The frame's anchor (terra.schemas.Wgs84Anchor: origin latitude, longitude, height and
the heading of +x) is the planar rigid transform that puts the poses, interpolated at the fixes'
stamps, onto the fixes in least squares, in a transverse Mercator plane centred on the fixes
(`fit_anchor`). Each fix counts by the inverse of its variance when the receiver gives one. Two
anchors give the pose of one frame in the other (terra.wgs84.pose_between), the prior that
registration then refines: white noise averages out over a drive, but a receiver's slowly wandering bias does
not, so the prior is only as good as the fixes (metres), never the final alignment.

The lever arm between antenna and LiDAR is not modelled: it moves the anchor by its length at
most, which the registration removes.

`gnss.csv`: a header `stamp,lat,lon,alt[,std]` then one fix per line: seconds, degrees, degrees,
metres, and optionally the horizontal standard deviation in metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from terra.errors import TerraError
from terra.geometry import yaw_rotation
from terra.schemas import Wgs84Anchor
from terra.wgs84 import MapToWgs84

GNSS_CSV = "gnss.csv"
NOT_READ = object()  # a source's anchor before it is fitted (sources fit it once)
HEADER = ("stamp", "lat", "lon", "alt")


@dataclass(frozen=True)
class GnssFixes:
    """N fixes: `stamps` (N,) seconds, `lat`, `lon` (N,) degrees WGS84, `alt` (N,) metres and
    `std` (N,) horizontal standard deviation in metres (NaN where the receiver gave none)."""

    stamps: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    alt: np.ndarray
    std: np.ndarray

    def __len__(self) -> int:
        return int(self.stamps.shape[0])


@dataclass(frozen=True)
class FittedAnchor:
    """An anchor fitted to a drive: the anchor, the RMS distance (metres) between the placed poses
    and the fixes, the fixes used, and the drive's spread (metres: the RMS distance of its fixed
    positions from their centre), which bounds how well the heading is known."""

    anchor: Wgs84Anchor
    rms: float
    fixes: int
    spread: float


def read_gnss_csv(path: Path) -> GnssFixes:
    """The fixes of a `gnss.csv` (module docstring); TerraError naming the file and line."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise TerraError(f"{path}: cannot read GNSS fixes ({exc})") from None
    header = [w.strip() for w in lines[0].split(",")] if lines else []
    if tuple(header[:4]) != HEADER or header[4:] not in ([], ["std"]):
        raise TerraError(f"{path}: expected the header 'stamp,lat,lon,alt' or 'stamp,lat,lon,alt,std', got {header}")
    rows = []
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        try:
            values = [float(w) for w in line.split(",")]
        except ValueError:
            values = []
        if len(values) != len(header) or not all(math.isfinite(v) for v in values[:4]):
            raise TerraError(f"{path}:{number}: expected {len(header)} numbers ({','.join(header)}), got {line!r}")
        if abs(values[1]) > 90.0 or abs(values[2]) > 180.0:
            raise TerraError(f"{path}:{number}: latitude {values[1]} / longitude {values[2]} out of range (degrees)")
        rows.append(values + [math.nan] * (5 - len(values)))
    table = np.asarray(rows, dtype=np.float64).reshape(-1, 5)
    order = np.argsort(table[:, 0], kind="stable")
    return GnssFixes(*(np.ascontiguousarray(table[order, k]) for k in range(5)))


def write_gnss_csv(path: Path, fixes: GnssFixes) -> None:
    """Write `fixes` as a `gnss.csv` (with the std column when any fix has one)."""
    with_std = bool(np.isfinite(fixes.std).any())
    lines = [",".join(HEADER + (("std",) if with_std else ()))]
    for i in range(len(fixes)):
        row = f"{fixes.stamps[i]:.6f},{fixes.lat[i]:.9f},{fixes.lon[i]:.9f},{fixes.alt[i]:.4f}"
        lines.append(row + (f",{fixes.std[i]:.4f}" if with_std else ""))
    Path(path).write_text("\n".join(lines) + "\n")


def fit_anchor(
    stamps: np.ndarray, positions: np.ndarray, fixes: GnssFixes, source: str, min_spread: float = 10.0
) -> FittedAnchor | None:
    """The anchor of the frame of a drive whose sensor is at `positions` (N, 3) metres (its frame) at
    `stamps` (N,) seconds, increasing, fitted to `fixes` (module docstring). Fixes outside the
    drive's time span are left out. None with fewer than 3 fixes or a drive that spreads less than
    `min_spread` metres (its heading would be a guess)."""
    stamps, positions = np.asarray(stamps, np.float64), np.asarray(positions, np.float64)
    inside = (fixes.stamps >= stamps[0]) & (fixes.stamps <= stamps[-1]) if len(stamps) else np.zeros(0, bool)
    if np.count_nonzero(inside) < 3:
        return None
    at = np.column_stack([np.interp(fixes.stamps[inside], stamps, positions[:, k]) for k in range(3)])
    lat, lon, alt = fixes.lat[inside], fixes.lon[inside], fixes.alt[inside]
    std = fixes.std[inside]
    weight = np.where(np.isfinite(std) & (std > 0), 1.0 / np.maximum(std, 1e-3) ** 2, 1.0)
    weight = weight / weight.sum()
    plane_of = MapToWgs84(Wgs84Anchor(lat=float(np.mean(lat)), lon=float(np.mean(lon))))  # east, north metres
    east_north = plane_of.map_points(np.column_stack([lon, lat, alt]))[:, :2]
    local_mean, plane_mean = weight @ at[:, :2], weight @ east_north
    local, plane = at[:, :2] - local_mean, east_north - plane_mean
    spread = float(np.sqrt(weight @ np.sum(local**2, axis=1)))
    if spread < min_spread:
        return None
    # Planar Kabsch: the rotation angle that best turns the drive's offsets onto the fixes'.
    cross = weight @ (local[:, 0] * plane[:, 1] - local[:, 1] * plane[:, 0])
    dot = weight @ np.sum(local * plane, axis=1)
    yaw = math.atan2(cross, dot)
    rotation = yaw_rotation(yaw)[:2, :2]
    origin = plane_mean - rotation @ local_mean  # where the frame's origin lies in the plane
    residual = plane - local @ rotation.T
    lon0, lat0, _ = plane_of.lon_lat_height(origin[None])[0]
    anchor = Wgs84Anchor(
        lat=float(lat0),
        lon=float(lon0),
        alt=float(weight @ (alt - at[:, 2])),
        yaw_deg=math.degrees(yaw),
        projection="tmerc",
        source=source,
    )
    rms = float(np.sqrt(weight @ np.sum(residual**2, axis=1)))
    return FittedAnchor(anchor, rms, int(np.count_nonzero(inside)), spread)


def anchor_fields(stamps: np.ndarray, positions: np.ndarray, fixes: GnssFixes, source: str) -> dict[str, object] | None:
    """`fit_anchor`'s anchor as the fields a source's `wgs84_anchor()` returns (terra.schemas.Wgs84Anchor),
    or None where the fixes do not fix the frame."""
    fitted = fit_anchor(stamps, positions, fixes, source)
    return None if fitted is None else fitted.anchor.model_dump(mode="json")
