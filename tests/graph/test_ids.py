"""Stable node ids (terra.graph.ids, graph format 2): matching on hand-made arrays and graphs, every
expected id worked out by hand in the comments; the ids stored in a bundle and read back; a format-1
bundle (no ids) still read with ids = indices."""

from __future__ import annotations

import numpy as np
import pytest

from terra.bundle import Bundle, BundleWriter
from terra.errors import TerraError
from terra.graph.ids import carried_ids, carry_ids, match_groups, match_points
from terra.graph.scene_graph import Objects, RegionLevel, SceneGraph
from terra.graph.storage import GRAPH_JSON, load_scene_graph, node_symbol, write_scene_graph
from terra.tasks.lookup import node_info, region_info
from terra.tasks.retrieval import FoundObject, with_objects
from tests.tasks.test_tasks_synthetic import make_graph


def xyz(*xs: float) -> np.ndarray:
    return np.array([[x, 0.0, 0.0] for x in xs])


def test_points_match_within_the_tolerance_and_the_same_group():
    old, old_group = xyz(0, 1, 5, 8), [0, 0, 0, 1]
    new, new_group = xyz(0.1, 0.95, 10, 8.1), [0, 0, 0, 0]
    # 0.1 and 0.05 from old 0 and 1; 10 is 5 from anything; 8.1 is near old 3 but of another group.
    assert match_points(old, old_group, new, new_group, 0.2).tolist() == [0, 1, -1, -1]
    assert match_points(old[:0], [], new, new_group, 0.2).tolist() == [-1] * 4


def test_points_match_one_to_one_with_the_most_pairs():
    # new 0 (0.35) is nearer old 1 (0.6: 0.25) than old 0 (0.35); taking it would leave new 1 (0.9,
    # only old 1 within 0.5) without a partner, so the matching pairs new 0-old 0, new 1-old 1.
    assert match_points(xyz(0, 0.6), [0, 0], xyz(0.35, 0.9), [0, 0], 0.5).tolist() == [0, 1]
    # All four pairs are candidates; 0.4 + 0.4 beats 0.6 + 0.6.
    assert match_points(xyz(0, 1), [0, 0], xyz(0.4, 0.6), [0, 0], 0.7).tolist() == [0, 1]
    # Two new points, one old: only one takes it, the nearer.
    assert match_points(xyz(0), [0], xyz(0.3, 0.1), [0, 0], 0.5).tolist() == [-1, 0]


def test_groups_match_on_shared_members_jaccard_at_least_half():
    # Old places 0..5 in regions 0 {0,1,2} and 1 {3,4,5}; new places 0..3 are old 0..3, 4 and 5 new.
    # New region 1 {0,1,2} = old region 0 (J = 3/3); new region 0 {3,n4,n5} shares 1 of 5 (J = 0.2).
    match = np.array([0, 1, 2, 3, -1, -1])
    assert match_groups(np.array([0, 0, 0, 1, 1, 1]), np.array([1, 1, 1, 0, 0, 0]), match, 2, 2).tolist() == [-1, 0]
    # One new region {a,b,c,d} over old {a,b} and {c,d}: J = 0.5 both; the lower old group wins.
    same = np.arange(4)
    assert match_groups(np.array([0, 0, 1, 1]), np.array([0, 0, 0, 0]), same, 2, 1).tolist() == [0]
    # Old {a,b,c,d} split in two new halves, J = 0.5 each: one-to-one, the lower new group takes it.
    assert match_groups(np.array([0, 0, 0, 0]), np.array([0, 0, 1, 1]), same, 1, 2).tolist() == [0, -1]
    assert match_groups(np.array([0]), np.array([0, 0]), np.array([-1, -1]), 1, 1).tolist() == [-1]


def test_carried_ids_never_reuse_an_id():
    ids, next_id = carried_ids(np.array([2, -1, 0, -1]), np.array([10, 11, 12]), 20)
    assert ids.tolist() == [12, 20, 10, 21] and next_id == 22
    # A recorded next id below the old ids is raised above them (13 = 12 + 1).
    ids, next_id = carried_ids(np.array([2, -1, 0, -1]), np.array([10, 11, 12]), 5)
    assert ids.tolist() == [12, 13, 10, 14] and next_id == 15
    ids, next_id = carried_ids(np.array([-1, -1]), np.zeros(0, dtype=np.int64), 0)
    assert ids.tolist() == [0, 1] and next_id == 2


