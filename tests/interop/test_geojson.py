"""`terra export --format geojson`: places, regions, objects and a planned path in WGS84. The
coordinates are checked against pyproj's geodesic (Geod) computed here from the anchor, the
KITTI anchor against the devkit's Mercator formulas written out here, the file's structure
against RFC 7946 (FeatureCollection, [lon, lat] order, closed counter-clockwise rings)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from terra.bundle import Bundle, BundleWriter
from terra.cli import run
from terra.graph.scene_graph import Objects, Places, RegionLevel, SceneGraph
from terra.graph.storage import load_scene_graph
from terra.interop.geojson import geojson_document
from terra.mapping.state import wgs84_anchor
from terra.schemas import Wgs84Anchor
from tests.graph.fixtures import copy_bundle

pyproj = pytest.importorskip("pyproj")
GEOD = pyproj.Geod(ellps="WGS84")


def hand_graph() -> SceneGraph:
    """Six places: a 10 m square at the origin (region R0), two at 100 m east (R1), and their
    level-2 region S0; one object 100 m east."""
    position = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 1], [0, 10, 1], [100, 0, 2], [100, 5, 2]], dtype=np.float64)
    n = len(position)
    places = Places(position, np.zeros(n, np.int64), np.ones(n), np.zeros((n, 2), np.float32), np.arange(n) + 10)
    level1 = RegionLevel(
        1,
        np.array([[5, 5, 0.5], [100, 2.5, 2]]),
        np.zeros((2, 2), np.float32),
        np.array([0, 0, 0, 0, 1, 1]),
        np.array([0, 7]),
    )
    level2 = RegionLevel(2, np.array([[50, 3, 1]]), np.zeros((1, 2), np.float32), np.array([0, 0]))
    objects = Objects(
        center=np.array([[100.0, 0.0, 3.0]]),
        size=np.array([[1.0, 2.0, 0.5]]),
        yaw=np.array([0.25]),
        label=["bench"],
        score=np.array([0.5], np.float32),
        point_count=np.array([9]),
        place=np.array([4]),
    )
    return SceneGraph(
        ["grass"],
        np.zeros((1, 2), np.float32),
        places,
        np.array([[0, 1]]),
        np.array([10.0]),
        np.array([0]),
        regions=[level1, level2],
        objects=objects,
    )


def features_of(doc: dict, kind: str) -> list[dict]:
    return [f for f in doc["features"] if f["properties"]["kind"] == kind]


def azimuth_distance(anchor: Wgs84Anchor, lon_lat: list[float]) -> tuple[float, float]:
    azimuth, _, distance = GEOD.inv(anchor.lon, anchor.lat, lon_lat[0], lon_lat[1])
    return azimuth % 360.0, distance


def test_map_x_points_east_at_yaw_0_and_north_at_yaw_90():
    graph = hand_graph()
    for yaw, bearing in ((0.0, 90.0), (90.0, 0.0), (-30.0, 120.0)):
        anchor = Wgs84Anchor(lat=47.0, lon=8.0, alt=400.0, yaw_deg=yaw)
        doc = geojson_document(graph, anchor)
        east = features_of(doc, "place")[4]["geometry"]["coordinates"]
        azimuth, distance = azimuth_distance(anchor, east)
        assert distance == pytest.approx(100.0, abs=1e-3)
        assert azimuth == pytest.approx(bearing, abs=1e-3)
        assert east[2] == pytest.approx(402.0)
        # pyproj's forward geodesic from the anchor lands on the same point (1e-8 deg ~ 1 mm).
        lon, lat, _ = GEOD.fwd(anchor.lon, anchor.lat, bearing, 100.0)
        assert east[:2] == pytest.approx([lon, lat], abs=1e-8)
        origin = features_of(doc, "place")[0]["geometry"]["coordinates"]
        assert origin == pytest.approx([8.0, 47.0, 400.0])


def test_places_regions_and_objects_carry_ids_and_hulls():
    doc = geojson_document(hand_graph(), Wgs84Anchor(lat=-33.9, lon=151.2))
    assert doc["type"] == "FeatureCollection" and all(f["type"] == "Feature" for f in doc["features"])
    places = features_of(doc, "place")
    assert [p["properties"]["id"] for p in places] == [f"p{i}" for i in range(10, 16)]
    assert places[0]["properties"] == {
        "kind": "place",
        "id": "p10",
        "terrain": "grass",
        "region_1": "R0",
        "region_2": "S0",
    }
    assert places[5]["properties"]["region_1"] == "R7"
    regions = {r["properties"]["id"]: r for r in features_of(doc, "region")}
    square, pair, top = regions["R0"], regions["R7"], regions["S0"]
    assert square["geometry"]["type"] == "Polygon" and square["properties"]["places"] == 4
    ring = np.array(square["geometry"]["coordinates"][0])
    assert len(ring) == 5 and np.array_equal(ring[0], ring[-1])
    # RFC 7946: exterior rings counter-clockwise (positive shoelace area in lon/lat).
    area = 0.5 * np.sum(ring[:-1, 0] * ring[1:, 1] - ring[1:, 0] * ring[:-1, 1])
    assert area > 0
    corners = {tuple(np.round(c, 9)) for c in ring[:-1]}
    expected = {tuple(np.round(p["geometry"]["coordinates"][:2], 9)) for p in places[:4]}
    assert corners == expected
    assert pair["geometry"]["type"] == "Point" and pair["properties"] == {
        "kind": "region",
        "id": "R7",
        "level": 1,
        "places": 2,
    }
    assert top["geometry"]["type"] == "Polygon" and top["properties"]["places"] == 6
    (obj,) = features_of(doc, "object")
    assert obj["properties"] == {
        "kind": "object",
        "id": "O0",
        "label": "bench",
        "score": 0.5,
        "size": [1.0, 2.0, 0.5],
        "yaw": 0.25,
    }
    assert obj["geometry"]["coordinates"][0] > 151.2 and obj["geometry"]["coordinates"][1] < 0  # [lon, lat]


def test_kitti_anchor_follows_the_devkit_mercator():
    lat0, lon0 = 49.011, 8.4237
    anchor = Wgs84Anchor(lat=lat0, lon=lon0, alt=112.0, projection="kitti-mercator")
    doc = geojson_document(hand_graph(), anchor)
    # The devkit: x = s R lon, y = s R ln tan((90 + lat) / 2), s = cos(lat0), R = 6378137 m.
    s, radius = math.cos(math.radians(lat0)), 6378137.0
    x0 = s * radius * math.radians(lon0)
    y0 = s * radius * math.log(math.tan(math.radians(90.0 + lat0) / 2.0))
    lon = math.degrees((x0 + 100.0) / (s * radius))
    lat = 2.0 * math.degrees(math.atan(math.exp((y0 + 5.0) / (s * radius)))) - 90.0
    assert features_of(doc, "place")[5]["geometry"]["coordinates"] == pytest.approx([lon, lat, 114.0], abs=1e-9)


# ------------------------------------------------------------------------------------- the CLI
def test_export_writes_a_feature_collection_of_the_bundle(interop_bundle, tmp_path):
    out = tmp_path / "tiny.geojson"
    args = ["export", str(interop_bundle.path), "-f", "geojson", "-o", str(out), "--anchor", "47.0,8.0,400,30"]
    assert run(args) == 0
    doc = json.loads(out.read_text())
    graph = load_scene_graph(interop_bundle)
    assert doc["type"] == "FeatureCollection"
    assert doc["terra"]["wgs84_anchor"]["yaw_deg"] == 30.0
    kinds = [f["properties"]["kind"] for f in doc["features"]]
    assert kinds.count("place") == len(graph.places) and kinds.count("object") == len(graph.objects) == 3
    assert kinds.count("region") == sum(len(level) for level in graph.regions)
    anchor = Wgs84Anchor(lat=47.0, lon=8.0, alt=400.0, yaw_deg=30.0)
    for feature, position in zip(features_of(doc, "place"), graph.places.position):
        assert feature["geometry"]["type"] == "Point"
        lon, lat, height = feature["geometry"]["coordinates"]
        assert 7.9 < lon < 8.1 and 46.9 < lat < 47.1  # [lon, lat], not [lat, lon]
        assert height == pytest.approx(400.0 + position[2], abs=1e-3)
        azimuth, distance = azimuth_distance(anchor, [lon, lat])
        assert distance == pytest.approx(np.hypot(*position[:2]), abs=1e-3)
        if distance > 1.0:
            bearing = (90.0 - 30.0 - math.degrees(math.atan2(position[1], position[0]))) % 360.0
            assert min(abs(azimuth - bearing), 360.0 - abs(azimuth - bearing)) < 1e-3
    for feature in features_of(doc, "region"):
        assert feature["geometry"]["type"] in ("Polygon", "LineString", "Point")


def test_export_refuses_without_an_anchor_and_writes_nothing(interop_bundle, tmp_path, capsys):
    out = tmp_path / "tiny.geojson"
    capsys.readouterr()
    assert run(["export", str(interop_bundle.path), "-f", "geojson", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "wgs84_anchor" in err[0] and "--anchor" in err[0]
    assert not out.exists()
    for bad in ("47.0", "47,x", "95,8", "1,2,3,4,5"):
        assert run(["export", str(interop_bundle.path), "-f", "geojson", "-o", str(out), "--anchor", bad]) == 2
    assert not out.exists()
    assert run(["export", str(interop_bundle.path), "-f", "ply", "-o", str(tmp_path / "x.ply"), "--anchor", "1,2"]) == 2


def test_export_reads_the_anchor_the_manifest_records(interop_bundle, tmp_path):
    path = copy_bundle(interop_bundle, tmp_path / "anchored.terra")
    with BundleWriter(path, base=Bundle(path)) as writer:
        writer.update_component("map", wgs84_anchor={"lat": 10.0, "lon": 20.0, "alt": 5.0, "source": "test"})
    # The next version of the map (an append, a joined or live session) keeps it.
    assert wgs84_anchor(Bundle(path)) == {
        "lat": 10.0,
        "lon": 20.0,
        "alt": 5.0,
        "yaw_deg": 0.0,
        "projection": "tmerc",
        "source": "test",
    }
    assert wgs84_anchor(None, object()) is None
    out = tmp_path / "anchored.geojson"
    assert run(["export", str(path), "-f", "geojson", "-o", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["terra"]["wgs84_anchor"]["source"] == "test"
    lon, lat, _ = features_of(doc, "place")[0]["geometry"]["coordinates"]
    assert 19.9 < lon < 20.1 and 9.9 < lat < 10.1


def test_export_adds_a_planned_path_as_a_line_string(interop_bundle, tmp_path, capsys):
    graph = load_scene_graph(interop_bundle)
    capsys.readouterr()
    plan_args = ["plan", str(interop_bundle.path), "--from-node", "0", "--to-node", str(len(graph.places) - 1)]
    assert run([*plan_args, "--json"]) == 0
    plan = json.loads(capsys.readouterr().out)
    plan_file = tmp_path / "plan.json"
    plan_file.write_text(json.dumps(plan))
    out = tmp_path / "path.geojson"
    args = ["export", str(interop_bundle.path), "-f", "geojson", "-o", str(out), "--anchor", "47,8", "--path"]
    assert run([*args, str(plan_file)]) == 0
    (path,) = features_of(json.loads(out.read_text()), "path")
    assert path["geometry"]["type"] == "LineString"
    line = path["geometry"]["coordinates"]
    assert len(line) == len(plan["waypoints"]) >= 2
    assert path["properties"]["length_m"] == plan["length_m"]
    anchor = Wgs84Anchor(lat=47.0, lon=8.0)
    for (lon, lat, height), (x, y, z) in zip(line, plan["waypoints"]):
        assert azimuth_distance(anchor, [lon, lat])[1] == pytest.approx(math.hypot(x, y), abs=1e-3)
        assert height == pytest.approx(z, abs=1e-3)
    # Geodesic length of the line = the plan's horizontal length (metres on the ground).
    horizontal = np.sum(np.hypot(*np.diff(np.array(plan["waypoints"])[:, :2], axis=0).T))
    assert GEOD.line_length([p[0] for p in line], [p[1] for p in line]) == pytest.approx(horizontal, rel=1e-4)
    (tmp_path / "bad.json").write_text('{"waypoints": [[0, 0, 0]]}')
    assert run([*args[:-1], "--overwrite", "--path", str(tmp_path / "bad.json")]) == 2


def test_a_graph_without_objects_or_regions_has_only_places():
    graph = hand_graph()
    graph.objects, graph.regions = Objects(), []
    doc = geojson_document(graph, Wgs84Anchor(lat=0.0, lon=0.0))
    assert [f["properties"]["kind"] for f in doc["features"]] == ["place"] * 6
    assert "region_1" not in doc["features"][0]["properties"]


def test_export_is_deterministic_and_refuses_to_overwrite(interop_bundle, tmp_path, capsys):
    out = tmp_path / "a.geojson"
    args = ["export", str(interop_bundle.path), "-f", "geojson", "-o", str(out), "--anchor", "47,8"]
    assert run(args) == 0
    first = out.read_bytes()
    capsys.readouterr()
    assert run(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists" in err[0] and "--overwrite" in err[0]
    assert run([*args, "--overwrite"]) == 0
    assert out.read_bytes() == first


def test_a_region_of_places_on_a_line_is_a_line_string():
    graph = hand_graph()
    graph.places.position[:4] = [[0, 0, 0], [5, 0, 0], [10, 0, 0], [2, 0, 0]]
    doc = geojson_document(graph, Wgs84Anchor(lat=47.0, lon=8.0))
    line = next(f for f in features_of(doc, "region") if f["properties"]["id"] == "R0")
    assert line["geometry"]["type"] == "LineString" and len(line["geometry"]["coordinates"]) == 2
    ends = sorted(azimuth_distance(Wgs84Anchor(lat=47.0, lon=8.0), p)[1] for p in line["geometry"]["coordinates"])
    assert ends == pytest.approx([0.0, 10.0], abs=1e-3)
