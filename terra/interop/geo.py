"""Map-frame metres to WGS84: the anchor that ties the map frame to the Earth, and the transform.

The map frame is a local metric frame: x, y horizontal, z up. An anchor (terra.schemas.Wgs84Anchor)
gives the WGS84 latitude, longitude and height of its origin and the heading of its +x axis
(`yaw_deg`, counter-clockwise from east). A map point (x, y, z) is first turned into east/north
metres of the anchor's plane, (e, n) = Rz(yaw) (x, y), then unprojected with pyproj:
- 'tmerc': a transverse Mercator on the WGS84 ellipsoid centred on the anchor, scale 1 there,
  so the map's metres are ground metres around the origin;
- 'kitti-mercator': the KITTI devkit's Mercator on a sphere of the WGS84 equatorial radius,
  scaled by cos(anchor latitude); the map's (e, n) are offsets from the anchor's projected point.
Height: anchor alt + z.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from terra.errors import TerraError
from terra.schemas import Wgs84Anchor

if TYPE_CHECKING:
    from terra.bundle import Bundle

ANCHOR_FORMAT = "LAT,LON[,ALT[,YAW_DEG]]"
EARTH_RADIUS = 6378137.0  # metres, the KITTI devkit's sphere (the WGS84 equatorial radius)


def parse_anchor(text: str) -> Wgs84Anchor:
    """The anchor of `--anchor LAT,LON[,ALT[,YAW_DEG]]` (degrees, metres); TerraError naming what is wrong."""
    words = [w.strip() for w in text.split(",")]
    try:
        numbers = [float(w) for w in words]
    except ValueError:
        raise TerraError(f"--anchor {text!r}: expected numbers {ANCHOR_FORMAT}") from None
    if not 2 <= len(numbers) <= 4 or not all(math.isfinite(v) for v in numbers):
        raise TerraError(f"--anchor {text!r}: expected 2 to 4 finite numbers {ANCHOR_FORMAT}")
    lat, lon, alt, yaw = [*numbers, 0.0, 0.0][:4]
    if abs(lat) >= 90.0 or abs(lon) > 180.0:
        raise TerraError(f"--anchor {text!r}: latitude {lat} / longitude {lon} out of range (degrees)")
    return Wgs84Anchor(lat=lat, lon=lon, alt=alt, yaw_deg=yaw, source="--anchor")


def bundle_anchor(bundle: Bundle) -> Wgs84Anchor | None:
    """The anchor the bundle's manifest records (components.map.wgs84_anchor), or None."""
    info = bundle.model.components.map
    return None if info is None else info.wgs84_anchor


def resolve_anchor(bundle: Bundle, text: str | None) -> Wgs84Anchor:
    """`--anchor` when given, else the bundle's; TerraError when neither is known."""
    if text is not None:
        return parse_anchor(text)
    anchor = bundle_anchor(bundle)
    if anchor is None:
        raise TerraError(
            f"{bundle.path}: the map has no WGS84 anchor (manifest.json components.map.wgs84_anchor); "
            f"give one with --anchor {ANCHOR_FORMAT}"
        )
    return anchor


@dataclass
class MapToWgs84:
    """Map-frame points (metres) to WGS84 [lon, lat, height] under one anchor (module docstring)."""

    anchor: Wgs84Anchor

    def __post_init__(self) -> None:
        try:
            from pyproj import CRS, Transformer
        except ImportError:
            raise TerraError("the geojson export needs pyproj: pip install 'terra-3dsg[geo]'") from None

        a = self.anchor
        if a.projection == "tmerc":
            plane = f"+proj=tmerc +lat_0={a.lat!r} +lon_0={a.lon!r} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m"
        else:
            scale = math.cos(math.radians(a.lat))
            plane = f"+proj=merc +R={EARTH_RADIUS!r} +k_0={scale!r} +lon_0=0 +x_0=0 +y_0=0 +units=m"
        crs = CRS.from_proj4(plane)
        # The sphere's latitudes are taken as WGS84 ones, as the devkit does: go through the plane's
        # own geographic CRS, whose degrees are then read as WGS84 degrees.
        self._to_degrees = Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True)
        origin = Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True).transform(a.lon, a.lat)
        self._origin = (float(origin[0]), float(origin[1]))

    def lon_lat_height(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) [lon, lat, height] (degrees, metres) of (N, 2 or 3) map points (metres); height
        is the anchor's alt + z (alt when the points have no z)."""
        points = np.atleast_2d(np.asarray(points, dtype=np.float64))
        yaw = math.radians(self.anchor.yaw_deg)
        c, s = math.cos(yaw), math.sin(yaw)
        east = self._origin[0] + c * points[:, 0] - s * points[:, 1]
        north = self._origin[1] + s * points[:, 0] + c * points[:, 1]
        lon, lat = self._to_degrees.transform(east, north)
        z = points[:, 2] if points.shape[1] > 2 else np.zeros(len(points))
        return np.stack([np.asarray(lon, np.float64), np.asarray(lat, np.float64), self.anchor.alt + z], axis=1)
