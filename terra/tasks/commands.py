"""The logic behind `terra find`, `terra monitor` and `terra plan`: load once, answer every query
of the call, return a JSON-ready report. The CLI modules only parse options and print."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from terra.errors import NoPathError, TerraError
from terra.graph.scene_graph import SceneGraph
from terra.perception.text import TextEmbedder
from terra.tasks.config import TasksConfig, alpha_for
from terra.tasks.context import open_for_tasks
from terra.tasks.monitoring import monitor_region
from terra.tasks.planning import CostGraph, TerrainCosts, approach_place, nearest_allowed_place, plan_on, plan_to_objects
from terra.tasks.queries import clean_queries
from terra.tasks.retrieval import FoundObject, best_object, find_objects, with_objects
from terra.tasks.task_file import TaskFile, load_task_file


def load_tasks_config(path: Path | None) -> TasksConfig:
    from terra.config import load_section

    return load_section(path, "tasks")  # type: ignore[return-value]


def _task_file(path: Path | None) -> TaskFile:
    return load_task_file(path) if path is not None else TaskFile()


def _check_alpha(alpha: float | None) -> float | None:
    if alpha is not None and not -1.0 <= alpha <= 1.0:
        raise TerraError(f"--alpha is a cosine similarity threshold in [-1, 1], got {alpha}")
    return alpha


# ---------------------------------------------------------------- find


def find_report(bundle: Path, queries: Sequence[str] = (), method: str | None = None, alpha: float | None = None,
                save: bool = False, tasks: Path | None = None, config: TasksConfig | None = None,
                embedder: TextEmbedder | None = None) -> dict[str, Any]:
    """Objects for every query (command line first, then the task file's), from one map load and
    one embedding batch. With `save`, they replace same-label objects in the bundle's graph."""
    config = config or TasksConfig()
    task_file = _task_file(tasks)
    file_method, feature = task_file.object_method(str(tasks))
    queries = clean_queries(list(queries) + task_file.object_queries())
    method = method or file_method or config.retrieval.method
    if feature is not None:
        config = config.model_copy(update={"retrieval": config.retrieval.model_copy(update={"sg_point_feature": feature})})
    alpha = _check_alpha(alpha if alpha is not None else task_file.alpha)
    ctx = open_for_tasks(bundle, config, need_map=True, need_graph=save or method == "3dsg", embedder=embedder)
    if alpha is None:
        alpha = alpha_for(config.retrieval.alpha, config.retrieval.default_alpha, ctx.embedder.name)
    found = find_objects(ctx.msm, ctx.graph, queries, method=method, alpha=alpha, config=config, embedder=ctx.embedder)
    if save:
        from terra.bundle import BundleWriter
        from terra.graph.storage import write_scene_graph

        graph = with_objects(ctx.require_graph("--save"), found)
        writer = BundleWriter(ctx.path, base=ctx.bundle)
        try:
            write_scene_graph(writer, graph)
            writer.commit()
        except BaseException:
            writer.abort()
            raise
    return {
        "bundle": str(ctx.path),
        "method": method,
        "alpha": alpha,
        "queries": queries,
        "objects": [dict(id=i, **o.to_json()) for i, o in enumerate(found)],
        "saved": bool(save),
    }


def format_find(report: dict[str, Any]) -> str:
    lines = [f"{len(report['objects'])} objects for {len(report['queries'])} queries "
             f"(method {report['method']}, alpha {report['alpha']:.3f})"]
    for q, query in enumerate(report["queries"]):
        mine = [o for o in report["objects"] if o["query"] == q]
        lines.append(f"{query!r}: {len(mine)} objects")
        for o in mine:
            c, s = o["center"], o["size"]
            lines.append(f"  #{o['id']:<3d} score {o['score']:.3f}  centre ({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}) m  "
                         f"size {s[0]:.2f} x {s[1]:.2f} x {s[2]:.2f} m  yaw {np.degrees(o['yaw']):6.1f} deg  "
                         f"{o['point_count']} points  place {o['place']}")
    if report["saved"]:
        lines.append(f"saved {len(report['objects'])} objects to the scene graph of {report['bundle']}")
    return "\n".join(lines)


# ---------------------------------------------------------------- monitor


def monitor_report(bundle: Path, queries: Sequence[str] = (), method: str | None = None, k: int | None = None,
                   alpha: float | None = None, tasks: Path | None = None, config: TasksConfig | None = None,
                   embedder: TextEmbedder | None = None) -> dict[str, Any]:
    """Regions and places to monitor for every query (command line first, then the task file's)."""
    config = config or TasksConfig()
    task_file = _task_file(tasks)
    queries = clean_queries(list(queries) + task_file.region_queries())
    method = method or task_file.region_method(str(tasks)) or config.monitoring.method
    k = k if k is not None else (task_file.k or config.monitoring.k)
    alpha = _check_alpha(alpha if alpha is not None else task_file.alpha)
    ctx = open_for_tasks(bundle, config, need_map=False, need_graph=True, embedder=embedder)
    graph = ctx.require_graph("terra monitor")
    if alpha is None:
        alpha = alpha_for(config.monitoring.alpha, config.monitoring.default_alpha, ctx.embedder.name)
    results = [monitor_region(graph, q, method=method, k=k, alpha=alpha, embedder=ctx.embedder, config=config).to_json(graph)
               for q in queries]
    return {"bundle": str(ctx.path), "method": method, "k": k, "alpha": alpha, "results": results}


def format_monitor(report: dict[str, Any]) -> str:
    lines = []
    for r in report["results"]:
        lines.append(f"{r['query']!r} (method {report['method']}, k {report['k']}, alpha {report['alpha']:.3f}): "
                     f"{len(r['regions'])} regions, {len(r['places'])} places")
        for g in r["regions"]:
            p = g["position"]
            lines.append(f"  region level {g['level']} #{g['index']}  score {g['score']:.3f}  "
                         f"centre ({p[0]:.1f}, {p[1]:.1f}) m  {g['place_count']} places")
        for c, members in enumerate(r.get("clusters", [])):
            lines.append(f"  cluster {c}: {len(members)} places")
        if r["places"]:
            xy = np.array([p["position"][:2] for p in r["places"]])
            lines.append(f"  places: {' '.join(str(p['place']) for p in r['places'])}")
            lines.append(f"  extent x {xy[:, 0].min():.1f}..{xy[:, 0].max():.1f} m, y {xy[:, 1].min():.1f}..{xy[:, 1].max():.1f} m")
    return "\n".join(lines)


# ---------------------------------------------------------------- plan


def parse_penalties(items: Sequence[str]) -> dict[str, float]:
    """["grass=5", "dirt=2.5"] -> {"grass": 5.0, "dirt": 2.5}; TerraError on a malformed item."""
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            if not sep or not name.strip():
                raise ValueError
            out[name.strip()] = float(value)
        except ValueError:
            raise TerraError(f"--penalty expects TERRAIN=WEIGHT (e.g. grass=5), got {item!r}") from None
    return out


def _object_place(graph: SceneGraph, obj: FoundObject, allowed: np.ndarray, radius: float, role: str) -> int:
    """The approach place of the object (terra.tasks.planning.approach_place); NoPathError without one."""
    place, why = approach_place(graph, obj, allowed, radius)
    if place < 0:
        raise NoPathError(f"no path: the {role} object {obj.label!r} is at place {obj.place}: {why}")
    return place


def plan_report(bundle: Path, to: str | None = None, to_node: int | None = None, from_query: str | None = None,
                from_node: int | None = None, from_xy: tuple[float, float] | None = None, prefer: Sequence[str] = (),
                penalty: Sequence[str] = (), forbid: Sequence[str] = (), method: str | None = None,
                alpha: float | None = None, tasks: Path | None = None, config: TasksConfig | None = None,
                embedder: TextEmbedder | None = None) -> dict[str, Any]:
    """Plan from a start (query, place, xy, or by default the place nearest the first camera pose)
    to the place of the best object for `to` (or to `to_node`). Raises NoPathError when unreachable."""
    config = config or TasksConfig()
    task_file = _task_file(tasks)
    prefs = task_file.terrain_preferences
    dest, start = task_file.queries.destination, task_file.queries.start
    if to is None and to_node is None:
        to, to_node = (None, dest) if isinstance(dest, int) else (dest, None)
    if from_query is None and from_node is None and from_xy is None:
        from_query, from_node = (None, start) if isinstance(start, int) else (start, None)
    if to is None and to_node is None:
        raise TerraError("give a destination: --to QUERY or --to-node ID (or queries.destination in --tasks)")
    if sum(x is not None for x in (from_query, from_node, from_xy)) > 1:
        raise TerraError("give at most one of --from, --from-node and --from-xy")
    file_method, feature = task_file.object_method(str(tasks))
    method = method or file_method or config.planning.find_method
    if feature is not None:
        config = config.model_copy(update={"retrieval": config.retrieval.model_copy(update={"sg_point_feature": feature})})
    alpha = _check_alpha(alpha if alpha is not None else task_file.alpha)
    object_queries = [q for q in (to, from_query) if q is not None]
    if object_queries:
        object_queries = clean_queries(object_queries)
    need_map = bool(object_queries) or (from_node is None and from_xy is None)
    ctx = open_for_tasks(bundle, config, need_map=need_map, need_graph=True, embedder=embedder,
                         need_embedder=bool(object_queries))
    graph = ctx.require_graph("terra plan")

    penalties: dict[Any, float] = {**prefs.penalties, **parse_penalties(penalty)}
    costs = TerrainCosts.from_preferences(graph.terrain_classes, list(prefs.preferred) + list(prefer), penalties,
                                          list(prefs.forbidden) + list(forbid), config.planning.default_penalty)
    cost_graph = CostGraph.build(graph, costs)
    allowed = cost_graph.allowed
    found: list[FoundObject] = []
    if object_queries:
        found = find_objects(ctx.msm, graph, object_queries, method=method, alpha=alpha, config=config, embedder=ctx.embedder)

    def object_for(q: int, role: str) -> FoundObject:
        obj = best_object(found, q)
        if obj is None:
            raise TerraError(f"no object matches the {role} query {object_queries[q]!r}; lower --alpha or rephrase it")
        return obj

    goal_object = start_object = None
    if to is None:
        goal = int(to_node)
    if from_query is not None:
        start_object = object_for(len(object_queries) - 1, "start")
        start = _object_place(graph, start_object, allowed, config.planning.goal_radius, "start")
        start_how = f"object for {from_query!r}"
    elif from_node is not None:
        start, start_how = int(from_node), "given place"
    else:
        if from_xy is not None:
            xy, start_how = np.asarray(from_xy, dtype=np.float64), f"nearest allowed place to ({from_xy[0]:g}, {from_xy[1]:g})"
        elif ctx.msm is not None and len(ctx.msm.images):
            xy, start_how = ctx.msm.images.position[0, :2], "nearest allowed place to the first camera pose"
        else:
            raise TerraError("the map records no camera poses; give a start with --from, --from-node or --from-xy")
        start = nearest_allowed_place(graph, xy, allowed)
        if start < 0:
            raise NoPathError("no path: every place is on forbidden terrain")
    for place, role in ((start, "start"), (None if to is not None else goal, "goal")):
        if place is not None and not 0 <= place < len(graph.places):
            raise TerraError(f"{role} place {place} does not exist; the graph has places 0..{len(graph.places) - 1}")
    skipped: list = []
    if to is not None:
        # Every object retrieved for the destination is a candidate, best score first.
        candidates = [o for o in found if o.query == 0]
        outcome = plan_to_objects(graph, cost_graph, start, candidates, config.planning.goal_radius,
                                  f"the destination query {object_queries[0]!r}")
        plan, goal_object, goal, skipped = outcome.plan, outcome.goal_object, outcome.goal_place, outcome.skipped
    else:
        plan = plan_on(graph, cost_graph, start, goal)
    report: dict[str, Any] = {"bundle": str(ctx.path), **plan.to_json()}
    report["start"] = {"place": start, "how": start_how, "object": start_object.to_json() if start_object else None}
    report["goal"] = {"place": goal, "query": to, "object": goal_object.to_json() if goal_object else None,
                      "candidates": len([o for o in found if o.query == 0]) if to is not None else 0,
                      "skipped": [s.to_json() for s in skipped]}
    report["preferences"] = {
        "penalty": {graph.terrain_classes[t]: float(costs.penalty[t]) for t in range(len(graph.terrain_classes))},
        "forbidden": [graph.terrain_classes[t] for t in np.flatnonzero(costs.forbidden)],
    }
    return report


def format_plan(report: dict[str, Any]) -> str:
    goal, start = report["goal"], report["start"]
    lines = []
    if goal["object"] is not None:
        o = goal["object"]
        c = o["center"]
        lines.append(f"goal: {goal['query']!r} -> object at ({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}) m, score {o['score']:.3f}, "
                     f"place {goal['place']}")
    else:
        lines.append(f"goal: place {goal['place']}")
    for sk in goal.get("skipped", []):
        c = sk["center"]
        lines.append(f"  skipped {sk['label']!r} at ({c[0]:.2f}, {c[1]:.2f}) m, score {sk['score']:.3f}: {sk['reason']}")
    lines.append(f"start: place {start['place']} ({start['how']})")
    forbidden = report["preferences"]["forbidden"]
    penalised = {k: v for k, v in report["preferences"]["penalty"].items() if v > 0}
    if penalised or forbidden:
        lines.append("terrain: " + ", ".join([f"{k} penalty {v:g}" for k, v in penalised.items()] + [f"{k} forbidden" for k in forbidden]))
    by_terrain = ", ".join(f"{k} {v:.1f} m" for k, v in report["length_by_terrain"].items())
    lines.append(f"path: {len(report['places'])} places, {report['length_m']:.1f} m ({by_terrain}), cost {report['cost']:.1f}")
    for i, (p, w, t) in enumerate(zip(report["places"], report["waypoints"], report["terrain"])):
        lines.append(f"  {i:3d}  place {p:<6d} ({w[0]:8.2f}, {w[1]:8.2f}, {w[2]:6.2f})  {t}")
    return "\n".join(lines)

