"""Measuring terrain preference: the place pairs joined by a route on a terrain, both plans
between them read against a hand-made ground-truth raster, and the case that shows the change."""

from __future__ import annotations

import numpy as np
import pytest

from terra.datasets.ground_truth import TerrainRaster
from terra.eval.navigation import choose_penalty, penalty_sweep, preference_case, preference_routes, terrain_route_pairs
from tests.tasks.test_tasks_planning import detour_graph


def detour_raster() -> TerrainRaster:
    """1 m cells over x in [-2, 12), y in [-2, 8): sidewalk, except a grass lawn x in [1, 9),
    y in [-1, 1) under the direct route of the detour graph."""
    classes = np.zeros((10, 14), dtype=np.int32)
    classes[1:3, 3:11] = 1
    return TerrainRaster(
        classes, np.zeros((10, 14), np.float32), np.array([-2.0, -2.0]), 1.0, {0: "sidewalk", 1: "grass"}
    )


def test_preferring_sidewalk_moves_the_detour_case_onto_it():
    graph, raster = detour_graph(), detour_raster()
    pairs = terrain_route_pairs(graph, raster, "sidewalk")
    # Sidewalk places 0, 3, 4, 5, 6 lie on one sidewalk component around the lawn: all 10 pairs.
    assert pairs.tolist() == [[0, 3], [0, 4], [0, 5], [0, 6], [3, 4], [3, 5], [3, 6], [4, 5], [4, 6], [5, 6]]
    routes = preference_routes(graph, raster, pairs, "sidewalk", step=0.1, default_penalty=1.0)
    case = preference_case(routes, min_share=0.8)
    assert case is not None
    # 0 -> 6: straight over the lawn then north (15 m) or round by 4 and 5 (15 m on sidewalk); the
    # shortest plan (ties broken by A*) crosses 8 m of lawn, preferring sidewalk moves all of it.
    assert pairs[case].tolist() == [0, 6]
    shortest, preferred = routes.shortest[case], routes.preferred[case]
    assert shortest.places.tolist() == [0, 1, 2, 3, 6] and preferred.places.tolist() == [0, 4, 5, 6]
    assert shortest.gt_terrain_m["grass"] == pytest.approx(8.0, abs=0.1)  # 0.1 m pieces on 1 m cells
    assert preferred.gt_terrain_m == pytest.approx({"sidewalk": 15.0})
    # 0 -> 3: the 20 m detour costs more than the 10 m across the lawn even with grass at twice the
    # price per metre (16.7), so the preference leaves that plan as it is.
    first = pairs.tolist().index([0, 3])
    assert routes.preferred[first].places.tolist() == routes.shortest[first].places.tolist() == [0, 1, 2, 3]
    summary = routes.to_json(0.8)
    assert summary["pairs"] == 10 and summary["pairs_meeting"] == 9  # all but 0 -> 3


def test_penalty_sweep_finds_the_smallest_penalty_that_keeps_every_pair_on_the_terrain():
    graph, raster = detour_graph(), detour_raster()
    pairs = terrain_route_pairs(graph, raster, "sidewalk")
    points = penalty_sweep(graph, raster, pairs, "sidewalk", [0.5, 1.0, 2.0, 5.0], min_share=0.8)
    # 0 -> 3 crosses 10 m of lawn-side places (cost 10/3 x (1 + p/2 + 1 + p + 1 + p/2) = 10 + 20p/3)
    # or goes round on sidewalk (20 m): the detour wins once 10 + 20p/3 > 20, i.e. p > 1.5.
    assert [p.meeting for p in points] == [9, 9, 10, 10]
    assert choose_penalty(points) == 2.0
    # The detour doubles that pair's length (20 m for 10 m); no other pair changes length.
    assert points[2].max_detour == pytest.approx(2.0) and points[2].max_extra_m == pytest.approx(10.0)
    assert points[0].max_detour == pytest.approx(1.0)
    # Penalties that move no further pair are never preferred over the smallest that does.
    assert choose_penalty(points[:2]) == 0.5


def test_pairs_need_one_ground_truth_component_and_the_terrain_in_the_graph():
    graph, raster = detour_graph(), detour_raster()
    raster.classes[:, 6] = 1  # a grass strip across the world at x = 4: two sidewalk components
    pairs = terrain_route_pairs(graph, raster, "sidewalk")
    assert pairs.tolist() == [[0, 4], [3, 5], [3, 6], [5, 6]]  # west: 0, 4 (x = 0); east: 5 (x = 5), 3 and 6 (x = 10)
    assert terrain_route_pairs(graph, raster, "dirt").shape == (0, 2)
    assert len(terrain_route_pairs(graph, detour_raster(), "sidewalk", max_pairs=3)) == 3
