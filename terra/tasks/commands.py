"""The task queries on a loaded bundle: find, monitor, plan. One typed request in, one typed result
out (terra.tasks.requests, terra.tasks.results); the CLI, the demo and `terra serve` all call these
with a shared LoadedBundle, so a warm process answers from memory."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from terra.errors import NoPathError, TerraError
from terra.graph.scene_graph import SceneGraph
from terra.loaded import LoadedBundle
from terra.tasks.config import TasksConfig, alpha_for
from terra.tasks.monitoring import monitor_region
from terra.tasks.planning import (
    CostGraph,
    CostGraphs,
    PathPlan,
    TerrainCosts,
    approach_place,
    nearest_allowed_place,
    plan_on,
    plan_to_objects,
)
from terra.tasks.queries import clean_queries
from terra.tasks.requests import FindRequest, MonitorRequest, PlanRequest, PointFeature
from terra.tasks.results import FindResult, MonitorResults, PlanEnd, PlanResult
from terra.tasks.robot import RobotProfile, robot_profile

if TYPE_CHECKING:  # retrieval (SciPy, shapely) is imported by the queries that find objects
    from terra.tasks.retrieval import FoundObject
    from terra.tasks.scoring import PointScorer


# ------------------------------------------------------------ query state kept on the bundle


def point_scorer(loaded: LoadedBundle) -> PointScorer:
    """Per-point cosine scoring of the bundle's map (float32 counts, MS-Avg norms, MS-Max ids),
    built once per loaded bundle."""
    from terra.tasks.scoring import PointScorer

    return loaded.derived("tasks.point_scorer", lambda: PointScorer(loaded.msm))


def cost_graph_of(loaded: LoadedBundle, costs: TerrainCosts, robot: RobotProfile | None = None) -> CostGraph:
    """The places graph under `costs` (and a robot's limits), built once per set of preferences,
    robot and scene graph version."""
    graph = loaded.require_graph("planning")
    return loaded.derived("tasks.cost_graphs", CostGraphs, of_graph=True).get(graph, costs, robot)


def warm(loaded: LoadedBundle) -> None:
    """Load everything a query may need now (a service does this before it listens)."""
    if loaded.has_map:
        _ = point_scorer(loaded).max_ids  # the map and its per-point data
    loaded.warm()


def require_embeddings(loaded: LoadedBundle, what: str) -> None:
    """TerraError when the bundle's map holds no embeddings at all (a LiDAR-only log: no camera
    images and no labelled points to embed), which text queries need."""
    info = loaded.bundle.model.components.map
    if info is not None and not info.bank and not info.images:
        raise TerraError(
            f"{loaded.path}: the map has no image embeddings (no camera images and no labelled points: a LiDAR-only "
            f"log), so {what} has nothing to match text against; plan on it with --from-xy/--from-node and --to-node"
        )


def _with_feature(config: TasksConfig, feature: PointFeature | None) -> TasksConfig:
    if feature is None:
        return config
    return config.model_copy(update={"retrieval": config.retrieval.model_copy(update={"sg_point_feature": feature})})


def _retrieval_alpha(alpha: float | None, config: TasksConfig, loaded: LoadedBundle) -> float:
    """The request's alpha, else the configured one (per embedder, then the default)."""
    if alpha is not None:
        return alpha
    return alpha_for(config.retrieval.alpha, config.retrieval.default_alpha, loaded.embedder_name)


def _find_objects(
    loaded: LoadedBundle, graph: SceneGraph | None, queries: list[str], method: str, alpha: float, config: TasksConfig
) -> list[FoundObject]:
    """Object retrieval with the loaded bundle's map, text embedder and cached scorer."""
    from terra.tasks.retrieval import find_objects

    return find_objects(
        loaded.msm,
        graph,
        queries,
        method=method,
        alpha=alpha,
        config=config,
        embedder=loaded.embedder,
        scorer=point_scorer(loaded),
    )


def find(loaded: LoadedBundle, request: FindRequest, config: TasksConfig | None = None) -> FindResult:
    """Objects for every query of the request, from one embedding batch. With `save`, they replace
    same-label objects in the bundle's scene graph (serialised, atomic: LoadedBundle.update_graph)."""
    from terra.tasks.retrieval import with_objects

    config = _with_feature(config or TasksConfig(), request.point_feature)
    require_embeddings(loaded, "terra find")
    queries = clean_queries(list(request.queries))
    method = request.method or config.retrieval.method
    graph = loaded.require_graph(f"--method {method}") if method == "3dsg" else loaded.graph
    if request.save:
        loaded.require_graph("--save")
    alpha = _retrieval_alpha(request.alpha, config, loaded)
    found = _find_objects(loaded, graph, queries, method, alpha, config)
    if request.save:
        loaded.update_graph(lambda current: with_objects(current, found))
    return FindResult(loaded.path, method, float(alpha), queries, found, saved=request.save)


