"""Objects stand on the ground: flat mask bleed is dropped, floating parts join the object below
them or are dropped (terra.tasks.standing), on hand-made clusters and through find_objects."""

from __future__ import annotations

import numpy as np
import pytest

from terra.tasks.config import RetrievalConfig
from terra.tasks.retrieval import find_objects
from terra.tasks.standing import standing_groups
from tests.tasks.test_tasks_synthetic import TERRAINS, box_points, make_graph, make_map

BANK = ["grass", "lamp post", "bench"]
GRASS, LAMP, BENCH = range(3)


def test_flat_clusters_go_floating_parts_join_the_nearest_standing_cluster_or_go():
    pole = box_points((0.0, 0.0, 2.5), (0.2, 0.2, 5.0), 0.0)  # 0 .. 5 m above the ground at z = 0
    head = box_points((1.6, 0.0, 6.0), (0.6, 0.2, 0.2), 0.0)  # 5.9 m up, 1.2 m beyond the pole's top
    slab = box_points((10.0, 0.0, 0.05), (2.0, 1.0, 0.1), 0.0)  # within 0.1 m of the ground
    far_head = box_points((30.0, 0.0, 6.0), (0.6, 0.2, 0.2), 0.0)  # nothing below it within 2 m
    parts = [pole, head, slab, far_head]
    points = np.vstack(parts)
    starts = np.cumsum([0] + [len(p) for p in parts])
    groups = [np.arange(a, b) for a, b in zip(starts[:-1], starts[1:])]
    ground = np.zeros(4)
    out = standing_groups(points, groups, ground, lift=0.15, float_height=1.0, attach_gap=2.0)
    # One object: the pole with its head (the head's nearest point is 1.2 m from the pole's top).
    assert len(out) == 1
    np.testing.assert_array_equal(out[0], np.concatenate([groups[0], groups[1]]))
    # A head 1.2 m away stays out with a 1 m reach (dropped, not an object of its own).
    out = standing_groups(points, groups, ground, attach_gap=1.0)
    assert [g.tolist() for g in out] == [groups[0].tolist()]
    # No float limit: the heads are objects too; an unknown ground keeps every cluster.
    assert len(standing_groups(points, groups, ground, float_height=None)) == 3
    assert len(standing_groups(points, groups, np.full(4, np.nan))) == 4
    # The ground at 5.9 m (a deck the heads rest on): the pole and the slab lie below it and go,
    # the heads (points 0.2 m above it) stand.
    deck = standing_groups(points, groups, np.full(4, 5.9))
    assert [g.tolist() for g in deck] == [groups[1].tolist(), groups[3].tolist()]


def test_a_query_whose_every_cluster_is_flat_keeps_them():
    # Two crosswalk stripes painted on the road (z = 0): nothing of the query rises off the ground,
    # so the clusters are the objects asked for, not mask bleed around a standing one.
    stripes = [box_points((0.0, y, 0.01), (6.0, 0.5, 0.02), 0.0) for y in (0.0, 20.0)]
    points = np.vstack(stripes)
    groups = [np.arange(len(stripes[0])), np.arange(len(stripes[0]), len(points))]
    out = standing_groups(points, groups, np.zeros(2))
    assert [g.tolist() for g in out] == [g.tolist() for g in groups]
    # A standing bench among them makes the stripes bleed again.
    bench = box_points((40.0, 0.0, 0.25), (1.6, 0.6, 0.5), 0.0)
    points = np.vstack([points, bench])
    groups.append(np.arange(len(points) - len(bench), len(points)))
    assert [g.tolist() for g in standing_groups(points, groups, np.zeros(3))] == [groups[2].tolist()]


