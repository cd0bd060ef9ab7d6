"""Terrain-aware A* planning on hand-made places graphs."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import Delaunay

from terra.errors import NoPathError, TerraError
from terra.tasks.astar import astar
from terra.tasks.planning import CostGraph, TerrainCosts, TerrainRef, plan_path, plan_to_objects, resolve_terrain
from tests.tasks.test_tasks_synthetic import make_graph

SIDEWALK, GRASS, ASPHALT, DIRT, WATER = range(5)


def random_graph(seed: int, n: int = 300):
    """A planar random graph (Delaunay triangulation minus a third of its edges) with costs at
    least the straight-line length, as CSR arrays."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(0, 100, size=(n, 2))
    tri = Delaunay(pos).simplices
    edges = np.unique(np.sort(np.vstack([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [0, 2]]]), axis=1), axis=0)
    edges = edges[rng.random(len(edges)) > 0.33]
    cost = np.linalg.norm(pos[edges[:, 0]] - pos[edges[:, 1]], axis=1) * rng.uniform(1.0, 3.0, len(edges))
    m = sp.coo_matrix(
        (np.r_[cost, cost], (np.r_[edges[:, 0], edges[:, 1]], np.r_[edges[:, 1], edges[:, 0]])), shape=(n, n)
    ).tocsr()
    m.sort_indices()
    return pos, m


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_astar_matches_dijkstra_on_random_graphs(seed):
    pos, m = random_graph(seed)
    rng = np.random.default_rng(100 + seed)
    starts = rng.integers(0, len(pos), 8)
    dist, _ = dijkstra(m, directed=True, indices=starts, return_predecessors=True)
    for row, s in enumerate(starts):
        for g in rng.integers(0, len(pos), 10):
            result = astar(m.indptr, m.indices, m.data, pos, int(s), int(g))
            if not np.isfinite(dist[row, g]):
                assert result is None
                continue
            assert result is not None
            path, cost = result
            assert path[0] == s and path[-1] == g
            # The path uses real edges and its cost is their sum, equal to Dijkstra's optimum.
            edge_costs = [m[a, b] for a, b in zip(path[:-1], path[1:])]
            assert all(c > 0 for c in edge_costs)
            assert cost == pytest.approx(sum(edge_costs), rel=1e-12)
            assert cost == pytest.approx(dist[row, g], rel=1e-9)


def test_astar_reports_unreachable():
    pos = np.array([[0.0, 0], [1, 0], [5, 0]])
    m = sp.csr_matrix((np.array([1.0, 1.0]), (np.array([0, 1]), np.array([1, 0]))), shape=(3, 3))
    assert astar(m.indptr, m.indices, m.data, pos, 0, 2) is None
    assert astar(m.indptr, m.indices, m.data, pos, 2, 2) == ([2], 0.0)


def detour_graph():
    """Start 0 and goal 3 are 10 m apart. The direct route crosses grass (places 1, 2); the detour
    over sidewalk (4, 5, 6) is 2 x 5 m + 10 m = 20 m long.

        4(sw) ---- 5(sw) ---- 6(sw)      y = 5
        |                      |
        0(sw) - 1(gr) - 2(gr) - 3(sw)    y = 0, x = 0, 3.33, 6.67, 10
    """
    pos = [[0, 0], [10 / 3, 0], [20 / 3, 0], [10, 0], [0, 5], [5, 5], [10, 5]]
    terrain = [SIDEWALK, GRASS, GRASS, SIDEWALK, SIDEWALK, SIDEWALK, SIDEWALK]
    edges = [[0, 1], [1, 2], [2, 3], [0, 4], [4, 5], [5, 6], [6, 3]]
    return make_graph(pos, terrain, edges)


def test_plan_without_preferences_takes_the_short_route():
    plan = plan_path(detour_graph(), 0, 3)
    assert plan.places.tolist() == [0, 1, 2, 3]
    assert plan.length_m == pytest.approx(10.0)
    assert plan.cost == pytest.approx(10.0)
    # Segment 0-1 is half sidewalk, half grass; 1-2 all grass; 2-3 half and half.
    assert plan.length_by_terrain == pytest.approx({"sidewalk": 10 / 3, "grass": 20 / 3})
    np.testing.assert_allclose(plan.waypoints[:, :2], [[0, 0], [10 / 3, 0], [20 / 3, 0], [10, 0]])