def _objects(labels: list[str], xs: list[float], place: list[int], ids=()) -> Objects:
    n = len(labels)
    return Objects(
        center=xyz(*xs).reshape(-1, 3),
        size=np.ones((n, 3)),
        yaw=np.zeros(n),
        label=labels,
        score=np.full(n, 0.5, dtype=np.float32),
        point_count=np.full(n, 10, dtype=np.int64),
        place=np.array(place, dtype=np.int64),
        id=np.array(ids, dtype=np.int64),
    )


def old_graph() -> SceneGraph:
    """Five sidewalk places on the x axis with ids 7, 3, 9, 4, 5 (12 given before), regions {0,1,2}
    (id 2) and {3,4} (id 6), one bench (id 5)."""
    graph = make_graph(
        xyz(0, 1, 2, 3, 4), [0] * 5, [[0, 1], [1, 2], [2, 3], [3, 4]], terrain_classes=["sidewalk", "grass"]
    )
    graph.places.id = np.array([7, 3, 9, 4, 5])
    level = RegionLevel(1, np.zeros((2, 3)), np.zeros((2, 4), np.float32), np.array([0, 0, 0, 1, 1]), np.array([2, 6]))
    graph.regions = [level]
    graph.objects = _objects(["bench"], [1.0], [1], [5])
    graph.next_id = {"p": 12}
    return graph


def new_graph() -> SceneGraph:
    """The same street rebuilt: the terrain list reordered, place 2 now grass, place 3 moved 2 cm, a
    new place at x = 10; regions {0,1,2} and {3,4}; benches at 1.3 and 4."""
    graph = make_graph(
        xyz(0, 1, 2, 3.02, 10), [1, 1, 0, 1, 1], [[0, 1], [1, 2], [2, 3], [3, 4]], terrain_classes=["grass", "sidewalk"]
    )
    graph.regions = [RegionLevel(1, np.zeros((2, 3)), np.zeros((2, 4), np.float32), np.array([0, 0, 0, 1, 1]))]
    graph.objects = _objects(["bench", "bench"], [1.3, 4.0], [1, 3])
    return graph


def test_carry_ids_between_two_hand_made_graphs():
    carried = carry_ids(new_graph(), old_graph(), tolerance=0.2)
    # Places 0, 1, 3 are old places 0, 1, 3 (7, 3, 4); place 2 changed terrain and 4 is new: fresh
    # ids from max(12 recorded, 9 + 1) = 12.
    assert carried.places.id.tolist() == [7, 3, 12, 4, 13]
    # New region {0,1,2} shares old places 0, 1 with old region {0,1,2}: J = 2 / 4 = 0.5, so id 2;
    # {3,4} shares only place 3 with old {3,4}: J = 1/3, fresh id 6 + 1.
    assert carried.regions[0].id.tolist() == [2, 7]
    # The bench 0.3 m from the old one keeps id 5; the other is new (6).
    assert carried.objects.id.tolist() == [5, 6]
    assert carried.next_ids() == {"p": 14, "R": 8, "O": 7}


def test_ids_survive_the_bundle_and_name_the_nodes(tmp_path):
    graph = carry_ids(new_graph(), old_graph(), tolerance=0.2)
    path = tmp_path / "ids.terra"
    with BundleWriter(path) as writer:
        write_scene_graph(writer, graph)
    bundle = Bundle(path)
    loaded = load_scene_graph(bundle)
    assert loaded.places.id.tolist() == [7, 3, 12, 4, 13] and loaded.regions[0].id.tolist() == [2, 7]
    assert loaded.objects.id.tolist() == [5, 6] and loaded.objects.place.tolist() == [1, 3]
    assert loaded.next_id == {"p": 14, "R": 8, "O": 7}
    assert bundle.array("graph/place_id").tolist() == [7, 3, 12, 4, 13]
    assert np.array_equal(loaded.place_region(1), [0, 0, 0, 1, 1])
    node_ids = {node["id"] for node in bundle.json(GRAPH_JSON)["nodes"]}
    assert {node_symbol("p", 12), node_symbol("R", 7), node_symbol("O", 6)} <= node_ids
    assert node_symbol("p", 2) not in node_ids
    place = node_info(loaded, "p12").to_json()  # index 2
    assert place["index"] == 2 and place["id"] == "p12" and place["position"] == [2.0, 0.0, 0.0]
    assert sorted(n["place"] for n in place["neighbors"]) == [3, 4] and place["regions"][0]["id"] == "R2"
    region = region_info(loaded, 1, 7).to_json()
    assert region["index"] == 1 and region["children"] == ["p4", "p13"] and region["places"] == [4, 13]
    assert node_info(loaded, "O6").to_json()["place"] == "p4"
    assert node_info(loaded, str(node_symbol("p", 13))).to_json()["position"] == [10.0, 0.0, 0.0]
    with pytest.raises(TerraError, match="place 2 does not exist; the graph has 5 places"):
        node_info(loaded, "p2")


