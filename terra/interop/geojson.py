"""The scene graph as GeoJSON (RFC 7946) in WGS84, for GIS tools (QGIS, geojson.io, web maps).

One FeatureCollection; coordinates are [lon, lat] (degrees, WGS84), with the height (anchor
alt + z, metres) as a third value on points and paths (terra.interop.geo turns map metres into
them under the map's anchor). Features, each with properties kind and id (the node's name, "p12",
"R3", "S0", "O4"):
  place    Point; terrain, and region_1 .. region_L: the id of its region on each level;
  region   the convex hull of its places (Polygon, counter-clockwise; a LineString when they
           lie on a line, a Point when fewer than 3); level (1..L), places (count);
  object   Point at the box centre; label, score, size [m, box axes], yaw (rad about +z, map frame);
  path     LineString of a plan's waypoints (`terra plan --json`, given with --path); start_place,
           goal_place (place indices), length_m, cost, terrain (per waypoint).
The collection's foreign member `terra` records the anchor and the units.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from terra.bundle import Bundle, dumps_json
from terra.errors import TerraError
from terra.graph.scene_graph import SceneGraph
from terra.interop.geo import resolve_anchor
from terra.interop.output import check_file_target, write_file
from terra.schemas import Wgs84Anchor
from terra.wgs84 import MapToWgs84

MAX_PATH_BYTES = 64 << 20


def _coordinates(lon_lat_height: np.ndarray, height: bool = True) -> list[list[float]]:
    """GeoJSON positions: [lon, lat(, height)], degrees rounded to 1e-9 (0.1 mm), heights to 1 mm."""
    return [
        [round(float(p[0]), 9), round(float(p[1]), 9), *([round(float(p[2]), 3)] if height else [])]
        for p in lon_lat_height
    ]


def _feature(geometry: dict[str, Any], **properties: Any) -> dict[str, Any]:
    return {"type": "Feature", "geometry": geometry, "properties": properties}


def _place_features(sg: SceneGraph, to_wgs84: MapToWgs84) -> list[dict[str, Any]]:
    places = sg.places
    positions = _coordinates(to_wgs84.lon_lat_height(places.position))
    region_of_place = {
        f"region_{level.level}": [f"{level.char}{int(level.id[r])}" for r in sg.place_region(level.level)]
        for level in sg.regions
    }
    return [
        _feature(
            {"type": "Point", "coordinates": positions[i]},
            kind="place",
            id=f"p{int(places.id[i])}",
            terrain=sg.terrain_classes[int(places.terrain[i])],
            **{name: ids[i] for name, ids in region_of_place.items()},
        )
        for i in range(len(places))
    ]


def _hull(points_xy: np.ndarray) -> tuple[str, np.ndarray]:
    """The convex hull of (N, 2) points as a GeoJSON geometry type and its (M, 2) vertices: a closed
    counter-clockwise ring for a Polygon, the two ends for a LineString (points on a line), their
    mean for a Point (fewer than 3, or all at one spot)."""
    from shapely.geometry import MultiPoint, Polygon
    from shapely.geometry.polygon import orient

    if len(points_xy) < 3:
        return "Point", points_xy.mean(axis=0, keepdims=True)
    hull = MultiPoint([tuple(p) for p in points_xy]).convex_hull
    if isinstance(hull, Polygon):
        return "Polygon", np.asarray(orient(hull, sign=1.0).exterior.coords)
    if hull.geom_type == "LineString":
        return "LineString", np.asarray(hull.coords)
    return "Point", points_xy.mean(axis=0, keepdims=True)


def _geometry(kind: str, vertices: np.ndarray, to_wgs84: MapToWgs84) -> dict[str, Any]:
    """The GeoJSON geometry `kind` of (M, 2) map vertices, [lon, lat] positions (no height)."""
    positions = _coordinates(to_wgs84.lon_lat_height(vertices), height=False)
    nested = {"Point": positions[0], "LineString": positions, "Polygon": [positions]}
    return {"type": kind, "coordinates": nested[kind]}


def _region_features(sg: SceneGraph, to_wgs84: MapToWgs84) -> list[dict[str, Any]]:
    features = []
    for level in sg.regions:
        place_region = sg.place_region(level.level)
        for r in range(len(level)):
            members = sg.places.position[place_region == r, :2]
            kind, vertices = _hull(members) if len(members) else ("Point", level.position[r : r + 1, :2])
            region = {"kind": "region", "id": f"{level.char}{int(level.id[r])}", "level": level.level}
            features.append(_feature(_geometry(kind, vertices, to_wgs84), **region, places=len(members)))
    return features


def _object_features(sg: SceneGraph, to_wgs84: MapToWgs84) -> list[dict[str, Any]]:
    objects = sg.objects
    centres = _coordinates(to_wgs84.lon_lat_height(objects.center))
    return [
        _feature(
            {"type": "Point", "coordinates": centres[i]},
            kind="object",
            id=f"O{int(objects.id[i])}",
            label=objects.label[i],
            score=round(float(objects.score[i]), 6),
            size=[round(float(v), 4) for v in objects.size[i]],
            yaw=round(float(objects.yaw[i]), 6),
        )
        for i in range(len(objects))
    ]


def read_plan_path(path: Path) -> dict[str, Any]:
    """The plan in `path` (`terra plan --json`) with its waypoints as an (n, 3) array (metres, map
    frame); TerraError naming the file unless it has at least two finite [x, y, z] waypoints."""
    from terra.fileio import decode_text, parse_json, read_bytes

    path = Path(path)
    doc = parse_json(decode_text(read_bytes(path, "plan file", MAX_PATH_BYTES), path), path, "plan file")
    if not isinstance(doc, dict):
        doc = {}
    try:
        points = np.asarray(doc.get("waypoints"), dtype=np.float64)
    except (TypeError, ValueError):
        points = np.zeros((0, 0))
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 2 or not np.all(np.isfinite(points)):
        raise TerraError(f"{path}: expected the JSON of `terra plan --json`, with at least two [x, y, z] waypoints")
    return {**doc, "waypoints": points}


def _path_feature(plan: dict[str, Any], to_wgs84: MapToWgs84) -> dict[str, Any]:
    keep = ("start_place", "goal_place", "length_m", "cost", "terrain")
    return _feature(
        {"type": "LineString", "coordinates": _coordinates(to_wgs84.lon_lat_height(plan["waypoints"]))},
        kind="path",
        id="path",
        **{k: plan[k] for k in keep if k in plan},
    )


def geojson_document(sg: SceneGraph, anchor: Wgs84Anchor, plan: dict[str, Any] | None = None) -> dict[str, Any]:
    """The FeatureCollection of `sg` (and the path of `plan`, as `read_plan_path` returns it) under `anchor`."""
    to_wgs84 = MapToWgs84(anchor)
    features = _place_features(sg, to_wgs84) + _region_features(sg, to_wgs84) + _object_features(sg, to_wgs84)
    if plan is not None:
        features.append(_path_feature(plan, to_wgs84))
    return {
        "type": "FeatureCollection",
        "features": features,
        "terra": {
            "wgs84_anchor": anchor.model_dump(mode="json"),
            "units": {
                "coordinates": "lon, lat: degrees WGS84; height: m (anchor alt + z)",
                "size": "m",
                "yaw": "rad about +z, map frame",
            },
        },
    }


def export_geojson(
    bundle: Bundle, out: Path, overwrite: bool = False, anchor: str | None = None, path: Path | None = None
) -> dict[str, Any]:
    """Write the bundle's scene graph (and the plan in file `path`) as GeoJSON to `out`; returns a
    summary. TerraError, nothing written, without an anchor (`anchor`, the --anchor text, or the
    manifest's) or for an unreadable plan file."""
    from terra.graph.storage import load_scene_graph

    georef = resolve_anchor(bundle, anchor)
    check_file_target(out, overwrite)
    plan = read_plan_path(path) if path is not None else None
    doc = geojson_document(load_scene_graph(bundle), georef, plan)
    write_file(out, dumps_json(doc).encode(), overwrite)
    kinds = [f["properties"]["kind"] for f in doc["features"]]
    return {
        "format": "geojson",
        "out": str(out),
        "places": kinds.count("place"),
        "regions": kinds.count("region"),
        "objects": kinds.count("object"),
        "path": kinds.count("path"),
        "anchor": georef.source or "manifest",
    }