def monitor(loaded: LoadedBundle, request: MonitorRequest, config: TasksConfig | None = None) -> MonitorResults:
    """Regions and places to monitor for every query of the request."""
    config = config or TasksConfig()
    require_embeddings(loaded, "terra monitor")
    queries = clean_queries(list(request.queries))
    method = request.method or config.monitoring.method
    k = request.k if request.k is not None else config.monitoring.k
    graph = loaded.require_graph("terra monitor")
    alpha = request.alpha
    if alpha is None:
        alpha = alpha_for(config.monitoring.alpha, config.monitoring.default_alpha, loaded.embedder_name)
    results = [
        monitor_region(graph, q, method=method, k=k, alpha=alpha, embedder=loaded.embedder, config=config)
        for q in queries
    ]
    return MonitorResults(loaded.path, method, int(k), float(alpha), results, graph)


# ---------------------------------------------------------------- plan


def _object_place(graph: SceneGraph, obj: FoundObject, allowed: np.ndarray, radius: float, role: str) -> int:
    """The approach place of the object (terra.tasks.planning.approach_place); NoPathError without one."""
    place, why = approach_place(graph, obj, allowed, radius)
    if place < 0:
        raise NoPathError(f"no path: the {role} object {obj.label!r} is at place {obj.place}: {why}")
    return place


_NO_DESTINATION = "give a destination: --to QUERY or --to-node ID (or queries.destination in --tasks)"


def plan(loaded: LoadedBundle, request: PlanRequest, config: TasksConfig | None = None) -> PlanResult:
    """Plan from a start (query, place, xy, or by default the place nearest the first camera pose)
    to the place of the best object for `to` (or to `to_node`). Raises NoPathError when unreachable."""
    config = _with_feature(config or TasksConfig(), request.point_feature)
    if request.to is None and request.to_node is None:
        raise TerraError(_NO_DESTINATION)
    if sum(x is not None for x in (request.from_query, request.from_node, request.from_xy)) > 1:
        raise TerraError("give at most one of --from, --from-node and --from-xy")
    graph = loaded.require_graph("terra plan")
    robot = _robot(request, config)
    costs = plan_costs(graph, request, robot, config.planning.default_penalty)
    cost_graph = cost_graph_of(loaded, costs, robot)
    object_queries = (
        clean_queries([q for q in (request.to, request.from_query) if q is not None])
        if (request.to is not None or request.from_query is not None)
        else []
    )
    found: list[FoundObject] = []
    if object_queries:
        require_embeddings(loaded, "a plan to or from a text query")
        method = request.method or config.planning.find_method
        found = _find_objects(
            loaded, graph, object_queries, method, _retrieval_alpha(request.alpha, config, loaded), config
        )
    start = _start(loaded, graph, request, found, object_queries, cost_graph, config)
    if not 0 <= start.place < len(graph.places):
        raise TerraError(f"start place {start.place} does not exist; the graph has places 0..{len(graph.places) - 1}")
    path, goal = _plan_to_goal(graph, request, found, object_queries, cost_graph, start.place, config)
    penalty = {graph.terrain_classes[t]: float(costs.penalty[t]) for t in range(len(graph.terrain_classes))}
    forbidden = [graph.terrain_classes[t] for t in np.flatnonzero(costs.forbidden)]
    return PlanResult(loaded.path, path, start, goal, penalty, forbidden, robot)


def _robot(request: PlanRequest, config: TasksConfig) -> RobotProfile | None:
    """The request's robot profile, else the configured one, else None."""
    if request.robot is not None:
        return robot_profile(request.robot, "robot")
    if config.planning.robot is not None:
        return robot_profile(config.planning.robot, "tasks.planning.robot")
    return None


