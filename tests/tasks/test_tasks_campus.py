"""Phase 3 on the small simulated campus (noise-free map, default build), judged against the
simulator's ground truth: object boxes, named region polygons and the terrain raster."""

from __future__ import annotations

import json

import numpy as np
import pytest
from shapely import contains_xy
from shapely.geometry import Polygon

from terra.cli import run
from terra.eval.metrics.boxes import BoxSet, box_iou
from terra.graph.storage import load_scene_graph
from terra.mapping.storage import load_map
from terra.tasks.monitoring import monitor_region
from terra.tasks.retrieval import best_object, find_objects


@pytest.fixture(scope="module")
def campus(small_graph_bundle, small_campus):
    gt = small_campus.ground_truth()
    return small_graph_bundle, load_map(small_graph_bundle), load_scene_graph(small_graph_bundle), gt


def gt_boxes(gt, name: str) -> list:
    return [o for o in gt.objects if o.class_name == name]


@pytest.mark.parametrize("method", ["ms-avg", "3dsg"])
def test_find_the_dumpster_lands_on_a_dumpster(campus, text_embedder, method):
    _, msm, graph, gt = campus
    dumpsters = np.array([o.center for o in gt_boxes(gt, "dumpster")])
    assert len(dumpsters) > 0
    best = best_object(find_objects(msm, graph, ["find the dumpster"], method=method, embedder=text_embedder))
    assert best is not None
    assert np.min(np.linalg.norm(dumpsters[:, :2] - best.center[:2], axis=1)) < 2.0
    # The object is linked to the place nearest its centre.
    nearest = np.argmin(np.linalg.norm(graph.places.position[:, :2] - best.center[:2], axis=1))
    assert best.place == nearest


@pytest.mark.parametrize("name", ["mailbox", "parking meter"])
def test_every_box_of_a_single_instance_query_overlaps_its_object(campus, text_embedder, name):
    _, msm, graph, gt = campus
    (truth,) = gt_boxes(gt, name)  # the small campus has exactly one
    found = find_objects(msm, graph, [f"find the {name}"], embedder=text_embedder)
    assert found
    for obj in found:
        assert box_iou(BoxSet.from_objects([obj]), BoxSet.from_objects([truth])) > 0.0


def test_two_racks_side_by_side_give_two_boxes_and_dumpster_boxes_face_their_truth(campus, text_embedder):
    """The entrance's two 3.2 m racks stand 3.5 m apart (their base bars 0.3 m apart, one voxel
    layer at ground level): one box each, centred within 0.5 m of its rack (they were one 6.80 x
    1.93 m box). The dumpsters, seen from one corner as an L of two faces, get their true yaw
    within 10 degrees (they were turned about 30 degrees, along the L's hypotenuse)."""
    _, msm, graph, gt = campus
    racks = [o for o in gt_boxes(gt, "bicycle rack") if o.center[1] < 60]  # the building entrance's pair
    assert len(racks) == 2 and abs(racks[0].center[1] - racks[1].center[1]) == pytest.approx(3.5)
    found = find_objects(msm, graph, ["bicycle rack"], embedder=text_embedder)
    for rack in racks:
        near = [o for o in found if np.linalg.norm(o.center[:2] - rack.center[:2]) < 0.5]
        assert len(near) == 1, [np.round(o.center, 2).tolist() for o in found]
        assert near[0].size[0] < 4.0
    dumpsters = gt_boxes(gt, "dumpster")
    assert len(dumpsters) == 2
    found = find_objects(msm, graph, ["dumpster"], embedder=text_embedder)
    for truth in dumpsters:
        box = min(found, key=lambda o: float(np.linalg.norm(o.center[:2] - truth.center[:2])))
        assert np.linalg.norm(box.center[:2] - truth.center[:2]) < 0.5
        turn = (box.yaw - truth.yaw + np.pi / 2) % np.pi - np.pi / 2  # a box is the same turned by 180 degrees
        assert abs(np.degrees(turn)) < 10.0, np.degrees(turn)


def test_monitor_picks_places_inside_the_named_region(campus, text_embedder):
    _, _, graph, gt = campus
    (park,) = [r for r in gt.regions if r.name.startswith("park_")]
    result = monitor_region(graph, park.description, embedder=text_embedder)
    xy = graph.places.position[result.places, :2]
    inside = contains_xy(Polygon(park.polygon), xy[:, 0], xy[:, 1])
    everywhere = contains_xy(Polygon(park.polygon), graph.places.position[:, 0], graph.places.position[:, 1])
    assert len(result.places) >= 5
    # Well above the park's share of all places. Not "mostly inside": the top regions' cosines
    # with the description differ by about 0.01 (class-name mixtures of 20 m of images), so which
    # of the park and its look-alike neighbours (the fields around the campus, the lawns) comes
    # first is close to chance; benchmarks/RESULTS.md (issue 14) measures it over every region.
    assert inside.mean() > 2 * everywhere.mean()


def test_plan_prefers_sidewalk_never_enters_grass_and_reaches_the_goal(campus, capsys):
    bundle, _, graph, gt = campus
    code = run(
        [
            "plan",
            str(bundle.path),
            "--to",
            "get bike from the bicycle rack",
            "--prefer",
            "sidewalk",
            "--forbid",
            "grass",
            "--json",
        ]
    )
    out = capsys.readouterr()
    assert code == 0, out.err
    plan = json.loads(out.out)
    places = [int(p) for p in plan["places"]]
    grass = graph.terrain_classes.index("grass")
    assert all(graph.places.terrain[p] != grass for p in places)
    assert places[-1] == plan["goal"]["place"]
    # Consecutive path places are joined by a place edge of the graph.
    edges = {tuple(sorted(map(int, e))) for e in graph.place_edges}
    assert all(tuple(sorted(pair)) in edges for pair in zip(places, places[1:]))
    # The goal is next to a real bicycle rack.
    racks = np.array([o.center for o in gt_boxes(gt, "bicycle rack")])
    goal_xy = graph.places.position[places[-1], :2]
    assert np.min(np.linalg.norm(racks[:, :2] - goal_xy, axis=1)) < 10.0


def test_unreachable_goal_says_so_with_exit_3(campus, capsys):
    bundle, _, graph, _ = campus
    water = graph.terrain_classes.index("water")
    start = int(np.flatnonzero(graph.places.terrain == water)[0])
    forbid = [t for t in graph.terrain_classes if t != "water"]
    args = ["plan", str(bundle.path), "--to", "get bike from the bicycle rack", "--from-node", str(start)]
    for t in forbid:
        args += ["--forbid", t]
    code = run(args)
    err = capsys.readouterr().err
    assert code == 3
    assert "no path" in err and len(err.strip().splitlines()) == 1
