"""The scene graph as the `spark-dsg` package reads it (Hydra, Clio and their tools).

The bundle already stores its graph in spark_dsg's JSON schema (terra.graph.storage: layers,
NodeSymbol ids made of each node's stable id, attributes). The export adds what a reader of the JSON alone needs:
- semantic_feature on places and regions: their embedding (D floats, the map's embedder);
- colour (RGBA, 0-255): places by terrain (Terra's figure palette), regions per region, objects
  per label;
- region bounding boxes: the axis-aligned box of the region's places (metres, map frame);
- object semantic_label: index into the object labelspace;
- labelspaces in the graph metadata, as spark_dsg stores them (`labelspaces._l{layer}p{partition}`
  = [[label, name], ...]): terrain classes for the places layer, object labels for the objects;
- a ROOMS alias for the first region layer (4), the layer Hydra's tools look for;
- metadata.terra.terrain_embeddings: (T, D) text embeddings of the terrain class names.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from terra.bundle import Bundle, dumps_json
from terra.graph.scene_graph import SceneGraph
from terra.graph.storage import LAYER_OBJECTS, LAYER_PLACES, load_scene_graph, scene_graph_to_spark_json, symbol_parts
from terra.interop.output import write_file


def _rgba(rgb: np.ndarray) -> dict[str, int]:
    r, g, b = (int(round(float(v) * 255)) for v in rgb[:3])
    return {"r": r, "g": g, "b": b, "a": 255}


def _aabb(points: np.ndarray) -> dict[str, Any]:
    lo, hi = points.min(axis=0), points.max(axis=0)
    return {
        "type": "AABB",
        "dimensions": [float(v) for v in hi - lo],
        "world_P_center": [float(v) for v in (lo + hi) / 2],
        "world_R_center": {"w": 1.0, "x": 0.0, "y": 0.0, "z": 0.0},
    }


def _labelspace_key(layer: int, partition: int = 0) -> str:
    return f"_l{layer}p{partition}"


def object_labels(sg: SceneGraph) -> list[str]:
    """The object labelspace: distinct object labels in order of first appearance."""
    return list(dict.fromkeys(sg.objects.label))


def spark_document(sg: SceneGraph, features: bool = True) -> dict[str, Any]:
    """The spark_dsg JSON document of `sg` with the additions listed in the module docstring."""
    from terra.viz.places import region_colours
    from terra.viz.style import terrain_palette

    doc = scene_graph_to_spark_json(sg, include_features=features)
    palette = terrain_palette(sg.terrain_classes)
    labels = object_labels(sg)
    label_colour = region_colours(np.arange(max(len(labels), 1)), seed=0)
    level_colour = {level.level: region_colours(np.arange(len(level)), seed=level.level) for level in sg.regions}
    boxes = {level.level: _region_boxes(sg, level.level) for level in sg.regions}
    level_of_char = {chr(ord("R") + level.level - 1): level.level for level in sg.regions}
    for node in doc["nodes"]:
        char, _ = symbol_parts(int(node["id"]))  # the id names the node; the index reads its arrays
        attributes = node["attributes"]
        index = int(attributes["metadata"]["terra"]["index"])
        if char == "p":
            attributes["color"] = _rgba(palette[int(sg.places.terrain[index])])
        elif char == "O":
            label = labels.index(sg.objects.label[index])
            attributes["semantic_label"] = label
            attributes["color"] = _rgba(label_colour[label])
        elif char in level_of_char:
            level = level_of_char[char]
            attributes["color"] = _rgba(level_colour[level][index])
            if boxes[level][index] is not None:
                attributes["bounding_box"] = boxes[level][index]
    if sg.regions:
        doc["layer_names"]["ROOMS"] = {"layer": LAYER_PLACES + 1, "partition": 0}
    doc["metadata"]["labelspaces"] = {
        _labelspace_key(LAYER_PLACES): [[i, name] for i, name in enumerate(sg.terrain_classes)],
        _labelspace_key(LAYER_OBJECTS): [[i, name] for i, name in enumerate(labels)],
    }
    if features:
        doc["metadata"]["terra"]["terrain_embeddings"] = [[float(v) for v in row] for row in sg.terrain_embeddings]
    return doc


def _region_boxes(sg: SceneGraph, level: int) -> list[dict[str, Any] | None]:
    """Per region of `level`: the axis-aligned box of its places (None for a region without any)."""
    assignment = sg.place_region(level)
    order = np.argsort(assignment, kind="stable")
    bounds = np.searchsorted(assignment[order], np.arange(len(sg.regions[level - 1]) + 1))
    position = sg.places.position
    return [_aabb(position[order[a:b]]) if b > a else None for a, b in zip(bounds[:-1], bounds[1:])]


def export_spark_dsg(bundle: Bundle, out: Path, overwrite: bool = False, features: bool = True) -> dict[str, Any]:
    """Write the bundle's scene graph to `out` (a .json file spark_dsg.DynamicSceneGraph.load reads).
    Returns a summary (path, node and edge counts)."""
    sg = load_scene_graph(bundle)
    doc = spark_document(sg, features)
    write_file(out, dumps_json(doc).encode(), overwrite)
    return {
        "format": "spark-dsg",
        "out": str(out),
        "nodes": len(doc["nodes"]),
        "edges": len(doc["edges"]),
        "layers": {name: key["layer"] for name, key in sorted(doc["layer_names"].items())},
    }