def plan_costs(
    graph: SceneGraph, request: PlanRequest, robot: RobotProfile | None, default_penalty: float
) -> TerrainCosts:
    """The terrain costs of a plan: the robot's terrain costs and forbidden terrains (those the map
    has) under the request's preferences, which win (a preferred terrain is never forbidden)."""
    names = {t.lower() for t in graph.terrain_classes}
    penalty: dict[str, float] = {}
    forbid = list(request.forbid)
    if robot is not None:
        penalty = {t: v for t, v in robot.terrain_costs.items() if t.lower() in names}
        preferred = {str(t).lower() for t in request.prefer}
        forbid += [t for t in robot.forbidden_terrain if t.lower() in names and t.lower() not in preferred]
    penalty.update(request.penalty)
    return TerrainCosts.from_preferences(graph.terrain_classes, request.prefer, penalty, forbid, default_penalty)


def _object_for(found: list[FoundObject], queries: list[str], q: int, role: str) -> FoundObject:
    from terra.tasks.retrieval import best_object

    obj = best_object(found, q)
    if obj is None:
        raise TerraError(f"no object matches the {role} query {queries[q]!r}; lower --alpha or rephrase it")
    return obj


def _plan_to_goal(
    graph: SceneGraph,
    request: PlanRequest,
    found: list[FoundObject],
    queries: list[str],
    cost_graph: CostGraph,
    start: int,
    config: TasksConfig,
) -> tuple[PathPlan, PlanEnd]:
    """The path and its goal: `to_node` as given, or every object retrieved for `to`, best score
    first, skipping those with no reachable approach place (terra.tasks.planning.plan_to_objects)."""
    if request.to is None:
        if request.to_node is None:  # plan() refuses such a request first
            raise TerraError(_NO_DESTINATION)
        goal = int(request.to_node)
        if not 0 <= goal < len(graph.places):
            raise TerraError(f"goal place {goal} does not exist; the graph has places 0..{len(graph.places) - 1}")
        return plan_on(graph, cost_graph, start, goal), PlanEnd(goal)
    candidates = [o for o in found if o.query == 0]
    outcome = plan_to_objects(
        graph, cost_graph, start, candidates, config.planning.goal_radius, f"the destination query {queries[0]!r}"
    )
    goal = PlanEnd(
        outcome.goal_place,
        query=request.to,
        object=outcome.goal_object,
        candidates=len(candidates),
        skipped=outcome.skipped,
    )
    return outcome.plan, goal


def _check_start_distance(graph: SceneGraph, xy: np.ndarray, place: int, radius: float) -> None:
    """TerraError when a start point lies farther than `radius` metres from the allowed place it
    would snap to (a typo in a coordinate, or another map's frame), naming that place."""
    if place < 0:
        raise NoPathError("no path: every place is on forbidden terrain")
    nearest = graph.places.position[place, :2]
    distance = float(np.linalg.norm(nearest - xy[:2]))
    if distance > radius:
        raise TerraError(
            f"start ({xy[0]:g}, {xy[1]:g}) is {distance:.1f} m from the nearest allowed place, "
            f"p{place} at ({nearest[0]:.1f}, {nearest[1]:.1f}); starts farther than {radius:g} m "
            "(tasks.planning.start_radius) are refused"
        )


def _start(
    loaded: LoadedBundle,
    graph: SceneGraph,
    request: PlanRequest,
    found: list[FoundObject],
    queries: list[str],
    cost_graph: CostGraph,
    config: TasksConfig,
) -> PlanEnd:
    allowed = cost_graph.allowed
    if request.from_query is not None:
        obj = _object_for(found, queries, len(queries) - 1, "start")
        place = _object_place(graph, obj, allowed, config.planning.goal_radius, "start")
        return PlanEnd(place, f"object for {request.from_query!r}", object=obj)
    if request.from_node is not None:
        return PlanEnd(int(request.from_node), "given place")
    if request.from_xy is not None:
        xy = np.asarray(request.from_xy, dtype=np.float64)
        place = nearest_allowed_place(graph, xy, allowed)
        _check_start_distance(graph, xy, place, config.planning.start_radius)
        return PlanEnd(place, f"nearest allowed place to ({xy[0]:g}, {xy[1]:g})")
    if loaded.has_map and len(loaded.msm.images):
        xy, how = loaded.msm.images.position[0, :2], "nearest allowed place to the first camera pose"
    else:
        raise TerraError("the map records no camera poses; give a start with --from, --from-node or --from-xy")
    place = nearest_allowed_place(graph, xy, allowed)
    if place < 0:
        raise NoPathError("no path: every place is on forbidden terrain")
    return PlanEnd(place, how)
