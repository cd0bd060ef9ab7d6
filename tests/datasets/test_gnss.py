"""GNSS fixes and the WGS84 anchor of a drive's frame (terra/datasets/gnss.py, terra/wgs84.py).

Fixes are made independently with pyproj's geodesic (a point `distance` metres from a known origin at
an azimuth), not with the transverse Mercator the code uses; over a few hundred metres the two agree
to millimetres."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from pyproj import Geod

from terra.datasets.gnss import GnssFixes, fit_anchor, read_gnss_csv, write_gnss_csv
from terra.errors import TerraError
from terra.geometry import make_pose, transform_points, yaw_rotation
from terra.schemas import Wgs84Anchor
from terra.wgs84 import MapToWgs84, pose_between

ORIGIN = (47.3769, 8.5417, 408.0)  # lat, lon degrees; alt metres
GEOD = Geod(ellps="WGS84")


def loop_drive(n: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """(stamps (n,) s, positions (n, 3) metres) of a 160 x 90 m loop in a frame of its own, rising 3 m."""
    t = np.linspace(0.0, 2 * math.pi, n)
    return t * 60.0, np.column_stack([80 * np.cos(t), 45 * np.sin(t), 3 * t / (2 * math.pi)])


def fixes_of(positions: np.ndarray, stamps: np.ndarray, yaw_deg: float, noise: float = 0.0, seed: int = 0) -> GnssFixes:
    """Fixes of `positions` in a frame whose origin is ORIGIN and whose +x points `yaw_deg` counter-clockwise
    from east, by geodesic forward steps (azimuth clockwise from north), with white noise of `noise` metres."""
    rng = np.random.default_rng(seed)
    turned = positions[:, :2] @ yaw_rotation(math.radians(yaw_deg))[:2, :2].T + rng.normal(0, noise, (len(stamps), 2))
    east, north = turned[:, 0], turned[:, 1]
    azimuth = np.degrees(np.arctan2(east, north))
    lon, lat, _ = GEOD.fwd(np.full(len(east), ORIGIN[1]), np.full(len(east), ORIGIN[0]), azimuth, np.hypot(east, north))
    alt = ORIGIN[2] + positions[:, 2]
    return GnssFixes(stamps, np.asarray(lat), np.asarray(lon), alt, np.full(len(stamps), noise or np.nan))


def test_an_exact_drive_gives_back_its_anchor():
    stamps, positions = loop_drive()
    fitted = fit_anchor(stamps, positions, fixes_of(positions, stamps, yaw_deg=30.0), "test")
    assert fitted is not None
    a = fitted.anchor
    north, east = (a.lat - ORIGIN[0]) * 111_200, (a.lon - ORIGIN[1]) * 111_200 * math.cos(math.radians(ORIGIN[0]))
    assert math.hypot(north, east) < 0.01 and abs(a.alt - ORIGIN[2]) < 1e-6
    assert abs(a.yaw_deg - 30.0) < 0.001 and fitted.rms < 0.01 and fitted.fixes == 300


def test_two_metre_noise_averages_out_over_a_drive():
    stamps, positions = loop_drive()
    fitted = fit_anchor(stamps, positions, fixes_of(positions, stamps, yaw_deg=-75.0, noise=2.0), "test")
    assert fitted is not None
    on_earth = MapToWgs84(fitted.anchor)
    truth = MapToWgs84(Wgs84Anchor(lat=ORIGIN[0], lon=ORIGIN[1], alt=ORIGIN[2], yaw_deg=-75.0))
    error = on_earth.lon_lat_height(positions) - truth.lon_lat_height(positions)
    metres = np.hypot(error[:, 0] * 111_200 * math.cos(math.radians(ORIGIN[0])), error[:, 1] * 111_200)
    assert metres.max() < 0.6 and abs(fitted.anchor.yaw_deg + 75.0) < 0.5
    assert 2.0 < fitted.rms < 3.5  # the fixes' own scatter: sqrt(2) x 2 m


def test_map_points_invert_lon_lat_height():
    anchor = Wgs84Anchor(lat=ORIGIN[0], lon=ORIGIN[1], alt=ORIGIN[2], yaw_deg=12.0)
    points = np.array([[0.0, 0.0, 0.0], [250.0, -40.0, 3.0], [-120.0, 310.0, -2.0]])
    to_earth = MapToWgs84(anchor)
    assert np.allclose(to_earth.map_points(to_earth.lon_lat_height(points)), points, atol=1e-6)


def test_the_pose_between_two_anchored_frames_moves_one_drive_onto_the_other():
    stamps, positions = loop_drive()
    map_anchor = Wgs84Anchor(lat=ORIGIN[0], lon=ORIGIN[1], alt=ORIGIN[2], yaw_deg=0.0)
    T_map_session = make_pose(yaw_rotation(math.radians(90.0)), [50.0, -10.0, 1.0])
    # The session's frame on the Earth, from the map's: its origin and heading through WGS84.
    lon, lat, alt = MapToWgs84(map_anchor).lon_lat_height(T_map_session[:3, 3][None])[0]
    session_anchor = Wgs84Anchor(lat=lat, lon=lon, alt=alt, yaw_deg=90.0)
    found = pose_between(map_anchor, session_anchor)
    assert np.abs(transform_points(found, positions) - transform_points(T_map_session, positions)).max() < 0.01


def test_a_drive_that_stays_put_or_has_too_few_fixes_gives_no_anchor():
    stamps, positions = loop_drive()
    still = np.zeros_like(positions) + np.random.default_rng(1).normal(0, 0.5, positions.shape)
    assert fit_anchor(stamps, still, fixes_of(still, stamps, 0.0), "test") is None
    few = fixes_of(positions[:2], stamps[:2], 0.0)
    assert fit_anchor(stamps, positions, few, "test") is None


def test_gnss_csv_round_trips_and_bad_files_name_the_line(tmp_path):
    stamps, positions = loop_drive(20)
    fixes = fixes_of(positions, stamps, 10.0, noise=1.5)
    path = tmp_path / "gnss.csv"
    write_gnss_csv(path, fixes)
    back = read_gnss_csv(path)
    assert np.allclose(back.lat, fixes.lat, atol=1e-9) and np.allclose(back.std, fixes.std)
    path.write_text("stamp,lat,lon,alt\n0.0,47.0,8.0,400\n1.0,47.0,eight,400\n")
    with pytest.raises(TerraError, match=r"gnss.csv:3: expected 4 numbers"):
        read_gnss_csv(path)
    path.write_text("stamp,lat,lon,alt\n0.0,97.0,8.0,400\n")
    with pytest.raises(TerraError, match=r"gnss.csv:2: latitude 97.0"):
        read_gnss_csv(path)
    path.write_text("time,latitude,longitude\n")
    with pytest.raises(TerraError, match="expected the header"):
        read_gnss_csv(path)


@pytest.mark.parametrize("store", ["ros2", "ros1"])
def test_navsatfix_messages_built_by_rosbags_become_fixes(store):
    """Messages of rosbags' own types: a fix with a diagonal covariance, a fix without one, no fix, NaN."""
    from rosbags.typesys import Stores, get_typestore

    from terra.datasets.ros.messages import MessageFactory
    from terra.datasets.ros.navsat import fix_row

    types = get_typestore(Stores.ROS2_HUMBLE if store == "ros2" else Stores.ROS1_NOETIC)
    factory = MessageFactory(types, store == "ros1")
    fix = factory.navsatfix(12_500_000_000, "gnss", 47.5, 8.25, 410.0, 1.5)
    assert fix_row(fix) == (12.5, 47.5, 8.25, 410.0, 1.5)
    unknown = factory.navsatfix(13_000_000_000, "gnss", 47.5, 8.25, 410.0, float("nan"))
    row = fix_row(unknown)
    assert row is not None and row[0] == 13.0 and math.isnan(row[4])
    status = types.types["sensor_msgs/msg/NavSatStatus"]
    assert fix_row(replace(fix, status=status(status=-1, service=1))) is None  # no fix yet
    assert fix_row(replace(fix, latitude=float("nan"))) is None