def test_preference_cost_is_length_times_one_plus_mean_penalty():
    g = detour_graph()
    # Preferring sidewalk with default penalty 1.0 on grass: the direct route costs
    # 10/3 * 1.5 + 10/3 * 2 + 10/3 * 1.5 = 16.67 < 20, so it still wins.
    plan = plan_path(g, 0, 3, prefer=["sidewalk"], default_penalty=1.0)
    assert plan.places.tolist() == [0, 1, 2, 3]
    assert plan.cost == pytest.approx(10 / 3 * 5)
    # The default penalty 5.0: 10/3 * (3.5 + 6 + 3.5) = 43.3 > 20, so the sidewalk detour wins.
    plan = plan_path(g, 0, 3, prefer=["sidewalk"])
    assert plan.places.tolist() == [0, 4, 5, 6, 3]
    assert plan.cost == pytest.approx(20.0)
    # With grass penalty 2.0: 10/3 * (2 + 3 + 2) = 23.3 > 20, so the sidewalk detour wins.
    plan = plan_path(g, 0, 3, prefer=["sidewalk"], penalties={"grass": 2.0})
    assert plan.places.tolist() == [0, 4, 5, 6, 3]
    assert plan.cost == pytest.approx(20.0)
    assert plan.length_by_terrain == pytest.approx({"sidewalk": 20.0})


def bent_path_graph():
    """Three places on one line, 0 (sidewalk) at x = 0, 1 (sidewalk) at x = 4, 2 (grass) at x = 8.
    The GVD path from 0 to 1 bends round a post: 5 m (a 3-4-5 detour); 1 to 2 is straight, 4 m,
    but its weight holds a duplicate edge of 6 m too (the cheaper one is used)."""
    return make_graph([[0, 0], [4, 0], [8, 0]], [SIDEWALK, SIDEWALK, GRASS], [[0, 1], [1, 2], [2, 1]], [5.0, 4.0, 6.0])


def test_cost_is_the_length_along_the_graph_times_one_plus_penalty_and_the_plan_reports_it():
    """By hand: straight segments 4 + 4 = 8 m; along the graph 5 + 4 = 9 m, split half and half
    per edge: sidewalk 5 + 2 = 7 m, grass 2 m. Grass penalty 5 (preferring sidewalk):
    cost = 5 x 1 + 4 x (1 + 5 / 2) = 19 = 7 x (1 + 0) + 2 x (1 + 5)."""
    plan = plan_path(bent_path_graph(), 0, 2, prefer=["sidewalk"])
    assert plan.places.tolist() == [0, 1, 2]
    assert plan.length_m == pytest.approx(8.0)
    assert plan.length_by_terrain == pytest.approx({"sidewalk": 6.0, "grass": 2.0})
    assert plan.edge_length_m == pytest.approx(9.0)
    assert plan.edge_length_by_terrain == pytest.approx({"sidewalk": 7.0, "grass": 2.0})
    assert plan.cost == pytest.approx(19.0)
    assert plan.cost == pytest.approx(
        sum(v * (1 + {"sidewalk": 0, "grass": 5}[k]) for k, v in plan.edge_length_by_terrain.items())
    )
    # With no penalty on its terrains the cost is the length along the graph, not the straight one.
    plain = plan_path(bent_path_graph(), 0, 2)
    assert plain.cost == pytest.approx(9.0) and plain.edge_length_m == pytest.approx(plain.cost)
    report = plan.to_json()
    assert report["edge_length_m"] == pytest.approx(9.0) and report["length_m"] == pytest.approx(8.0)


def test_a_plan_says_which_steps_only_a_bridge_joins():
    """Four sidewalk places on a line, 4 m apart: 0-1 a GVD edge, 1-2 a bridge only (27 m of
    ground the map did not join would be the same), 2-3 a bridge and a GVD edge (the step has an
    edge the map joined). The plan 0 -> 3 takes one bridge step, 4 m; its report and its text say so."""
    from terra.cli.render import render_plan
    from terra.graph.scene_graph import EDGE_BRIDGE
    from terra.tasks.results import PlanEnd, PlanResult

    g = make_graph([[0, 0], [4, 0], [8, 0], [12, 0]], [SIDEWALK] * 4, [[0, 1], [1, 2], [2, 3], [3, 2]])
    g.place_edge_kind = np.array([0, EDGE_BRIDGE, EDGE_BRIDGE, 0])
    plan = plan_path(g, 0, 3)
    assert plan.places.tolist() == [0, 1, 2, 3]
    assert plan.bridges == 1 and plan.bridge_length_m == pytest.approx(4.0)
    assert plan.to_json()["bridges"] == 1 and plan.to_json()["bridge_length_m"] == pytest.approx(4.0)
    result = PlanResult(Path("map.terra"), plan, PlanEnd(0, "place"), PlanEnd(3, "place"), {}, [])
    assert "bridges: 1 step (4.0 m) only a bridge joins" in render_plan(result)
    assert plan_path(g, 0, 1).bridges == 0 and "bridges" not in render_plan(
        PlanResult(Path("map.terra"), plan_path(g, 0, 1), PlanEnd(0, "place"), PlanEnd(1, "place"), {}, [])
    )


