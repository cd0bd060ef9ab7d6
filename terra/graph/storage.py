"""The scene graph in a bundle: component `graph/`, spark_dsg JSON plus embedding arrays.

`graph/scene_graph.json` follows spark_dsg's JSON schema (the file `DynamicSceneGraph.save` writes,
header version 1.1.3), so spark_dsg loads it as is:
  layers  OBJECTS 2, PLACES 3, REGIONS 4 (level 1), REGIONS_k 3 + k (level k), ROOT 4 + L;
  node ids NodeSymbol = ord(char) << 56 | id, chars 'O' objects, 'p' places, 'R', 'S', ... for
  region levels 1, 2, ..., 'Z' the root; the id is the node's stable id (terra.graph.ids) and
  metadata.terra.index its position in the arrays (format 1 had no ids: id = index);
  places   PlaceNodeAttributes: position (metres, map frame, z = local ground), name = terrain
           class, semantic_label = terrain index, distance = clearance (m);
  regions  RoomNodeAttributes: position = centroid of the children;
  objects  ObjectNodeAttributes with a RAABB bounding box (size, centre, yaw about +z);
  edges    place-place with weight = traversal cost (m) and metadata kind gvd | cross_terrain |
           bridge | level_route; parent -> child between layers (unweighted).
Terra's own attributes sit in each node's `metadata.terra`. Embeddings are arrays beside it
(float32): graph/place_embedding (P, D), graph/terrain_embedding (T, D), graph/region_embedding_<k>
(R_k, D). Node ids are int64 arrays in index order: graph/place_id (P,), graph/region_id_<k>
(R_k,), graph/object_id (O,); metadata.terra.next_id holds each layer's next free id (ids are
never given twice). `scene_graph_to_spark_json(..., include_features=True)` also writes them into the nodes'
`semantic_feature` for tools that read only the JSON.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from terra.bundle import Bundle, BundleWriter
from terra.errors import TerraError
from terra.graph.scene_graph import (
    EDGE_BRIDGE,
    EDGE_CROSS_TERRAIN,
    EDGE_GEOMETRY_COLUMNS,
    EDGE_GVD,
    EDGE_LEVEL_ROUTE,
    MAX_NODE_ID,
    Objects,
    Places,
    RegionLevel,
    SceneGraph,
    index_of,
    level_char,
)

GRAPH_FORMAT = 2  # 2: stable node ids (1: ids were the indices; still read)
READABLE_FORMATS = (1, 2)
GRAPH_JSON = "graph/scene_graph.json"
PLACE_IDS, OBJECT_IDS, REGION_IDS = "graph/place_id", "graph/object_id", "graph/region_id_"
PLACE_ROOM = "graph/place_room"  # (P,) float32 metres to the nearest obstacle (terra.graph.room)
EDGE_GEOMETRY = "graph/place_edge_geometry"  # (E, 5) float32: EDGE_GEOMETRY_COLUMNS (terra.graph.ground)
GROUND_FILES = "graph/ground_"  # the ground layers (terra.graph.ground.GROUND_FILES)
SPARK_HEADER = {"project_name": "main", "version": {"major": 1, "minor": 1, "patch": 3}}
LAYER_OBJECTS, LAYER_PLACES, LAYER_REGIONS = 2, 3, 4
MAX_LEVELS = 8  # region level chars 'R'..'Y'
EDGE_KIND_NAMES = {
    EDGE_GVD: "gvd",
    EDGE_CROSS_TERRAIN: "cross_terrain",
    EDGE_BRIDGE: "bridge",
    EDGE_LEVEL_ROUTE: "level_route",
}
EDGE_KIND_CODES = {v: k for k, v in EDGE_KIND_NAMES.items()}
_INDEX_MASK = (1 << 56) - 1


@dataclass
class Layer:
    """The nodes of one NodeSymbol char as read: attributes and ids in index order, id -> index."""

    attributes: list[Any]
    ids: np.ndarray
    index: dict[int, int]


def node_symbol(char: str, index: int) -> int:
    """spark_dsg NodeSymbol value: ord(char) << 56 | index."""
    return (ord(char) << 56) | int(index)


def symbol_parts(node_id: int) -> tuple[str, int]:
    return chr(node_id >> 56), node_id & _INDEX_MASK


def layer_names(levels: int) -> dict[str, int]:
    names = {"OBJECTS": LAYER_OBJECTS, "PLACES": LAYER_PLACES, "REGIONS": LAYER_REGIONS}
    names.update({f"REGIONS_{k}": LAYER_PLACES + k for k in range(2, levels + 1)})
    names["ROOT"] = LAYER_PLACES + levels + 1
    return names


def _feature(vec: np.ndarray | None) -> dict[str, Any]:
    if vec is None:
        return {"rows": 0, "cols": 0, "data": None}
    return {"rows": int(vec.shape[0]), "cols": 1, "data": [float(x) for x in vec]}


def _node(
    node_id: int,
    layer: int,
    kind: str,
    position: np.ndarray,
    terra: dict,
    extra: dict | None = None,
    feature: np.ndarray | None = None,
) -> dict:
    attributes = {
        "type": kind,
        "position": [float(v) for v in position],
        "last_update_time_ns": 0,
        "is_active": False,
        "is_predicted": False,
        "semantic_feature": _feature(feature),
        "metadata": {"terra": terra},
    }
    attributes.update(extra or {})
    return {"id": node_id, "layer": layer, "partition": 0, "attributes": attributes}


def _edge(source: int, target: int, weight: float | None = None, kind: str | None = None) -> dict:
    info: dict[str, Any] = {
        "type": "EdgeAttributes",
        "weight": 1.0 if weight is None else float(weight),
        "weighted": weight is not None,
        "metadata": {},
    }
    if kind is not None:
        info["metadata"] = {"terra": {"kind": kind}}
    return {"source": source, "target": target, "info": info}


def scene_graph_to_spark_json(sg: SceneGraph, include_features: bool = False) -> dict[str, Any]:
    """The scene graph as a spark_dsg JSON document (a dict ready for json.dumps)."""
    L = len(sg.regions)
    if L > MAX_LEVELS:
        raise ValueError(f"at most {MAX_LEVELS} region levels can be stored, got {L}")
    names = layer_names(L)
    # Nodes and edges layer by layer, from the objects up to the root.
    nodes, edges = _object_layer(sg.objects, sg.places.id)
    nodes += _place_nodes(sg, include_features)
    edges += _place_edges(sg)
    region_nodes, region_edges = _region_layers(sg.regions, sg.places.id, include_features, names["ROOT"])
    nodes += region_nodes
    edges += region_edges
    return {
        "SPARK_DSG_header": SPARK_HEADER,
        "directed": False,
        "multigraph": False,
        "layer_keys": [{"layer": layer, "partition": 0} for layer in sorted(set(names.values()))],
        "layer_names": {name: {"layer": layer, "partition": 0} for name, layer in names.items()},
        "metadata": {"terra": _graph_metadata(sg)},
        "nodes": nodes,
        "edges": edges,
    }


def _object_layer(objects: Objects, place_ids: np.ndarray) -> tuple[list[dict], list[dict]]:
    """The object nodes (RAABB boxes) and the edge from each object's place to it; `place_ids`
    (P,) names the places (metadata.terra.place is the place's id)."""
    o = objects
    nodes: list[dict] = []
    edges: list[dict] = []
    for i in range(len(o)):
        yaw = float(o.yaw[i])
        box = {
            "type": "RAABB",
            "dimensions": [float(v) for v in o.size[i]],
            "world_P_center": [float(v) for v in o.center[i]],
            "world_R_center": {"w": float(np.cos(yaw / 2)), "x": 0.0, "y": 0.0, "z": float(np.sin(yaw / 2))},
        }
        terra = {
            "index": i,
            "yaw": yaw,
            "score": float(o.score[i]),
            "point_count": int(o.point_count[i]),
            "place": int(place_ids[o.place[i]]),
        }
        nodes.append(
            _node(
                node_symbol("O", int(o.id[i])),
                LAYER_OBJECTS,
                "ObjectNodeAttributes",
                o.center[i],
                terra,
                {"name": o.label[i], "bounding_box": box},
            )
        )
        edges.append(_edge(node_symbol("p", int(place_ids[o.place[i]])), node_symbol("O", int(o.id[i]))))
    return nodes, edges


def _place_nodes(sg: SceneGraph, include_features: bool) -> list[dict]:
    """One PlaceNodeAttributes node per place (terrain class as its name, clearance as distance)."""
    places = sg.places
    nodes: list[dict] = []
    for i in range(len(places)):
        t = int(places.terrain[i])
        terra = {"index": i, "terrain": sg.terrain_classes[t], "clearance": float(places.clearance[i])}
        extra = {
            "name": sg.terrain_classes[t],
            "semantic_label": t,
            "distance": float(places.clearance[i]),
            "num_basis_points": 0,
            "real_place": True,
        }
        nodes.append(
            _node(
                node_symbol("p", int(places.id[i])),
                LAYER_PLACES,
                "PlaceNodeAttributes",
                places.position[i],
                terra,
                extra,
                places.embedding[i] if include_features else None,
            )
        )
    return nodes


def _place_edges(sg: SceneGraph) -> list[dict]:
    """The place-place edges, weighted by traversal cost, with their kind in the metadata."""
    ids = sg.places.id
    return [
        _edge(node_symbol("p", int(ids[i])), node_symbol("p", int(ids[j])), float(w), EDGE_KIND_NAMES[int(k)])
        for (i, j), w, k in zip(sg.place_edges, sg.place_edge_weight, sg.place_edge_kind)
    ]


def _region_layers(
    regions: list[RegionLevel], place_ids: np.ndarray, include_features: bool, root_layer: int
) -> tuple[list[dict], list[dict]]:
    """The region nodes of every level with the edges to their children, then the root (when there
    are region levels) with the edges to the top level's regions."""
    nodes: list[dict] = []
    edges: list[dict] = []
    child_char, child_ids = "p", place_ids
    for level in regions:
        char = level.char
        layer = LAYER_PLACES + level.level
        for r in range(len(level)):
            terra = {"index": r, "level": level.level}
            nodes.append(
                _node(
                    node_symbol(char, int(level.id[r])),
                    layer,
                    "RoomNodeAttributes",
                    level.position[r],
                    terra,
                    {"name": f"L{level.level}-{int(level.id[r])}"},
                    level.embedding[r] if include_features else None,
                )
            )
        for c, r in enumerate(level.parent_of_child):
            edges.append(_edge(node_symbol(char, int(level.id[r])), node_symbol(child_char, int(child_ids[c]))))
        child_char, child_ids = char, level.id
    if regions:
        top = regions[-1]
        root_pos = top.position.mean(axis=0) if len(top) else np.zeros(3)
        nodes.append(
            _node(
                node_symbol("Z", 0),
                root_layer,
                "SemanticNodeAttributes",
                root_pos,
                {"index": 0, "level": len(regions) + 1},
                {"name": "root"},
            )
        )
        for r in range(len(top)):
            edges.append(_edge(node_symbol("Z", 0), node_symbol(child_char, int(child_ids[r]))))
    return nodes, edges


def _graph_metadata(sg: SceneGraph) -> dict[str, Any]:
    """The document's `metadata.terra`: format, vocabulary, provenance and units."""
    return {
        "schema": "terra-scene-graph",
        "format": GRAPH_FORMAT,
        "terrain_classes": list(sg.terrain_classes),
        "embedder": sg.embedder,
        "region_method": sg.region_method,
        "region_levels": len(sg.regions),
        "next_id": sg.next_ids(),
        "units": {
            "position": "m, map frame",
            "clearance": "m",
            "weight": "m (bridges: times their penalty)",
            "yaw": "rad about +z",
        },
    }


def write_scene_graph(writer: BundleWriter, sg: SceneGraph, info: dict[str, Any] | None = None) -> None:
    """Put `sg` into the bundle being written as component `graph/` (replacing any old one).
    `info` (counts, config, stats) goes to manifest components.graph beside the format number."""
    # The ground layers (terra.graph.ground) belong to the build, not to the nodes: an edit of the
    # graph (objects saved by `terra find --save`) keeps them.
    for name in [n for n in writer.files if n.startswith("graph/") and not n.startswith(GROUND_FILES)]:
        writer.remove(name[:-4] if name.endswith(".npy") else name)
    writer.put_json(GRAPH_JSON, scene_graph_to_spark_json(sg))
    dim = sg.terrain_embeddings.shape[1] if sg.terrain_embeddings.ndim == 2 else 0
    writer.put_array("graph/place_embedding", np.asarray(sg.places.embedding, dtype=np.float32).reshape(-1, dim))
    writer.put_array("graph/terrain_embedding", np.asarray(sg.terrain_embeddings, dtype=np.float32))
    writer.put_array(PLACE_IDS, sg.places.id)
    room = np.asarray(sg.places.room, dtype=np.float32)
    if len(room) and np.isfinite(room).all():  # unknown (read from an older bundle): not written
        writer.put_array(PLACE_ROOM, room)
    if sg.has_edge_geometry:
        writer.put_array(EDGE_GEOMETRY, _recorded_columns(np.asarray(sg.place_edge_geometry, dtype=np.float32)))
    writer.put_array(OBJECT_IDS, sg.objects.id)
    for level in sg.regions:
        writer.put_array(
            f"graph/region_embedding_{level.level}", np.asarray(level.embedding, dtype=np.float32).reshape(-1, dim)
        )
        writer.put_array(f"{REGION_IDS}{level.level}", level.id)
    previous = writer.model.components.graph
    kept = {} if previous is None else previous.model_dump(mode="json", exclude_unset=True)
    entry = (
        dict(info)
        if info is not None
        else {k: v for k, v in kept.items() if k not in ("format", "places", "place_edges", "regions", "objects")}
    )
    entry.update(
        {
            "format": GRAPH_FORMAT,
            "places": len(sg.places),
            "place_edges": int(len(sg.place_edges)),
            "regions": [len(level) for level in sg.regions],
            "objects": len(sg.objects),
        }
    )
    writer.set_component("graph", entry)


def load_scene_graph(bundle: Bundle) -> SceneGraph:
    """The scene graph stored in `bundle` (format 2, or format 1 whose ids are the indices);
    TerraError (one line naming the file and what is wrong) when absent, incompatible, or
    inconsistent: the document is validated (terra.schemas), node ids must name each layer's nodes
    once each (format 1: number them 0..n-1), edges must join existing nodes of adjacent levels,
    every node below the top level has one parent, and the id and embedding arrays must match the
    node counts."""
    from terra.schemas import SceneGraphDocument

    info = bundle.model.components.graph
    if info is None or not bundle.has(GRAPH_JSON):
        raise TerraError(f"{bundle.path}: the bundle has no scene graph; build one with `terra build {bundle.path}`")
    if info.format not in READABLE_FORMATS:
        raise TerraError(
            f"{bundle.path}: scene graph format {info.format!r} is not supported (expected "
            f"{' or '.join(map(str, READABLE_FORMATS))}); rebuild it with `terra build {bundle.path}`"
        )
    # Fully typed below the metadata dicts Terra does not read, so no depth walk is needed.
    doc = bundle.document(GRAPH_JSON, SceneGraphDocument, max_depth=None)
    where = str(bundle.path / GRAPH_JSON)
    meta = doc.metadata.terra
    if meta.format != info.format:
        raise TerraError(
            f"{where}: metadata.terra.format {meta.format!r}, but manifest.json components.graph.format is "
            f"{info.format}"
        )
    if info.regions is not None and len(info.regions) != meta.region_levels:
        raise TerraError(
            f"{where}: {meta.region_levels} region levels, but manifest.json components.graph.regions "
            f"lists {len(info.regions)}"
        )
    return _from_document(doc, bundle, where)


def _stored_ids(bundle: Bundle, levels: int) -> dict[str, np.ndarray]:
    """The id arrays of a format-2 graph, per NodeSymbol char."""
    from terra.npy import ArraySpec

    spec = ArraySpec(("int64",), (None,), low=0, high=float(MAX_NODE_ID), what="node ids, one per node")
    names = {"p": PLACE_IDS, "O": OBJECT_IDS} | {level_char(k): f"{REGION_IDS}{k}" for k in range(1, levels + 1)}
    return {char: bundle.array(name, spec) for char, name in names.items()}


def _layers(doc, levels: int, where: str, stored: dict[str, np.ndarray] | None) -> dict[str, Layer]:
    """Node attributes and ids per id char ('O', 'p', region level chars, 'Z'), in index order.
    `stored`: the id arrays of a format-2 graph (index order), whose ids the char's nodes must be
    once each; without them (format 1, or the root) the NodeSymbol indices must be 0..n-1."""
    chars = {"O", "p", "Z"} | {level_char(k) for k in range(1, levels + 1)}
    by_char: dict[str, list[tuple[int, object]]] = {}
    for node in doc.nodes:
        char, node_id = symbol_parts(node.id)
        if char not in chars:
            raise TerraError(
                f"{where}: node id {node.id} has symbol {char!r}, expected one of {''.join(sorted(chars))} "
                f"for {levels} region levels"
            )
        by_char.setdefault(char, []).append((node_id, node.attributes))
    out = {}
    for char in chars:
        items = by_char.get(char, [])
        ids = stored.get(char) if stored is not None else None
        if ids is None:
            ids = np.arange(len(items), dtype=np.int64)
            expected = "number 0..n-1"
        else:
            expected = f"be those of its id array ({len(ids)} listed there)"
        index = index_of(ids)
        slots: list[object] = [None] * len(ids)
        for node_id, attributes in items:
            position = index.get(node_id)
            if position is None or slots[position] is not None:
                break
            slots[position] = attributes
        if len(items) != len(ids) or any(a is None for a in slots):
            raise TerraError(
                f"{where}: node ids of symbol {char!r} must {expected}, once each ({len(items)} such nodes)"
            )
        out[char] = Layer(slots, ids, index)
    return out


def _embedding(bundle: Bundle, name: str, rows: int, dim: int | None) -> np.ndarray:
    from terra.npy import ArraySpec

    spec = ArraySpec(("float32",), (rows, dim), finite=True, what="unit embeddings, one row per node")
    return bundle.array(name, spec)


def _places(layer: Layer, terrain_count: int, bundle: Bundle, dim: int, where: str) -> Places:
    items = layer.attributes
    for i, a in enumerate(items):
        if (
            a.semantic_label is None
            or not 0 <= a.semantic_label < terrain_count
            or a.distance is None
            or a.distance < 0
        ):
            raise TerraError(
                f"{where}: place p{layer.ids[i]}: semantic_label must be a terrain index 0..{terrain_count - 1} and "
                "distance (clearance) a number >= 0"
            )
    return Places(
        position=np.array([a.position for a in items], dtype=np.float64).reshape(-1, 3),
        terrain=np.array([a.semantic_label for a in items], dtype=np.int64),
        clearance=np.array([a.distance for a in items], dtype=np.float64),
        embedding=_embedding(bundle, "graph/place_embedding", len(items), dim),
        id=layer.ids,
        room=_room(bundle, len(items)),
    )


def _room(bundle: Bundle, places: int) -> np.ndarray | None:
    """Each place's room (metres), None (unknown) in a bundle written before it was recorded."""
    from terra.npy import ArraySpec

    if not bundle.has(PLACE_ROOM):
        return None
    spec = ArraySpec(("float32",), (places,), finite=True, low=0.0, high=1e6, what="metres to the nearest obstacle")
    return np.asarray(bundle.array(PLACE_ROOM, spec), dtype=np.float64)


def _objects(layer: Layer, places: Layer, where: str) -> Objects:
    from terra.schemas import ObjectTerra, validate_model

    items = layer.attributes
    terra = []
    for i, a in enumerate(items):
        name = f"object O{layer.ids[i]}"
        extra = validate_model(a.metadata.get("terra"), ObjectTerra, f"{where} {name} metadata")
        if a.bounding_box is None or a.name is None or extra.place not in places.index:
            raise TerraError(f"{where}: {name}: needs a name, a bounding_box and the id of a place of the graph")
        terra.append(extra)
    return Objects(
        center=np.array([a.position for a in items], dtype=np.float64).reshape(-1, 3),
        size=np.array([a.bounding_box.dimensions for a in items], dtype=np.float64).reshape(-1, 3),
        yaw=np.array([t.yaw for t in terra], dtype=np.float64),
        label=[a.name for a in items],
        score=np.array([t.score for t in terra], dtype=np.float32),
        point_count=np.array([t.point_count for t in terra], dtype=np.int64),
        place=np.array([places.index[t.place] for t in terra], dtype=np.int64),
        id=layer.ids,
    )


def _edges(
    doc, layers: dict[str, Layer], levels: int, where: str
) -> tuple[list, list, list, dict[str, dict[int, int]]]:
    """Place edges (index pairs, weights, kinds) and, per child char, child index -> parent index."""
    from terra.schemas import EdgeTerra, validate_model

    above = {"p": level_char(1)} | {level_char(k): level_char(k + 1) for k in range(1, levels)}
    if levels:
        above[level_char(levels)] = "Z"
    empty: dict[int, int] = {}
    place_edges, weights, kinds = [], [], []
    parent_of: dict[str, dict[int, int]] = {}
    for e, edge in enumerate(doc.edges):
        (sc, sid), (tc, tid) = symbol_parts(edge.source), symbol_parts(edge.target)
        si = layers[sc].index.get(sid) if sc in layers else empty.get(sid)
        ti = layers[tc].index.get(tid) if tc in layers else empty.get(tid)
        if si is None or ti is None:
            raise TerraError(
                f"{where}: edge {e} joins {sc}{sid} and {tc}{tid} (NodeSymbol char and id), "
                "which are not both nodes of the graph"
            )
        if sc == "p" and tc == "p":
            if si == ti:
                raise TerraError(f"{where}: edge {e} joins place p{sid} to itself")
            kind = validate_model(edge.info.metadata.get("terra"), EdgeTerra, f"{where} edge {e} metadata").kind
            place_edges.append((si, ti))
            weights.append(edge.info.weight)
            kinds.append(EDGE_KIND_CODES[kind])
        elif tc == "O" and sc == "p":
            continue  # object -> place links are stored on the objects
        elif above.get(tc) == sc:
            if parent_of.setdefault(tc, {}).setdefault(ti, si) != si:
                raise TerraError(f"{where}: node {tc}{tid} (NodeSymbol char and id) has two parents")
        else:
            raise TerraError(f"{where}: edge {e} from {sc!r} to {tc!r} nodes is neither a place edge nor a parent link")
    return place_edges, weights, kinds, parent_of


def _from_document(doc, bundle: Bundle, where: str) -> SceneGraph:
    meta = doc.metadata.terra
    levels, terrain_classes = meta.region_levels, list(meta.terrain_classes)
    dim = bundle.model.embedder.dim if bundle.model.embedder is not None else None
    terrain_embeddings = bundle.array("graph/terrain_embedding", _terrain_spec(len(terrain_classes), dim))
    dim = terrain_embeddings.shape[1]
    layers = _layers(doc, levels, where, _stored_ids(bundle, levels) if meta.format >= 2 else None)
    places = _places(layers["p"], len(terrain_classes), bundle, dim, where)
    objects = _objects(layers["O"], layers["p"], where)
    place_edges, weights, kinds, parent_of = _edges(doc, layers, levels, where)
    return SceneGraph(
        terrain_classes=terrain_classes,
        terrain_embeddings=terrain_embeddings,
        places=places,
        place_edges=np.array(place_edges, dtype=np.int64).reshape(-1, 2),
        place_edge_weight=np.array(weights, dtype=np.float64),
        place_edge_kind=np.array(kinds, dtype=np.int64),
        regions=_region_levels(layers, parent_of, levels, bundle, dim, where),
        objects=objects,
        embedder=meta.embedder,
        region_method=meta.region_method,
        next_id=dict(meta.next_id),
        place_edge_geometry=_edge_geometry(bundle, len(place_edges)),
    )


def _recorded_columns(geometry: np.ndarray) -> np.ndarray:
    """The edge geometry (E, 5) without its trailing columns that hold NaN (unknown: a graph read
    from a bundle written before they were recorded), so that what is written reads back."""
    columns = geometry.shape[1]
    while columns > 3 and np.isnan(geometry[:, columns - 1]).any():
        columns -= 1
    return geometry[:, :columns]


def _edge_geometry(bundle: Bundle, edges: int) -> np.ndarray:
    """The (E, 5) ground geometry of the place edges (EDGE_GEOMETRY_COLUMNS), (0, 5) when the graph
    has none. A bundle written before the unobserved stretch (E, 3) or the cross slope (E, 4) was
    recorded reads the missing columns as NaN: unknown, which no robot profile refuses."""
    from terra.npy import ArraySpec

    columns = len(EDGE_GEOMETRY_COLUMNS)
    if not bundle.has(EDGE_GEOMETRY):
        return np.zeros((0, columns), dtype=np.float32)
    spec = ArraySpec(
        ("float32",),
        (edges, None),
        finite=True,
        low=0.0,
        high=1e6,
        what=f"per place edge: {', '.join(EDGE_GEOMETRY_COLUMNS)} (the first three at least)",
    )
    geometry = bundle.array(EDGE_GEOMETRY, spec)
    if not 3 <= geometry.shape[1] <= columns:
        raise TerraError(
            f"{bundle.path / EDGE_GEOMETRY}.npy: expected 3 to {columns} columns "
            f"({', '.join(EDGE_GEOMETRY_COLUMNS)}), found {geometry.shape[1]}"
        )
    missing = columns - geometry.shape[1]
    if missing:
        geometry = np.column_stack([geometry, np.full((edges, missing), np.nan, dtype=np.float32)])
    return geometry


def _region_levels(
    layers: dict[str, Layer], parent_of: dict[str, dict[int, int]], levels: int, bundle: Bundle, dim: int, where: str
) -> list[RegionLevel]:
    """The region levels, 1 upwards, with each child's parent index."""
    regions = []
    child_char, n_children = "p", len(layers["p"].ids)
    for k in range(1, levels + 1):
        char = level_char(k)
        layer = layers[char]
        mapping = parent_of.get(child_char, {})
        if len(mapping) != n_children:
            raise TerraError(
                f"{where}: {n_children - len(mapping)} of the {n_children} nodes below region level {k} "
                "have no parent there"
            )
        regions.append(
            RegionLevel(
                level=k,
                position=np.array([a.position for a in layer.attributes], dtype=np.float64).reshape(-1, 3),
                embedding=_embedding(bundle, f"graph/region_embedding_{k}", len(layer.ids), dim),
                parent_of_child=np.array([mapping[c] for c in range(n_children)], dtype=np.int64),
                id=layer.ids,
            )
        )
        child_char, n_children = char, len(layer.ids)
    return regions


def _terrain_spec(count: int, dim: int | None):
    from terra.npy import ArraySpec

    return ArraySpec(("float32",), (count, dim), finite=True, what="terrain class embeddings, one row per class")
