"""`terra export` of the scene graph and the map: spark_dsg JSON loaded back by the spark-dsg
package, networkx node-link JSON loaded by networkx, PLY read by trimesh; each compared with the
bundle's graph and map, computed independently where it can be."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

from terra.cli import run
from terra.graph.storage import load_scene_graph
from terra.mapping.storage import load_map
from terra.viz.style import terrain_palette
from tests.mapping.fixtures import folder_digest


@pytest.fixture(scope="module")
def graph(interop_bundle):
    return load_scene_graph(interop_bundle)


@pytest.fixture(scope="module")
def spark_file(interop_bundle, tmp_path_factory):
    out = tmp_path_factory.mktemp("spark") / "tiny.dsg.json"
    assert run(["export", str(interop_bundle.path), "--format", "spark-dsg", "--out", str(out)]) == 0
    return out


def _rgb255(rgb) -> list[int]:
    return [int(round(v * 255)) for v in rgb]


def test_spark_dsg_loads_the_export_with_every_layer_edge_and_attribute(spark_file, graph):
    dsg = pytest.importorskip("spark_dsg")
    g = dsg.DynamicSceneGraph.load(str(spark_file))
    levels = len(graph.regions)
    assert g.get_layer(2).num_nodes() == len(graph.objects) == 3
    assert g.get_layer(3).num_nodes() == len(graph.places)
    for k, level in enumerate(graph.regions, start=1):
        assert g.get_layer(3 + k).num_nodes() == len(level)
    assert g.get_layer(4 + levels).num_nodes() == 1  # the root
    parent_edges = len(graph.places) + sum(len(level) for level in graph.regions)
    assert g.num_edges() == len(graph.place_edges) + parent_edges + len(graph.objects)
    names = g.layer_names
    assert names["PLACES"] == 3 and names["ROOMS"] == 4 and names["REGIONS_2"] == 5 and names["ROOT"] == 4 + levels

    palette = terrain_palette(graph.terrain_classes)
    for i in range(len(graph.places)):
        a = g.get_node(dsg.NodeSymbol("p", i).value).attributes
        t = int(graph.places.terrain[i])
        assert np.allclose(a.position, graph.places.position[i])
        assert a.semantic_label == t and a.name == graph.terrain_classes[t]
        assert a.distance == pytest.approx(graph.places.clearance[i])
        assert np.allclose(a.semantic_feature.ravel(), graph.places.embedding[i], atol=1e-6)
        assert list(a.color) == _rgb255(palette[t])
    assert g.get_labelspace(3, 0).labels_to_names == dict(enumerate(graph.terrain_classes))


def test_spark_dsg_edges_keep_weights_and_hierarchy(spark_file, graph):
    dsg = pytest.importorskip("spark_dsg")
    g = dsg.DynamicSceneGraph.load(str(spark_file))
    for (i, j), w in zip(graph.place_edges, graph.place_edge_weight):
        edge = g.get_edge(dsg.NodeSymbol("p", int(i)).value, dsg.NodeSymbol("p", int(j)).value)
        assert edge.info.weighted and edge.info.weight == pytest.approx(float(w))
    level1 = graph.place_region(1)
    for i in range(len(graph.places)):
        node = g.get_node(dsg.NodeSymbol("p", i).value)
        assert node.get_parent() == dsg.NodeSymbol("R", int(level1[i])).value


def test_spark_dsg_region_boxes_hold_their_places_and_objects_keep_their_boxes(spark_file, graph):
    dsg = pytest.importorskip("spark_dsg")
    g = dsg.DynamicSceneGraph.load(str(spark_file))
    for k, level in enumerate(graph.regions, start=1):
        assignment = graph.place_region(k)
        for r in range(len(level)):
            members = graph.places.position[assignment == r]
            box = g.get_node(dsg.NodeSymbol(chr(ord("R") + k - 1), r).value).attributes.bounding_box
            assert np.allclose(box.min, members.min(axis=0), atol=1e-4) and np.allclose(
                box.max, members.max(axis=0), atol=1e-4
            )
            assert np.allclose(
                g.get_node(dsg.NodeSymbol(chr(ord("R") + k - 1), r).value).attributes.semantic_feature.ravel(),
                level.embedding[r],
                atol=1e-6,
            )
    labels = g.get_labelspace(2, 0).labels_to_names
    assert labels == {0: "bench", 1: "trash can"}
    for i in range(len(graph.objects)):
        node = g.get_node(dsg.NodeSymbol("O", i).value)
        a = node.attributes
        assert labels[a.semantic_label] == graph.objects.label[i]
        assert np.allclose(a.bounding_box.dimensions, graph.objects.size[i], atol=1e-5)
        assert np.allclose(a.bounding_box.world_P_center, graph.objects.center[i], atol=1e-5)
        c, s = np.cos(graph.objects.yaw[i]), np.sin(graph.objects.yaw[i])
        assert np.allclose(a.bounding_box.world_R_center, [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-5)
        assert node.get_parent() == dsg.NodeSymbol("p", int(graph.objects.place[i])).value


def test_networkx_node_link_round_trip_gives_the_same_shortest_paths(interop_bundle, graph, tmp_path):
    nx = pytest.importorskip("networkx")
    out = tmp_path / "g.nx.json"
    assert run(["export", str(interop_bundle.path), "-f", "networkx", "-o", str(out), "--no-features"]) == 0
    g = nx.node_link_graph(json.loads(out.read_text()), edges="edges")
    assert g.number_of_nodes() == len(graph.places) + sum(len(level) for level in graph.regions) + 1 + len(
        graph.objects
    )
    assert g.nodes["p7"]["terrain"] == graph.terrain_classes[graph.places.terrain[7]]
    assert g.nodes["p7"]["level"] == 1 and g.nodes["O1"]["level"] == 0 and g.nodes["R0"]["level"] == 2
    assert "embedding" not in g.nodes["p7"]
    places = g.subgraph([f"p{i}" for i in range(len(graph.places))])
    expected = dijkstra(graph.place_adjacency(), indices=0)
    lengths = nx.single_source_dijkstra_path_length(places, "p0", weight="weight")
    for i in range(len(graph.places)):
        if np.isfinite(expected[i]):
            assert lengths[f"p{i}"] == pytest.approx(expected[i])


@pytest.mark.parametrize("color", ["terrain", "ms-max"])
def test_ply_holds_every_point_with_its_colour_terrain_and_class(interop_bundle, tmp_path, color):
    trimesh = pytest.importorskip("trimesh")
    out = tmp_path / "map.ply"
    assert run(["export", str(interop_bundle.path), "-f", "ply", "-o", str(out), "--color", color]) == 0
    cloud = trimesh.load(out)
    msm = load_map(interop_bundle)
    raw = cloud.metadata["_ply_raw"]["vertex"]["data"]
    assert np.array_equal(np.asarray(cloud.vertices, dtype=np.float32), msm.points)
    terrain = msm.terrain_index()
    assert np.array_equal(raw["terrain"], terrain) and np.array_equal(raw["ms_max"], msm.ms_max_ids())
    if color == "terrain":
        expected = np.round(terrain_palette(msm.terrain_classes)[terrain] * 255)
        assert np.array_equal(np.asarray(cloud.colors)[:, :3], expected)
    else:
        ids = msm.ms_max_ids()
        colours = np.asarray(cloud.colors)[:, :3]
        # Points sharing a bank entry share a colour, and different entries look different.
        for bank_id in np.unique(ids[ids >= 0])[:5]:
            assert len(np.unique(colours[ids == bank_id], axis=0)) == 1
        assert len(np.unique(colours[ids >= 0], axis=0)) == min(len(np.unique(ids[ids >= 0])), 40)


def test_exports_are_deterministic_and_refuse_to_overwrite(interop_bundle, tmp_path, capsys):
    out = tmp_path / "a.dsg.json"
    assert run(["export", str(interop_bundle.path), "-f", "spark-dsg", "-o", str(out)]) == 0
    first = out.read_bytes()
    capsys.readouterr()
    assert run(["export", str(interop_bundle.path), "-f", "spark-dsg", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists" in err[0] and "--overwrite" in err[0]
    assert out.read_bytes() == first
    assert run(["export", str(interop_bundle.path), "-f", "spark-dsg", "-o", str(out), "--overwrite"]) == 0
    assert out.read_bytes() == first
    before = folder_digest(tmp_path)
    assert run(["export", str(interop_bundle.path), "-f", "gltf", "-o", str(tmp_path / "x")]) == 2
    assert folder_digest(tmp_path) == before


def test_a_bundle_of_another_schema_version_is_refused(interop_bundle, tmp_path, capsys):
    from tests.graph.fixtures import copy_bundle

    path = copy_bundle(interop_bundle, tmp_path / "old.terra")
    manifest = json.loads((path / "manifest.json").read_text())
    manifest["schema_version"] = 99
    (path / "manifest.json").write_text(json.dumps(manifest))
    assert run(["export", str(path), "-f", "ply", "-o", str(tmp_path / "x.ply")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "schema_version 99" in err[0]
    assert not (tmp_path / "x.ply").exists()
