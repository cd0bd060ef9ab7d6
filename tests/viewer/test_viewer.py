"""`terra view`: the drawn layers computed by hand, the viewer's queries equal the typed task API
on a fresh load, a busy port is one clear line, and the page in a real headless browser shows the
scene, answers a query typed into it, and screenshots as a picture."""

from __future__ import annotations

import socket

import numpy as np
import pytest

from terra.cli import run
from terra.graph.storage import load_scene_graph
from terra.loaded import LoadedBundle
from terra.tasks.commands import find, plan, point_scorer
from terra.tasks.requests import FindRequest, PlanRequest
from terra.viewer import scene
from terra.viewer.browser import browser_missing

viser = pytest.importorskip("viser")


def test_display_subset_is_bounded_fixed_and_sorted():
    a, b = scene.display_subset(10_000, 1_000), scene.display_subset(10_000, 1_000)
    assert np.array_equal(a, b) and len(a) == 1_000 and np.all(np.diff(a) > 0)
    assert np.array_equal(scene.display_subset(500, 1_000), np.arange(500))


def test_a_click_ray_picks_the_place_under_it(interop_bundle):
    graph = load_scene_graph(interop_bundle)
    ground = float(np.median(graph.places.position[:, 2]))
    target = graph.places.position[7]
    origin = np.array([target[0] - 30.0, target[1] + 10.0, ground + 40.0])
    direction = np.array([target[0], target[1], ground]) - origin
    assert scene.ray_place(graph, origin, direction / np.linalg.norm(direction)) == 7
    assert scene.ray_place(graph, origin, np.array([0.0, 0.0, 1.0])) == -1  # looking up


def test_region_layers_link_each_region_to_its_children(interop_bundle):
    graph = load_scene_graph(interop_bundle)
    layers = scene.region_layers(graph)
    assert [layer.level for layer in layers] == [level.level for level in graph.regions]
    first = layers[0]
    assert first.segments.shape == (len(graph.places), 2, 3)
    for place in (0, 11, 40):
        parent = graph.regions[0].parent_of_child[place]
        assert np.allclose(first.segments[place, 0], first.position[parent])
        assert np.allclose(first.segments[place, 1], graph.places.position[place])
    assert (layers[1].position[:, 2] > first.position[:, 2].max()).all()


def test_yaw_quaternion_turns_x_towards_y():
    w, x, y, z = scene.yaw_wxyz(np.pi / 2)
    # Rotating (1, 0, 0) by q: for a rotation about z the image is (cos, sin, 0) of the angle.
    angle = 2 * np.arctan2(z, w)
    assert np.allclose([np.cos(angle), np.sin(angle)], [0.0, 1.0]) and x == y == 0.0
    assert scene.parse_end(" 12 ") == ("node", 12) and scene.parse_end("bench") == ("query", "bench")
    assert scene.parse_end("") == ("default", None)


@pytest.fixture(scope="module")
def viewer(interop_bundle, text_embedder):
    from terra.viewer.app import TerraViewer, free_port

    v = TerraViewer(LoadedBundle(interop_bundle.path, embedder=text_embedder), port=free_port("127.0.0.1"))
    yield v
    v.stop()


def test_viewer_queries_equal_the_task_api_on_a_fresh_load(viewer, interop_bundle, text_embedder):
    text = viewer.run_query("find", "bench")
    fresh = find(LoadedBundle(interop_bundle.path, embedder=text_embedder), FindRequest(queries=["bench"]))
    assert [o.to_json() for o in viewer.last_result.objects] == [o.to_json() for o in fresh.objects]
    assert text.startswith(f"**{len(fresh.objects)} objects**")
    summary = viewer.run_plan("2", "30", prefer="sidewalk")
    expected = plan(LoadedBundle(interop_bundle.path), PlanRequest(from_node=2, to_node=30, prefer=["sidewalk"])).plan
    assert f"{expected.length_m:.1f} m over {len(expected.places)} places" in summary
    assert "No path" in viewer.run_plan("2", "30", forbid="sidewalk,grass,asphalt")
    # A user error in the GUI is shown in its panel (one line), never raised into viser's thread.
    viewer._guarded(lambda: viewer.run_plan("2", "30", prefer="lava"), viewer.plan_answer)
    assert viewer.plan_answer.content.startswith("**Error:** unknown terrain &#x27;lava&#x27;")


def test_colour_modes_colour_the_drawn_points(viewer):
    viewer.colour_mode.value = "MS-Max class"
    viewer.recolour()
    ids = point_scorer(viewer.loaded).max_ids[viewer.rows]
    colours = np.asarray(viewer.points.colors)
    assert (colours[ids < 0] == scene.UNOBSERVED).all() and not (colours[ids >= 0] == scene.UNOBSERVED).all(
        axis=1
    ).all()
    viewer.colour_mode.value = "similarity"
    viewer.similarity_text.value = "bench"
    viewer.recolour()
    assert "cosine" in viewer.legend.content
    viewer.colour_mode.value = "terrain"
    viewer.recolour()
    assert np.array_equal(np.asarray(viewer.points.colors), scene.terrain_point_colours(viewer.msm, viewer.rows))


def test_a_busy_port_is_one_line_naming_it_and_another(interop_bundle, capsys):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert run(["view", str(interop_bundle.path), "--port", str(port)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"port {port} on 127.0.0.1 is in use; try --port " in err[0]
    suggested = int(err[0].rsplit(" ", 1)[1])
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", suggested))  # the suggestion was free


@pytest.mark.slow
@pytest.mark.skipif(browser_missing() is not None, reason=str(browser_missing()))
def test_the_page_shows_the_scene_answers_a_query_and_screenshots(viewer, tmp_path, interop_bundle, text_embedder):
    from PIL import Image

    from terra.viewer.browser import HeadlessPage

    page = HeadlessPage(viewer.url)
    try:
        page.wait_for_text(f"{len(viewer.msm):,} points")
        assert len(viewer.server.get_clients()) >= 1  # the scene went out over the page's websocket
        page.type_into("query", "trash can")
        page.click("Run query")
        text = page.wait_for_text("objects for")
        fresh = find(LoadedBundle(interop_bundle.path, embedder=text_embedder), FindRequest(queries=["trash can"]))
        assert f"{len(fresh.objects)} objects for “trash can”" in text
        assert [o.to_json() for o in viewer.last_result.objects] == [o.to_json() for o in fresh.objects]
        page.dismiss_notifications()
        shot = page.screenshot(tmp_path / "viewer.png")
    finally:
        page.close()
    pixels = np.asarray(Image.open(shot).convert("RGB")).reshape(-1, 3)
    colours, counts = np.unique(pixels, axis=0, return_counts=True)
    assert len(colours) > 50 and counts.max() < 0.9 * len(pixels)
