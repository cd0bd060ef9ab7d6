"""The scene graph as networkx node-link JSON (`networkx.node_link_graph(json.load(f))`).

Nodes are named by their spark_dsg symbol ("p12" place 12, "R3" region 3 of level 1, "S0" of
level 2, ..., "O4" object 4, "Z0" the root) and carry:
  layer (spark_dsg layer), level (the authors' convention: objects 0, places 1, regions 2..L+1,
  root L+2), index, position [x, y, z] and pos [x, y] (metres, map frame), and per kind:
  places   terrain (name), terrain_id (index), clearance (m);
  regions  terrain_id -1, region_level (1..L);
  objects  label, score, size [m], yaw (rad about +z);
  embedding (D floats of the map's embedder) on places and regions unless features are off.
Edges: kind gvd | cross_terrain | bridge with weight = traversal cost (m) between places; kind
child from a region (or the root) to each member; kind object from a place to its objects.
Graph attributes: terrain_classes, embedder, region_method, region_levels, units.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from terra.bundle import Bundle, dumps_json
from terra.graph.scene_graph import SceneGraph
from terra.graph.storage import EDGE_KIND_NAMES, LAYER_OBJECTS, LAYER_PLACES, layer_names, level_char, load_scene_graph
from terra.interop.output import write_file


def _floats(values: np.ndarray) -> list[float]:
    return [float(v) for v in values]


def _node(name: str, layer: int, level: int, index: int, position: np.ndarray, **attributes: Any) -> dict[str, Any]:
    return {
        "id": name,
        "layer": layer,
        "level": level,
        "index": index,
        "position": _floats(position),
        "pos": _floats(position[:2]),
        **attributes,
    }


def _place_nodes(sg: SceneGraph, features: bool) -> list[dict[str, Any]]:
    places = sg.places
    out = []
    for i in range(len(places)):
        t = int(places.terrain[i])
        extra = {"embedding": _floats(places.embedding[i])} if features else {}
        out.append(
            _node(
                f"p{i}",
                LAYER_PLACES,
                1,
                i,
                places.position[i],
                kind="place",
                terrain=sg.terrain_classes[t],
                terrain_id=t,
                clearance=float(places.clearance[i]),
                **extra,
            )
        )
    return out


def _region_nodes(sg: SceneGraph, features: bool) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    nodes, edges = [], []
    child = "p"
    for level in sg.regions:
        char = level_char(level.level)
        for r in range(len(level)):
            extra = {"embedding": _floats(level.embedding[r])} if features else {}
            nodes.append(
                _node(
                    f"{char}{r}",
                    LAYER_PLACES + level.level,
                    level.level + 1,
                    r,
                    level.position[r],
                    kind="region",
                    region_level=level.level,
                    terrain_id=-1,
                    **extra,
                )
            )
        edges.extend(
            {"source": f"{char}{int(r)}", "target": f"{child}{c}", "kind": "child"}
            for c, r in enumerate(level.parent_of_child)
        )
        child = char
    if sg.regions:
        top = sg.regions[-1]
        levels = len(sg.regions)
        nodes.append(
            _node(
                "Z0",
                layer_names(levels)["ROOT"],
                levels + 2,
                0,
                top.position.mean(axis=0) if len(top) else np.zeros(3),
                kind="root",
                terrain_id=-1,
            )
        )
        edges.extend({"source": "Z0", "target": f"{child}{r}", "kind": "child"} for r in range(len(top)))
    return nodes, edges


def _object_nodes(sg: SceneGraph) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    o = sg.objects
    nodes = [
        _node(
            f"O{i}",
            LAYER_OBJECTS,
            0,
            i,
            o.center[i],
            kind="object",
            label=o.label[i],
            score=float(o.score[i]),
            size=_floats(o.size[i]),
            yaw=float(o.yaw[i]),
            point_count=int(o.point_count[i]),
        )
        for i in range(len(o))
    ]
    edges = [{"source": f"p{int(o.place[i])}", "target": f"O{i}", "kind": "object"} for i in range(len(o))]
    return nodes, edges


def node_link_document(sg: SceneGraph, features: bool = True) -> dict[str, Any]:
    """The node-link dict of `sg` (see the module docstring)."""
    nodes = _place_nodes(sg, features)
    edges = [
        {"source": f"p{int(i)}", "target": f"p{int(j)}", "kind": EDGE_KIND_NAMES[int(k)], "weight": float(w)}
        for (i, j), w, k in zip(sg.place_edges, sg.place_edge_weight, sg.place_edge_kind)
    ]
    region_nodes, region_edges = _region_nodes(sg, features)
    object_nodes, object_edges = _object_nodes(sg)
    graph = {
        "terrain_classes": list(sg.terrain_classes),
        "embedder": sg.embedder,
        "region_method": sg.region_method,
        "region_levels": len(sg.regions),
        "units": {
            "position": "m, map frame",
            "clearance": "m",
            "weight": "m (bridges: times their penalty)",
            "yaw": "rad about +z",
        },
    }
    return {
        "directed": False,
        "multigraph": False,
        "graph": graph,
        "nodes": nodes + region_nodes + object_nodes,
        "edges": edges + region_edges + object_edges,
    }


def export_node_link(bundle: Bundle, out: Path, overwrite: bool = False, features: bool = True) -> dict[str, Any]:
    """Write the bundle's scene graph as node-link JSON to `out`; returns a summary."""
    doc = node_link_document(load_scene_graph(bundle), features)
    write_file(out, dumps_json(doc).encode(), overwrite)
    return {"format": "networkx", "out": str(out), "nodes": len(doc["nodes"]), "edges": len(doc["edges"])}