def test_forbidden_terrain_is_never_crossed_and_unreachable_goals_say_so():
    g = detour_graph()
    plan = plan_path(g, 0, 3, forbid=["grass"])
    assert plan.places.tolist() == [0, 4, 5, 6, 3]
    assert "grass" not in plan.terrain
    # Cut the detour: the only remaining way is through grass, which is forbidden.
    cut = make_graph(g.places.position, g.places.terrain, [[0, 1], [1, 2], [2, 3], [0, 4], [4, 5]])
    with pytest.raises(NoPathError, match="forbidden terrain \\(grass\\)"):
        plan_path(cut, 0, 3, forbid=["grass"])
    with pytest.raises(NoPathError, match="goal place 2 is on forbidden terrain 'grass'"):
        plan_path(g, 0, 2, forbid=["grass"])
    assert NoPathError.exit_code == 3


def test_bad_terrain_and_place_arguments():
    g = detour_graph()
    with pytest.raises(TerraError, match="unknown terrain 'gras'.*sidewalk, grass"):
        plan_path(g, 0, 3, prefer=["gras"])
    with pytest.raises(TerraError, match="both preferred and forbidden"):
        plan_path(g, 0, 3, prefer=["grass"], forbid=["grass"])
    with pytest.raises(TerraError, match=">= 0"):
        plan_path(g, 0, 3, penalties={"grass": -1})
    with pytest.raises(TerraError, match="goal place 99 does not exist"):
        plan_path(g, 0, 99)
    assert resolve_terrain(g.terrain_classes, "Grass") == GRASS
    assert resolve_terrain(g.terrain_classes, 2) == ASPHALT
    assert resolve_terrain(g.terrain_classes, "4") == WATER


def test_preferred_terrain_overrides_an_explicit_penalty_as_in_reference_task_files():
    costs = TerrainCosts.from_preferences(
        ["sidewalk", "grass", "asphalt"], prefer=[0], penalties={0: 1.0, 1: 5.0}, default_penalty=1.0
    )
    np.testing.assert_allclose(costs.penalty, [0.0, 5.0, 1.0])
    # Without a default given, the other terrains get the configured default (5).
    costs = TerrainCosts.from_preferences(["sidewalk", "grass", "asphalt"], prefer=[0], penalties={1: 2.0})
    np.testing.assert_allclose(costs.penalty, [0.0, 2.0, 5.0])


def test_cost_graph_never_goes_below_straight_line_and_keeps_cheapest_duplicate():
    # Edge 0-1 listed twice (weights 3 and 7) and edge 1-2 with a weight below its length (4 m).
    g = make_graph([[0, 0], [3, 0], [3, 4]], [SIDEWALK] * 3, [[0, 1], [1, 0], [1, 2]], weight=[3.0, 7.0, 1.0])
    cg = CostGraph.build(g, TerrainCosts.from_preferences(g.terrain_classes))
    dense = np.zeros((3, 3))
    for u in range(3):
        for e in range(cg.indptr[u], cg.indptr[u + 1]):
            dense[u, cg.indices[e]] = cg.cost[e]
    np.testing.assert_allclose(dense, [[0, 3, 0], [3, 0, 4], [0, 4, 0]])


