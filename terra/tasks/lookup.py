"""Node and region lookups on the scene graph: what a place, region or object is, and where a point
of the map falls (its nearest place and the regions above it).

Nodes are named by their stable ids (terra.graph.ids) as spark_dsg NodeSymbols, either numerically
(ord(char) << 56 | id, as in graph/scene_graph.json) or in short form: "p12" the place of id 12,
"R3" region 3 of level 1, "S0" region 0 of level 2 (then "T", "U", ...), "O4" object 4, "Z0" the
root. An answer gives each node's id as its name and its `index` (position in the graph's arrays,
which changes with every build). Positions are metres, map frame.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from terra.errors import TerraError
from terra.graph.scene_graph import EDGE_BRIDGE, EDGE_CROSS_TERRAIN, EDGE_GVD, EDGE_LEVEL_ROUTE, SceneGraph


class UnknownNode(TerraError):
    """A node, region or place that the scene graph does not hold."""


_KIND = {EDGE_GVD: "gvd", EDGE_CROSS_TERRAIN: "cross_terrain", EDGE_BRIDGE: "bridge", EDGE_LEVEL_ROUTE: "level_route"}
_SHORT = re.compile(r"^([A-Za-z])([0-9]{1,18})$", re.ASCII)  # ASCII digits: '²' is a digit to str.isdigit
_NUMERIC = re.compile(r"^[0-9]{1,20}$", re.ASCII)  # a spark_dsg id is an unsigned 64-bit integer
MAX_COORDINATE = 1.0e7  # metres: a map frame spans at most a few hundred km; farther is a typo or overflow


def _r(values: Any) -> list[float]:
    return [round(float(v), 4) for v in values]


def node_name(char: str, index: int | np.integer) -> str:
    return f"{char}{int(index)}"


def region_name(level: int, index: int) -> str:
    """Short name of region `index` of `level` (1-based): 'R', 'S', ... as in graph/storage.py."""
    return node_name(chr(ord("R") + level - 1), index)


def parse_node(ref: str | int) -> tuple[str, int]:
    """(char, id) of a node reference: short form ("p12") or a numeric NodeSymbol."""
    text = str(ref).strip()
    match = _SHORT.match(text)
    if match:
        return match.group(1), int(match.group(2))
    if _NUMERIC.match(text) and int(text) < 1 << 64:
        value = int(text)
        return chr(value >> 56), value & ((1 << 56) - 1)
    shown = text if len(text) <= 40 else f"{text[:40]}... ({len(text)} characters)"
    raise TerraError(
        f"node {shown!r}: expected a short name such as p12 (place), R3 (region), O0 (object) "
        "or a numeric spark_dsg id (an unsigned 64-bit integer)"
    )


def _index(ids: np.ndarray, node_id: int) -> int | None:
    """The index of the node of id `node_id` among `ids`, None when there is none."""
    if not 0 <= node_id < 1 << 63:
        return None
    found = np.flatnonzero(ids == node_id)
    return int(found[0]) if len(found) else None


def _id_range(ids: np.ndarray) -> str:
    return f"ids {int(ids.min())}..{int(ids.max())}" if len(ids) else "no ids"


def _ancestors(graph: SceneGraph, place: int) -> list[dict[str, Any]]:
    """The regions above a place (index), level 1 upwards."""
    out = []
    for level in range(1, len(graph.regions) + 1):
        index = int(graph.place_region(level)[place])
        out.append({"id": region_name(level, int(graph.regions[level - 1].id[index])), "level": level, "index": index})
    return out


@dataclass
class NodeInfo:
    """One scene-graph node as JSON-ready facts (`fields` depend on the kind)."""

    id: str
    kind: str
    fields: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        return {"id": self.id, "kind": self.kind, **self.fields}


def place_info(graph: SceneGraph, place: int) -> NodeInfo:
    """The place of index `place` (see `node_info` for ids)."""
    if not 0 <= place < len(graph.places):
        raise UnknownNode(f"place index {place} does not exist; the graph has places 0..{len(graph.places) - 1}")
    ids = graph.places.id
    edges = graph.place_edges
    mine = (
        np.flatnonzero((edges[:, 0] == place) | (edges[:, 1] == place)) if len(edges) else np.zeros(0, dtype=np.int64)
    )
    neighbours = [
        {
            "place": int(ids[edges[e, 1] if edges[e, 0] == place else edges[e, 0]]),
            "weight": round(float(graph.place_edge_weight[e]), 4),
            "kind": _KIND.get(int(graph.place_edge_kind[e]), ""),
        }
        for e in mine
    ]
    mine_objects = np.flatnonzero(np.asarray(graph.objects.place) == place)
    objects = [node_name("O", graph.objects.id[o]) for o in mine_objects]
    return NodeInfo(
        node_name("p", ids[place]),
        "place",
        {
            "index": place,
            "position": _r(graph.places.position[place]),
            "terrain": graph.terrain_classes[int(graph.places.terrain[place])],
            "clearance": round(float(graph.places.clearance[place]), 4),
            "room": _room(graph, place),
            "neighbors": neighbours,
            "regions": _ancestors(graph, place),
            "objects": objects,
        },
    )


def _room(graph: SceneGraph, place: int) -> float | None:
    """Metres from the place to the nearest obstacle (terra.graph.room), None where not recorded."""
    room = float(np.asarray(graph.places.room)[place])
    return round(room, 4) if np.isfinite(room) else None


def region_info(graph: SceneGraph, level: int, region: int) -> NodeInfo:
    """The region of id `region` at `level` (1-based)."""
    if not 1 <= level <= len(graph.regions):
        raise UnknownNode(f"region level {level} does not exist; the graph has levels 1..{len(graph.regions)}")
    layer = graph.regions[level - 1]
    index = _index(layer.id, region)
    if index is None:
        raise UnknownNode(
            f"region {region} of level {level} does not exist; "
            f"that level has {len(layer)} regions ({_id_range(layer.id)})"
        )
    below = graph.places.id if level == 1 else graph.regions[level - 2].id
    below_char = "p" if level == 1 else graph.regions[level - 2].char
    children = [node_name(below_char, below[c]) for c in np.flatnonzero(layer.parent_of_child == index)]
    parent = None
    if level < len(graph.regions):
        above = graph.regions[level]
        parent = region_name(level + 1, int(above.id[above.parent_of_child[index]]))
    places = [int(graph.places.id[p]) for p in np.flatnonzero(graph.place_region(level) == index)]
    return NodeInfo(
        region_name(level, region),
        "region",
        {
            "level": level,
            "index": index,
            "position": _r(layer.position[index]),
            "parent": parent or ("Z0" if graph.regions else None),
            "children": children,
            "places": places,
        },
    )


def object_info(graph: SceneGraph, object_id: int) -> NodeInfo:
    """The object of id `object_id`."""
    o = graph.objects
    index = _index(o.id, object_id)
    if index is None:
        raise UnknownNode(
            f"object {object_id} does not exist; the graph has {len(o)} objects ({_id_range(o.id)}; save some with "
            "`terra find --save`)"
        )
    return NodeInfo(
        node_name("O", object_id),
        "object",
        {
            "index": index,
            "label": o.label[index],
            "center": _r(o.center[index]),
            "size": _r(o.size[index]),
            "yaw": round(float(o.yaw[index]), 6),
            "score": round(float(o.score[index]), 6),
            "point_count": int(o.point_count[index]),
            "place": node_name("p", graph.places.id[int(o.place[index])]),
        },
    )


def node_info(graph: SceneGraph, ref: str | int) -> NodeInfo:
    """Facts about the node `ref` names by its id (see the module docstring); TerraError when it
    does not exist."""
    char, node_id = parse_node(ref)
    if char == "p":
        index = _index(graph.places.id, node_id)
        if index is None:
            raise UnknownNode(
                f"place {node_id} does not exist; "
                f"the graph has {len(graph.places)} places ({_id_range(graph.places.id)})"
            )
        return place_info(graph, index)
    if char == "O":
        return object_info(graph, node_id)
    if char == "Z" and node_id == 0 and graph.regions:
        top = graph.regions[-1]
        return NodeInfo("Z0", "root", {"children": [region_name(top.level, int(r)) for r in top.id]})
    if "R" <= char <= "Y":
        return region_info(graph, ord(char) - ord("R") + 1, node_id)
    raise UnknownNode(f"node {ref!r} does not exist in this scene graph")


@dataclass
class Location:
    """Where a map point (x, y) falls: its nearest place (2-D) and that place's regions."""

    xy: tuple[float, float]
    place: NodeInfo
    distance_m: float

    def to_json(self) -> dict[str, Any]:
        return {"xy": _r(self.xy), "distance_m": round(self.distance_m, 4), "place": self.place.to_json()}


def locate(graph: SceneGraph, x: float, y: float) -> Location:
    """The place nearest to (x, y) metres in the map frame, with its regions."""
    if len(graph.places) == 0:
        raise TerraError("the scene graph has no places")
    if not (np.isfinite(x) and np.isfinite(y)) or max(abs(x), abs(y)) > MAX_COORDINATE:
        raise TerraError(f"x and y must be finite numbers of metres within +-{MAX_COORDINATE:g}, got {x:g}, {y:g}")
    d = np.linalg.norm(graph.places.position[:, :2] - np.array([x, y]), axis=1)
    place = int(np.argmin(d))
    return Location((float(x), float(y)), place_info(graph, place), float(d[place]))
