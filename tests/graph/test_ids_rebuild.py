"""Ids kept across two builds of a bundle (`terra build` over a graph it built before): a hand-made
two-part map, a 60 m x 8 m dirt strip in the west and a patch 10 m east of it, whose second version
differs only in the east patch (30 m of grass, then 15 m of asphalt). Places are ordered by terrain
and grass and asphalt come before dirt, so the west places move to other indices; they must keep
their ids exactly, and the east ones get fresh ids above every id given before."""

from __future__ import annotations

import json

import numpy as np
import pytest

from terra.bundle import MANIFEST, Bundle, BundleWriter
from terra.cli import run
from terra.graph.pipeline import run_build
from terra.graph.storage import load_scene_graph
from terra.loaded import LoadedBundle
from terra.mapping.storage import write_map
from terra.tasks.retrieval import FoundObject, with_objects
from tests.tasks.test_tasks_synthetic import BANK, TERRAINS, make_map

WEST_END = 60.0  # metres: the west strip spans x 0..60, the east patch x 70..100


def two_part_map(text_embedder, east_terrain: str, east_length: float):
    """Points every 0.2 m on both parts (z = 0), every point voting for its part's terrain."""
    xs, ys = np.meshgrid(np.arange(0.0, WEST_END, 0.2), np.arange(0.0, 8.0, 0.2), indexing="ij")
    west = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    east = west[west[:, 0] < east_length] + [70.0, 0.0, 0.0]
    points = np.vstack([west, east])
    msm = make_map(points, [{}] * len(points), text_embedder.embed_text(BANK), text_embedder.embed_text(TERRAINS))
    votes = np.zeros((len(points), len(TERRAINS)), dtype=np.uint16)
    votes[: len(west), TERRAINS.index("dirt")] = 5
    votes[len(west) :, TERRAINS.index(east_terrain)] = 5
    msm.terrain_votes = votes
    return msm


def put_map(path, msm) -> None:
    base = Bundle(path) if path.exists() else None
    with BundleWriter(path, base=base) as writer:
        write_map(writer, msm)


@pytest.fixture(scope="module")
def rebuilt(text_embedder, tmp_path_factory):
    """The graphs of the first build (grass east) and of the rebuild (asphalt east)."""
    path = tmp_path_factory.mktemp("ids") / "two_part.terra"
    put_map(path, two_part_map(text_embedder, "grass", 30.0))
    run_build(path, show_progress=False)
    # `terra find --save` stores two benches on the first graph (ids 0, 1).
    benches = [bench(10.0, 2.0, 0.9), bench(75.0, 2.0, 0.8)]
    first = LoadedBundle(path).update_graph(lambda graph: with_objects(graph, benches))
    put_map(path, two_part_map(text_embedder, "asphalt", 15.0))
    assert run(["build", str(path), "--overwrite", "--quiet"]) == 0  # the CLI rebuilds over the stored graph
    return path, first, load_scene_graph(Bundle(path))


def bench(x: float, y: float, score: float) -> FoundObject:
    return FoundObject(np.array([x, y, 0.5]), np.ones(3), 0.0, 0, "bench", score, np.ones(1), 10, 0, np.arange(3))


def position_key(position: np.ndarray) -> tuple[float, float]:
    return (round(float(position[0]), 3), round(float(position[1]), 3))


def test_places_far_from_the_change_keep_their_ids(rebuilt):
    _, first, second = rebuilt
    west_first = first.places.position[:, 0] < WEST_END
    west_second = second.places.position[:, 0] < WEST_END
    assert west_first.sum() >= 5 and (~west_first).sum() >= 2
    # A first build numbers the places by index; the west strip is built again to the same places,
    # so each keeps the index it had in the first build, found here by its position.
    first_index = {position_key(p): i for i, p in enumerate(first.places.position)}
    expected = [first_index[position_key(p)] for p in second.places.position[west_second]]
    assert first.places.id.tolist() == list(range(len(first.places)))
    assert second.places.id[west_second].tolist() == expected
    assert sorted(expected) == np.flatnonzero(west_first).tolist()
    assert expected != np.flatnonzero(west_second).tolist()  # the indices did move


def test_places_of_the_changed_area_get_fresh_ids_never_reused(rebuilt):
    path, first, second = rebuilt
    east = second.places.position[:, 0] > WEST_END
    assert {second.terrain_classes[t] for t in second.places.terrain[east]} == {"asphalt"}
    fresh = second.places.id[east]
    # Fresh ids count up from the first build's place count, in index order.
    assert fresh.tolist() == list(range(len(first.places), len(first.places) + int(east.sum())))
    assert not set(fresh.tolist()) & set(first.places.id.tolist())
    assert second.next_ids()["p"] == len(first.places) + int(east.sum())
    # 9 west places, 5 east ones in the first build and 2 in the second. One region a level in both
    # builds, sharing the 9 west places: Jaccard 9 / (14 + 11 - 9) = 0.5625 >= 0.5, so each level's
    # region keeps its id 0, and the next free region id stays 1.
    assert (int((~east).sum()), len(first.places), len(second.places)) == (9, 14, 11)
    assert [len(level) for level in first.regions] == [len(level) for level in second.regions] == [1, 1, 1, 1]
    assert [level.id.tolist() for level in second.regions] == [[0]] * 4
    assert [second.next_ids()[c] for c in "RSTU"] == [1, 1, 1, 1]


def test_saved_objects_survive_the_rebuild_with_their_ids(rebuilt):
    _, first, second = rebuilt
    assert first.objects.id.tolist() == [0, 1] and second.objects.id.tolist() == [0, 1]
    assert second.objects.label == ["bench", "bench"] and np.allclose(second.objects.center[:, 0], [10.0, 75.0])
    # Each is linked to its nearest place of the new graph (2-D).
    for center, place in zip(second.objects.center, second.objects.place):
        d = np.linalg.norm(second.places.position[:, :2] - center[:2], axis=1)
        assert d[place] == d.min()
    assert second.next_ids()["O"] == 2


def test_a_rebuild_of_the_same_map_keeps_every_id(rebuilt):
    path, _, second = rebuilt
    again = run_build(path, show_progress=False).graph
    assert again.places.id.tolist() == second.places.id.tolist()
    assert [level.id.tolist() for level in again.regions] == [level.id.tolist() for level in second.regions]
    assert again.next_ids() == second.next_ids()


def test_a_graph_that_cannot_be_read_is_rebuilt_with_fresh_ids(text_embedder, tmp_path):
    """A rebuild replaces an unsupported or damaged graph (what `terra build --overwrite` is for):
    it cannot carry ids from it, so the ids are the indices again."""
    path = tmp_path / "old.terra"
    put_map(path, two_part_map(text_embedder, "grass", 30.0))
    run_build(path, show_progress=False)
    manifest = json.loads((path / MANIFEST).read_text())
    manifest["components"]["graph"]["format"] = 0
    (path / MANIFEST).write_text(json.dumps(manifest))
    graph = run_build(path, show_progress=False).graph
    assert graph.places.id.tolist() == list(range(len(graph.places))) and len(graph.objects) == 0
    assert load_scene_graph(Bundle(path)).places.id.tolist() == graph.places.id.tolist()
