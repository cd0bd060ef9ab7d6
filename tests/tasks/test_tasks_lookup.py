"""Node and region lookups (terra.tasks.lookup, `terra node`) on the hand-made dumpster lot: places
every 5 m (index 8 i + j at x = 5 i, y = 5 j), grass west of x = 20, region 0 east, region 1 west."""

from __future__ import annotations

import json

import numpy as np
import pytest

from terra.bundle import BundleWriter
from terra.cli import run
from terra.graph.storage import node_symbol
from terra.tasks.lookup import UnknownNode, locate, node_info, parse_node, region_info
from tests.tasks.test_tasks_synthetic import dumpster_lot


@pytest.fixture(scope="module")
def lot(text_embedder, tmp_path_factory):
    from terra.graph.storage import write_scene_graph
    from terra.mapping.storage import write_map

    msm, graph, _ = dumpster_lot(text_embedder)
    path = tmp_path_factory.mktemp("lookup") / "lot.terra"
    with BundleWriter(path) as w:
        write_map(w, msm)
        write_scene_graph(w, graph)
    return path, graph


def test_place_lookup_by_short_and_numeric_id(lot):
    _, graph = lot
    info = node_info(graph, "p9").to_json()
    assert info["kind"] == "place" and info["position"] == [5.0, 5.0, 0.0] and info["terrain"] == "grass"
    assert sorted(n["place"] for n in info["neighbors"]) == [1, 8, 10, 17]
    assert all(n["weight"] == pytest.approx(5.0) for n in info["neighbors"])
    assert info["regions"] == [{"id": "R1", "level": 1, "index": 1}] and info["objects"] == []
    assert info["room"] is None  # a hand-made graph records no room
    graph.places.room = np.full(len(graph.places), 1.25)
    assert node_info(graph, "p9").to_json()["room"] == 1.25
    from terra.cli.render import render_node

    assert "1.25 m from the nearest obstacle" in render_node(node_info(graph, "p9"))
    graph.places.room = np.full(len(graph.places), np.nan)
    assert node_info(graph, str(node_symbol("p", 9))).to_json() == info
    assert parse_node(node_symbol("S", 3)) == ("S", 3)


def test_region_lookup_lists_its_places_and_parent(lot):
    _, graph = lot
    east = region_info(graph, 1, 0).to_json()
    expected = [8 * i + j for i in range(4, 8) for j in range(8)]
    assert east["id"] == "R0" and east["places"] == expected and east["position"] == [30.0, 20.0, 0.0]
    assert east["children"] == [f"p{p}" for p in expected] and east["parent"] == "Z0"
    assert node_info(graph, "R0").to_json() == east
    assert node_info(graph, "Z0").to_json() == {"id": "Z0", "kind": "root", "children": ["R0", "R1"]}


def test_locate_finds_the_nearest_place(lot):
    _, graph = lot
    where = locate(graph, 12.4, 7.6).to_json()
    assert where["place"]["id"] == "p18" and where["distance_m"] == pytest.approx(np.hypot(2.4, 2.4), abs=1e-4)


@pytest.mark.parametrize(
    "ref, error",
    [
        ("p64", UnknownNode),
        ("R2", UnknownNode),
        ("S0", UnknownNode),
        ("O0", UnknownNode),
        ("Q1", UnknownNode),
        ("place9", Exception),
    ],
)
def test_unknown_nodes_are_refused(lot, ref, error):
    _, graph = lot
    with pytest.raises(error):
        node_info(graph, ref)


def test_node_command_prints_the_lookup(lot, capsys):
    path, graph = lot
    assert run(["node", str(path), "p9", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == node_info(graph, "p9").to_json()
    assert run(["node", str(path), "--at", "12.4", "7.6", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == locate(graph, 12.4, 7.6).to_json()
    assert run(["node", str(path), "R1"]) == 0 and "region R1: level 1" in capsys.readouterr().out
    assert run(["node", str(path), "p99"]) == 2
    err = capsys.readouterr().err
    assert "place 99 does not exist" in err and err.count("\n") == 1


@pytest.mark.parametrize(
    "ref", ["123456789012345678901234", "\u00b2", "p\u00b2", "9" * 5000, "-1", str(1 << 64), "p" + "1" * 19]
)
def test_malformed_node_ids_are_one_short_line(lot, ref, capsys):
    path, _ = lot
    assert run(["node", str(path), ref]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "expected a short name" in err and len(err) < 400, err


def test_locate_refuses_coordinates_off_any_map(lot, capsys):
    path, graph = lot
    with pytest.raises(Exception, match="within"):
        locate(graph, 1e308, -1e308)
    assert run(["node", str(path), "--at", "1e308", "-1e308"]) == 2
    assert "within" in capsys.readouterr().err