REAL_BAG = Path(__file__).resolve().parents[1] / "data" / "ros" / "husky_navsat_fix.bag"


def _real_messages(topic: str) -> list:
    """The messages of `topic` in the real Husky bag (tests/data/README.md), read by rosbags directly."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    with AnyReader([REAL_BAG], default_typestore=get_typestore(Stores.ROS1_NOETIC)) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        return [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=connections)]


def test_a_real_receivers_fixes_and_the_anchor_of_its_wheel_odometry():
    """A real recording (a Husky's /fix, 989 SBAS fixes at 2.5 Hz, and its wheel odometry, 359 m in 395 s):
    every fix read as recorded, and the frame of the odometry anchored where the fixes put it, checked by
    geodesic distances (pyproj), not by the transverse Mercator the fit uses."""
    from terra.datasets.ros.bag import Bag
    from terra.datasets.ros.navsat import choose_gnss, read_fixes

    bag = Bag(REAL_BAG)
    topic = choose_gnss(bag, None)
    assert topic == "/fix"
    fixes, left_out = read_fixes(bag, topic)
    messages = _real_messages("/fix")
    assert left_out == 0 and len(fixes) == len(messages) == 989
    stamps = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in messages])
    np.testing.assert_array_equal(fixes.stamps, stamps)  # recorded in stamp order
    np.testing.assert_array_equal(fixes.lat, [m.latitude for m in messages])
    np.testing.assert_array_equal(fixes.lon, [m.longitude for m in messages])
    np.testing.assert_array_equal(fixes.alt, [m.altitude for m in messages])
    # status 1 (SBAS), covariance type 1 (approximated): std from the east and north variances (0.8 to 1.7 m)
    assert {int(m.status.status) for m in messages} == {1} == {int(m.position_covariance_type) for m in messages}
    east_north = np.array([[m.position_covariance[0], m.position_covariance[4]] for m in messages])
    np.testing.assert_allclose(fixes.std, np.sqrt(east_north.mean(axis=1)))
    assert fixes.std.min() >= 0.8 and fixes.std.max() <= 1.7

    odometry = _real_messages("/husky_velocity_controller/odom")
    when = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in odometry])
    where = np.array([[m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z] for m in odometry])
    first_minute = when <= when[0] + 60.0  # wheel odometry drifts: over the whole drive the fit is worse (6.8 m)
    fitted = fit_anchor(when[first_minute], where[first_minute], fixes, "test")
    assert fitted is not None and fitted.fixes == 150 and fitted.spread > 15.0
    inside = (fixes.stamps >= when[0]) & (fixes.stamps <= when[first_minute][-1])
    at = np.column_stack([np.interp(fixes.stamps[inside], when, where[:, k]) for k in range(3)])
    lon, lat, _ = MapToWgs84(fitted.anchor).lon_lat_height(at).T
    _, _, metres = GEOD.inv(lon, lat, fixes.lon[inside], fixes.lat[inside])
    weight = 1.0 / fixes.std[inside] ** 2  # the fit weighs each fix by its variance
    assert math.sqrt(np.sum(weight * metres**2) / weight.sum()) == pytest.approx(fitted.rms, abs=0.005)
    assert fitted.rms < 2.5  # the odometry and the receiver agree to about two fix sigmas over that minute
