"""Map-frame metres to WGS84 and back, under the anchor that ties the map frame to the Earth.

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

import numpy as np

from terra.errors import TerraError
from terra.geometry import make_pose, yaw_rotation
from terra.schemas import Wgs84Anchor

EARTH_RADIUS = 6378137.0  # metres, the KITTI devkit's sphere (the WGS84 equatorial radius)


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
        self._to_plane = Transformer.from_crs(crs.geodetic_crs, crs, always_xy=True)
        origin = self._to_plane.transform(a.lon, a.lat)
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

    def map_points(self, lon_lat_height: np.ndarray) -> np.ndarray:
        """(N, 3) map points (metres) of (N, 3) [lon, lat, height] (degrees, metres): the inverse of
        `lon_lat_height`."""
        lon_lat_height = np.atleast_2d(np.asarray(lon_lat_height, dtype=np.float64))
        east, north = self._to_plane.transform(lon_lat_height[:, 0], lon_lat_height[:, 1])
        east = np.asarray(east, np.float64) - self._origin[0]
        north = np.asarray(north, np.float64) - self._origin[1]
        yaw = math.radians(self.anchor.yaw_deg)
        c, s = math.cos(yaw), math.sin(yaw)
        return np.stack([c * east + s * north, -s * east + c * north, lon_lat_height[:, 2] - self.anchor.alt], axis=1)


def pose_between(map_anchor: Wgs84Anchor, session_anchor: Wgs84Anchor) -> np.ndarray:
    """T_map_session (4x4, map <- session) of two frames anchored on the Earth: the session's origin
    and a point 100 m along its +x, through WGS84, into the map frame (a turn about +z only: both
    frames are level)."""
    degrees = MapToWgs84(session_anchor).lon_lat_height(np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]]))
    origin, ahead = MapToWgs84(map_anchor).map_points(degrees)
    heading = ahead[:2] - origin[:2]
    return make_pose(yaw_rotation(math.atan2(heading[1], heading[0])), origin)