@pytest.fixture(scope="module")
def lamp_scene(text_embedder):
    """Grass ground (z = 0) with a lamp post whose head DBSCAN (eps 1 m) separates from the pole,
    a bench, a bench-labelled slab on the grass (a mask bled onto it) and a bench-labelled piece
    hanging 3 m up with nothing below it. Places every 5 m on the ground."""
    xs, ys = np.meshgrid(np.arange(0.0, 40.0, 1.0), np.arange(0.0, 40.0, 1.0), indexing="ij")
    ground = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    parts = [
        (ground, GRASS),
        (box_points((10.0, 10.0, 2.5), (0.2, 0.2, 5.0), 0.0), LAMP),
        (box_points((11.6, 10.0, 5.9), (0.6, 0.2, 0.2), 0.0), LAMP),
        (box_points((25.0, 10.0, 0.25), (1.6, 0.6, 0.5), 0.0), BENCH),
        (box_points((20.0, 30.0, 0.02), (2.0, 1.0, 0.04), 0.0), BENCH),
        (box_points((32.0, 30.0, 3.0), (1.0, 0.4, 0.4), 0.0), BENCH),
    ]
    points = np.vstack([p for p, _ in parts])
    observations = [{label: 3} for p, label in parts for _ in range(len(p))]
    msm = make_map(points, observations, text_embedder.embed_text(BANK), text_embedder.embed_text(TERRAINS))
    gx, gy = np.meshgrid(np.arange(0.0, 40.0, 5.0), np.arange(0.0, 40.0, 5.0), indexing="ij")
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
    edges = [[i, j] for i in range(len(xy)) for j in range(i + 1, len(xy)) if np.linalg.norm(xy[i] - xy[j]) == 5.0]
    return msm, make_graph(xy, np.ones(len(xy), dtype=np.int64), edges)


def test_retrieval_keeps_standing_objects_with_their_floating_parts(lamp_scene, text_embedder):
    msm, graph = lamp_scene
    found = find_objects(msm, graph, ["lamp post", "bench"], method="ms-avg", alpha=0.4, embedder=text_embedder)
    lamps = [o for o in found if o.query == 0]
    benches = [o for o in found if o.query == 1]
    # The lamp is one object from the pole (x 9.9) to the head's end (x 11.9), padded 0.1 m a side.
    assert len(lamps) == 1
    assert lamps[0].size[2] == pytest.approx(6.0 + 0.1, abs=0.02)  # ground to 6.0 m, 0.1 m above the top
    assert sorted(lamps[0].size[:2]) == pytest.approx([0.2 + 0.2, 2.0 + 0.2], abs=0.02)
    assert lamps[0].center[:2] == pytest.approx([10.9, 10.0], abs=0.02)
    # Only the standing bench: the slab on the grass and the hanging piece are no objects.
    assert [tuple(np.round(o.center[:2], 3)) for o in benches] == [(25.0, 10.0)]
    # Keeping every cluster (main's behaviour before) finds the head and both bench-coloured pieces.
    every = find_objects(
        msm,
        graph,
        ["lamp post", "bench"],
        method="ms-avg",
        alpha=0.4,
        embedder=text_embedder,
        config=RetrievalConfig(standing_only=False),
    )
    assert sorted(o.query for o in every) == [0, 0, 1, 1, 1]


def test_retrieval_keeps_a_flat_thing_when_nothing_of_its_query_stands(text_embedder):
    """Two crosswalk stripes painted on the grass-level ground and a bench: "crosswalk" finds both
    stripes (nothing of it stands, so they are the objects asked for), "bench" only the bench."""
    bank = ["grass", "crosswalk", "bench"]
    xs, ys = np.meshgrid(np.arange(0.0, 40.0, 1.0), np.arange(0.0, 40.0, 1.0), indexing="ij")
    ground = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    parts = [
        (ground, 0),
        (box_points((10.0, 10.0, 0.01), (6.0, 0.5, 0.02), 0.0), 1),
        (box_points((10.0, 30.0, 0.01), (6.0, 0.5, 0.02), 0.0), 1),
        (box_points((25.0, 10.0, 0.25), (1.6, 0.6, 0.5), 0.0), 2),
        (box_points((30.0, 30.0, 0.02), (2.0, 1.0, 0.04), 0.0), 2),
    ]  # a bench mask bled onto the grass
    points = np.vstack([p for p, _ in parts])
    observations = [{label: 3} for p, label in parts for _ in range(len(p))]
    msm = make_map(points, observations, text_embedder.embed_text(bank), text_embedder.embed_text(TERRAINS))
    gx, gy = np.meshgrid(np.arange(0.0, 40.0, 5.0), np.arange(0.0, 40.0, 5.0), indexing="ij")
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
    graph = make_graph(xy, np.ones(len(xy), dtype=np.int64), [])
    found = find_objects(msm, graph, ["crosswalk", "bench"], method="ms-avg", alpha=0.4, embedder=text_embedder)
    stripes = sorted(o.center[:2].tolist() for o in found if o.query == 0)
    assert len(stripes) == 2  # within a point spacing (0.1 m) of the painted stripes' centres
    assert stripes[0] == pytest.approx([10.0, 10.0], abs=0.1) and stripes[1] == pytest.approx([10.0, 30.0], abs=0.1)
    assert [tuple(np.round(o.center[:2], 3)) for o in found if o.query == 1] == [(25.0, 10.0)]