def test_plans_under_penalties_are_optimal_against_dijkstra():
    # Every terrain penalised (so the heuristic is scaled by 1 + the smallest penalty) and one
    # forbidden: plan costs equal Dijkstra's on the same cost graph, built independently here.
    pos, m = random_graph(7, n=200)
    rng = np.random.default_rng(7)
    terrain = rng.integers(0, 5, len(pos))
    coo = sp.triu(m).tocoo()
    g = make_graph(pos, terrain, np.column_stack([coo.row, coo.col]), weight=coo.data)
    pen = np.array([0.5, 2.0, 1.0, 3.0, 0.0])
    mult = 1 + (pen[terrain[coo.row]] + pen[terrain[coo.col]]) / 2
    ok = (terrain[coo.row] != WATER) & (terrain[coo.col] != WATER)
    ref = sp.coo_matrix(
        (
            np.r_[coo.data * mult, coo.data * mult][np.r_[ok, ok]],
            (np.r_[coo.row, coo.col][np.r_[ok, ok]], np.r_[coo.col, coo.row][np.r_[ok, ok]]),
        ),
        shape=m.shape,
    ).tocsr()
    dist = dijkstra(ref, directed=True)
    penalties: dict[TerrainRef, float] = {"sidewalk": 0.5, "grass": 2.0, "asphalt": 1.0, "dirt": 3.0}
    checked = 0
    for s, t in rng.integers(0, len(pos), (60, 2)):
        if terrain[s] == WATER or terrain[t] == WATER:
            continue
        if not np.isfinite(dist[s, t]):
            with pytest.raises(NoPathError):
                plan_path(g, int(s), int(t), penalties=penalties, forbid=["water"])
            continue
        plan = plan_path(g, int(s), int(t), penalties=penalties, forbid=["water"])
        assert plan.cost == pytest.approx(dist[s, t], rel=1e-9)
        assert WATER not in terrain[plan.places]
        checked += 1
    assert checked > 20


# ------------------------------------------------------------------ goals from retrieved objects


@dataclass
class Candidate:
    label: str
    score: float
    center: np.ndarray
    place: int


def test_goal_falls_back_to_the_next_candidate_and_reports_the_skipped_one():
    """Two objects for one task on the detour graph, grass forbidden: the best one (score 0.9)
    stands on grass 1 m from place 1 and 3.3 m from the nearest sidewalk place (0), so with a 2 m
    approach radius it has no allowed place; the second (score 0.8) stands by sidewalk place 5."""
    graph = detour_graph()
    costs = TerrainCosts.from_preferences(graph.terrain_classes, forbid=["grass"])
    cost_graph = CostGraph.build(graph, costs)
    best = Candidate("bicycle rack", 0.9, np.array([10 / 3, 1.0, 0.0]), 1)
    second = Candidate("bicycle rack", 0.8, np.array([5.0, 6.0, 0.0]), 5)
    outcome = plan_to_objects(graph, cost_graph, 3, [second, best], radius=2.0)
    assert outcome.goal_object is second and outcome.goal_place == 5
    assert outcome.plan.places.tolist() == [3, 6, 5]
    (skipped,) = outcome.skipped
    assert skipped.object is best and skipped.approach_place == -1
    assert "forbidden terrain 'grass'" in skipped.reason and "2 m" in skipped.reason
    # A 4 m radius reaches sidewalk place 0 from the best object: it wins, nothing is skipped.
    wider = plan_to_objects(graph, cost_graph, 3, [second, best], radius=4.0)
    assert wider.goal_object is best and wider.goal_place == 0 and wider.skipped == []


def test_goal_candidates_that_cannot_be_reached_are_skipped_and_none_reachable_is_no_path():
    """The start is sidewalk place 0 and both candidates sit by grass places 1 and 2 (forbidden, no
    allowed place within 1 m), so no candidate is reachable: NoPathError naming both."""
    graph = detour_graph()
    cost_graph = CostGraph.build(graph, TerrainCosts.from_preferences(graph.terrain_classes, forbid=["grass"]))
    a = Candidate("dumpster", 0.7, np.array([10 / 3, 0.0, 0.0]), 1)
    b = Candidate("dumpster", 0.6, np.array([20 / 3, 0.0, 0.0]), 2)
    with pytest.raises(NoPathError, match=r"no path to any of the 2 objects.*0\.700.*0\.600"):
        plan_to_objects(graph, cost_graph, 0, [b, a], radius=1.0)
    # A place that exists and is allowed but lies in another component is skipped with A*'s reason.
    island = make_graph([[0, 0], [5, 0], [50, 0]], [SIDEWALK, SIDEWALK, SIDEWALK], [[0, 1]])
    far = Candidate("bench", 0.9, np.array([50.0, 0.0, 0.0]), 2)
    near = Candidate("bench", 0.5, np.array([5.0, 0.0, 0.0]), 1)
    outcome = plan_to_objects(
        island, CostGraph.build(island, TerrainCosts.from_preferences(island.terrain_classes)), 0, [far, near], 5.0
    )
    assert outcome.goal_place == 1 and outcome.skipped[0].approach_place == 2
    assert "disconnected" in outcome.skipped[0].reason
    with pytest.raises(TerraError, match="no object matches"):
        plan_to_objects(graph, cost_graph, 0, [], 1.0)