def bench(x: float, score: float, place: int) -> FoundObject:
    return FoundObject(xyz(x)[0], np.ones(3), 0.0, 0, "bench", score, np.ones(1), 10, place, np.arange(3))


def test_saving_objects_keeps_their_ids():
    graph = old_graph()
    graph.objects = _objects(["bench", "bin"], [1.0, 3.0], [1, 3], [5, 8])
    found = [bench(1.2, 0.9, 1), bench(4.0, 0.8, 4)]
    saved = with_objects(graph, found)
    # The bin is kept (8); the bench found 0.2 m from the old one takes its id 5; the other is new:
    # 9, above the 8 in use.
    assert saved.objects.label == ["bin", "bench", "bench"] and saved.objects.id.tolist() == [8, 5, 9]
    assert saved.next_ids()["O"] == 10


def test_a_format_1_graph_reads_with_ids_as_indices(tmp_path):
    """A bundle written before ids (format 1: NodeSymbol index = array index, no id arrays, no
    next_id); made from a format-2 bundle of a graph whose ids are its indices, which differ from
    format 1 in exactly those fields."""
    graph = make_graph(xyz(0, 1, 2), [0, 0, 1], [[0, 1], [1, 2]], terrain_classes=["sidewalk", "grass"])
    graph.objects = _objects(["bench"], [2.0], [2])
    path = tmp_path / "v1.terra"
    with BundleWriter(path) as writer:
        write_scene_graph(writer, graph)
    with BundleWriter(path, base=Bundle(path)) as writer:
        doc = Bundle(path).json(GRAPH_JSON)
        doc["metadata"]["terra"]["format"] = 1
        del doc["metadata"]["terra"]["next_id"]
        writer.put_json(GRAPH_JSON, doc)
        for name in ("graph/place_id", "graph/object_id"):
            writer.remove(name)
        entry = Bundle(path).model.components.graph
        assert entry is not None
        writer.set_component("graph", entry.model_dump(mode="json", exclude_unset=True) | {"format": 1})
    loaded = load_scene_graph(Bundle(path))
    assert loaded.places.id.tolist() == [0, 1, 2] and loaded.objects.id.tolist() == [0]
    assert loaded.next_ids() == {"p": 3, "O": 1} and loaded.objects.place.tolist() == [2]
    assert node_info(loaded, "p2").to_json()["objects"] == ["O0"]


def test_ids_that_disagree_with_the_document_are_refused(tmp_path):
    graph = make_graph(xyz(0, 1), [0, 0], [[0, 1]], terrain_classes=["sidewalk"])
    graph.places.id = np.array([4, 9])
    path = tmp_path / "bad.terra"
    with BundleWriter(path) as writer:
        write_scene_graph(writer, graph)
        writer.put_array("graph/place_id", np.array([4, 8]))
    with pytest.raises(
        TerraError,
        match=r"scene_graph.json: node ids of symbol 'p' must be those of its id array \(2 listed there\), once each",
    ):
        load_scene_graph(Bundle(path))


def test_spark_dsg_reads_the_nodes_by_their_ids(tmp_path):
    """The export names every node by its id: spark_dsg finds place id 12 (index 2) with its
    position, terrain and parent region id 2; the new bench (id 6) on place id 4."""
    dsg = pytest.importorskip("spark_dsg")
    from terra.interop.spark import export_spark_dsg

    graph = carry_ids(new_graph(), old_graph(), tolerance=0.2)
    path = tmp_path / "ids.terra"
    with BundleWriter(path) as writer:
        write_scene_graph(writer, graph)
    out = tmp_path / "dsg.json"
    export_spark_dsg(Bundle(path), out)
    g = dsg.DynamicSceneGraph.load(str(out))
    place = g.get_node(dsg.NodeSymbol("p", 12).value)
    assert np.allclose(place.attributes.position, [2.0, 0.0, 0.0]) and place.attributes.name == "grass"
    assert place.get_parent() == dsg.NodeSymbol("R", 2).value
    assert g.get_node(dsg.NodeSymbol("p", 13).value).get_parent() == dsg.NodeSymbol("R", 7).value
    assert not g.has_node(dsg.NodeSymbol("p", 2).value)
    bench = g.get_node(dsg.NodeSymbol("O", 6).value)
    assert np.allclose(bench.attributes.position, [4.0, 0.0, 0.0])
    assert g.has_edge(dsg.NodeSymbol("p", 4).value, dsg.NodeSymbol("O", 6).value)
    assert g.has_edge(dsg.NodeSymbol("p", 7).value, dsg.NodeSymbol("p", 3).value)  # indices 0 and 1
