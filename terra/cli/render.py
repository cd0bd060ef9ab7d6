"""Text renderings of the typed results of every command: the stages (`terra map/build/eval/sim/
import/export`) and the task queries (`terra find/monitor/plan/node`). Their `--json` is the
result's `to_json()` (for the queries, the same JSON `terra serve` answers with)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from terra.words import counted

if TYPE_CHECKING:  # every cli module is imported for `terra --help`: keep this one light
    from terra.eval.results import EvalResult, GroundTable, TerrainTable, TuneResult
    from terra.graph.results import BuildResult
    from terra.interop.results import ExportResult, ImportResult
    from terra.mapping.changes import ChangesResult
    from terra.mapping.results import ClusterSummary, MapResult, OdometrySummary, PerceptionResult
    from terra.sim.results import SimResult
    from terra.tasks.lookup import Location, NodeInfo
    from terra.tasks.results import FindResult, MonitorResults, PlanResult


def render_json(result: Any) -> str:
    return json.dumps(result.to_json(), indent=1)


def render_stage_json(result: Any) -> str:
    """A stage's `--json`: its result's `to_json()`, keys sorted."""
    return json.dumps(result.to_json(), indent=1, sort_keys=True)


# ------------------------------------------------------------------------------------ the stages
def render_build(result: BuildResult) -> str:
    """The summary `terra build` prints: places, edges, regions, embeddings, grid, timings."""
    stats, edges, src = result.stats, result.stats.edges, result.stats.embedding_source
    per_terrain = ", ".join(f"{k} {v}" for k, v in stats.places_per_terrain.items())
    lines = [
        f"graph: {counted(result.places, 'place')} ({per_terrain}) -> {result.bundle}",
        f"  place edges: {result.place_edges} (gvd {edges.gvd}, cross-terrain {edges.cross_terrain}, "
        f"bridge {edges.bridge}, level route {edges.level_route})",
        f"  regions ({result.region_method}): " + " / ".join(str(n) for n in result.regions_per_level) + " per level",
        f"  place embeddings: {src.images} from images, {src.points} from points, "
        f"{src.terrain_text} from the terrain name",
    ]
    if src.images == 0 and src.points:
        lines.append("  (the map has no images: place embeddings come from the map points instead)")
    if stats.step_line_cells is not None:
        lines.append(
            f"  ground split at lines of steps ({counted(stats.step_line_cells, 'cell')}): places keep to each "
            "level and meet where the ground is level (build.ground.barrier_step)"
        )
    cells = stats.grid_cells
    lines.append(
        f"  terrain grid: {cells[0]} x {cells[1]} cells, computed {_grid_where(result)}; GVD {_gvd_where(result)}"
    )
    if result.timer is not None:
        lines.append(result.timer.table())
    return "\n".join(lines)


def _grid_where(result: BuildResult) -> str:
    tiles = result.stats.grid_tiles
    if tiles is None:
        return "in one piece"
    if tiles.one_piece:
        return f"in one piece ({tiles.one_piece})"
    size = f"{result.tile_size_m:g} m " if result.tile_size_m is not None else ""
    return f"in {size}tiles ({tiles.windows} windows, overlap up to {tiles.max_overlap_m:g} m)"


def _gvd_where(result: BuildResult) -> str:
    tiles = result.stats.gvd_tiles
    if tiles is None:
        return "in one piece"
    return f"in tiles ({tiles.windows} windows, overlap up to {tiles.max_overlap_m:g} m)"


def render_map(result: MapResult | PerceptionResult) -> str:
    """The summary `terra map` prints (a map written, or with --perception-only the cache filled)."""
    from terra.mapping.results import PerceptionResult

    if isinstance(result, PerceptionResult):
        return _render_perception(result)
    counts, lines = result.counts, []
    if result.resumed_from:
        lines.append(f"resumed after frame {result.resumed_from}")
    lines.append(
        f"map: {counted(counts.points, 'point')} ({counts.observed_points} with object observations), "
        f"{counted(counts.bank, 'bank entry', 'bank entries')}, {counted(counts.images, 'image')} "
        f"-> {result.bundle}"
    )
    if result.session is not None:
        lines.append(session_line(result.session, "joined as "))
    if result.cluster is not None:
        lines.append(_cluster_line(result.cluster))
    if result.cache is not None:
        cache = result.cache
        where = "removed: the config keeps no cache" if cache.removed else cache.folder
        lines.append(f"perception cache: {counted(cache.hits, 'image')} read back, {cache.computed} computed ({where})")
    if result.pose_source:
        lines.append(f"  poses: {result.pose_source}")
    lines += _fault_lines(result.stats, result.notes)
    if result.odometry is not None:
        lines.append(_odometry_line(result.odometry))
    if result.timer is not None:
        lines.append(result.timer.table())
    return "\n".join(lines)


def session_line(session: dict, head: str = "") -> str:
    """One session of a map (terra/mapping/sessions.py:session_list): its number, source, frames, time span,
    T_map_session as x, y, z and yaw, how it was found and its fit."""
    import numpy as np

    T = np.asarray(session.get("T_map_session", np.eye(4)), dtype=np.float64)
    yaw = float(np.degrees(np.arctan2(T[1, 0], T[0, 0])))
    span = session.get("time_span")
    when = f", {span[0]:.1f} .. {span[1]:.1f} s" if span else ""
    fit = ""
    if session.get("fitness") is not None:
        fit = f", fitness {session['fitness']:.2f}, overlap {session['overlap']:.2f}, rmse {session['rmse']:.3f} m"
    return (
        f"{head}session {session.get('session')}: {session.get('name')} ({session.get('frames')} frames{when}), "
        f"T_map_session x {T[0, 3]:.2f} m, y {T[1, 3]:.2f} m, z {T[2, 3]:.2f} m, yaw {yaw:.2f} deg, "
        f"{session.get('how')}{fit}"
    )


def render_changes(result: ChangesResult) -> str:
    """What `terra changes` prints: the area both sessions observed, each object change (its class where the
    map names it), terrain per pair, and the changes per region of the scene graph."""
    counts = result.to_json()["counts"]
    lines = [
        f"changes from session {result.first} to session {result.second} in {result.bundle} "
        f"(judged where both observed: {result.observed_area_m2:,.0f} m2)",
        f"  objects: {counts['added']} added, {counts['removed']} removed, {counts['moved']} moved",
    ]
    for change in result.objects:
        where = change.before if change.after is None else change.after
        assert where is not None
        size = " x ".join(f"{v:.1f}" for v in change.size)
        if change.change == "moved" and change.before is not None:
            place = f"({change.before[0]:.1f}, {change.before[1]:.1f}) -> ({where[0]:.1f}, {where[1]:.1f}) m, "
            place += f"{change.distance:.2f} m"
        else:
            place = f"at ({where[0]:.1f}, {where[1]:.1f}) m"
        if change.entry < 0:
            what = "object (seen by LiDAR only"
        else:
            what = f"{change.name or 'object'} (bank entry {change.entry}"
        region = f" in {change.region}" if change.region else ""
        lines.append(f"    {change.change:8s} {what}, {size} m) {place}{region}")
    terrain = ", ".join(f"{t.before} -> {t.after} {t.area_m2:,.0f} m2" for t in result.terrain) or "no change"
    lines.append(f"  terrain: {terrain}")
    if result.regions is not None:
        lines.append(f"  per region: {len(result.regions)} with changes" if result.regions else "  per region: none")
    for region in result.regions or []:
        area = ", ".join(f"{pair} {m2:,.0f} m2" for pair, m2 in sorted(region.terrain_m2.items()))
        lines.append(
            f"    {region.region}: {region.added} added, {region.removed} removed, {region.moved} moved"
            + (f"; terrain {area}" if area else "")
        )
    return "\n".join(lines)


def _render_perception(result: PerceptionResult) -> str:
    lines = [] if result.cluster is None else [_cluster_line(result.cluster)]
    lines.append(
        f"perception cache: {counted(result.images, 'image')} of {counted(result.frames, 'frame')}, "
        f"{result.hits} already cached, "
        f"{result.computed} computed -> {result.folder}"
    )
    lines += _fault_lines(result.stats, result.notes)
    if result.timer is not None:
        lines.append(result.timer.table())
    return "\n".join(lines)


def _cluster_line(cluster: ClusterSummary) -> str:
    return (
        f"perception on {cluster.cluster}: {counted(cluster.frames, 'frame')} by "
        f"{counted(cluster.workers_used, 'worker')} (up to {cluster.in_flight} in flight), "
        f"{counted(cluster.computed, 'image')} computed, {cluster.hits} read back, "
        f"{cluster.seconds:.1f} s of worker time"
    )


def _fault_lines(stats: dict[str, int], notes: dict[str, str]) -> list[str]:
    """One line per fault counter that counted something (skipped frames or images, dropped points)."""
    faults = {k: v for k, v in stats.items() if ("skipped" in k or "dropped_nonfinite" in k) and v}
    return [
        f"  {name}: {count}" + (f" (first: {notes[name]})" if notes.get(name) else "") for name, count in faults.items()
    ]


def _odometry_line(odometry: OdometrySummary) -> str:
    kitti, tum = odometry.trajectory
    line = (
        f"odometry: KISS-ICP over {counted(odometry.scans, 'scan')} ({odometry.scans_per_second:.1f} scans/s, "
        f"{odometry.deskewed} deskewed), trajectory -> {kitti}, {tum.name}"
    )
    if odometry.errors:
        e = odometry.errors
        line += (
            f"\n  vs the source's poses: ATE {e['ate_rmse_m']:.3f} m RMSE, final error {e['final_error_m']:.3f} m "
            f"= {e['drift_percent']:.2f} % of {e['distance_m']:.1f} m travelled"
        )
    return line


def render_import(result: ImportResult, folder: Path) -> str:
    """The summary `terra import` prints for the reference folder `folder`."""
    return "\n".join(
        [
            f"imported {folder} (itr {result.itr}) -> {result.bundle}: {counted(result.points, 'point')}, "
            f"{result.observed_points} with "
            f"object observations, bank {result.bank}, {counted(result.images, 'image')}, "
            f"embedder {result.embedder}",
            f"  terrain classes: {', '.join(result.terrain_classes)}",
            "  image positions: "
            + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in result.image_positions.items())
            + (
                " (exact poses from terra_reference.json)"
                if "recorded" in result.image_positions
                else " (orientation unknown)"
            ),
            *(f"  note: {note}" for note in result.notes),
        ]
    )


def render_export(result: ExportResult) -> str:
    """The line `terra export` prints: format, output and what it holds."""
    return f"{result.format} -> {result.out} (" + ", ".join(f"{k} {v}" for k, v in result.details.items()) + ")"


def render_sim(result: SimResult) -> str:
    """The line `terra sim` prints (its timing table goes to stderr)."""
    return (
        f"wrote {result.folder} ({result.format}): {counted(result.frames, 'frame')}, "
        f"{counted(result.objects, 'object')}, {result.regions} named regions, picture {result.picture}"
    )


def render_eval(result: EvalResult | TuneResult | TerrainTable | GroundTable) -> str:
    """What `terra eval` prints: the report's headline, the tuned parameters (--tune), Table I
    (--terrain-only) or the ground segmentation scores (--ground-only); the timing table is the command's."""
    from terra.eval.results import EvalResult, GroundTable, TerrainTable

    if isinstance(result, TerrainTable):
        return "\n".join(_terrain_lines(result))
    if isinstance(result, GroundTable):
        return "\n".join(_ground_lines(result))
    if isinstance(result, EvalResult):
        from terra.eval.report import headline

        lines = [f"evaluation of {result.bundle} against {result.gt} (parameters: {result.parameter_source}):"]
        lines += headline(result.summary())
        lines.append(f"report: {Path(result.report or '.') / 'report.md'}")
        return "\n".join(lines)
    params = result.params
    lines = [f"tuned on {result.bundle} / {result.gt}:"]
    for name, p in {**params.retrieval, **params.monitoring}.items():
        lines.append(
            f"  {name}: " + ", ".join(f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}" for k, v in p.items())
        )
    lines.append(f"wrote {result.path}")
    return "\n".join(lines)


def _terrain_lines(table: TerrainTable) -> list[str]:
    """Table I as aligned text: one row per method, then per-class IoU."""
    methods = table.methods
    width = max([len(m) for m in methods] + [6])
    lines = [
        f"terrain segmentation of {table.dataset} ({counted(table.images, 'labelled image')}):",
        f"  {'method':<{width}}  {'mIoU':>6}  {'F-mIoU':>6}  {'F1':>6}  {'FPS':>7}",
    ]
    for name, s in methods.items():
        fps = "-" if s.fps is None else f"{s.fps:.1f}"  # a label lookup has no frame rate
        lines.append(f"  {name:<{width}}  {s.miou:>6.3f}  {s.fw_miou:>6.3f}  {s.f1:>6.3f}  {fps:>7}")
    for name, s in methods.items():
        per_class = ", ".join(f"{c} {'-' if v is None else f'{v:.3f}'}" for c, v in zip(s.classes, s.iou))
        lines.append(f"  IoU per class, {name}: {per_class}")
    return lines


def _ground_lines(table: GroundTable) -> list[str]:
    """Pooled and per-scan-mean scores, then the worst scans."""
    p, r, f = table.pooled()
    mp, mr, mf = table.mean()
    points = sum(s.scored for s in table.scans)
    seconds = sum(s.seconds for s in table.scans)
    lines = [
        f"ground segmentation ({table.method}) of {table.sequence}: {counted(len(table.scans), 'labelled scan')}, "
        f"{counted(points, 'scored point')}, ground = SemanticKITTI {', '.join(map(str, table.ground_labels))}",
        f"  pooled:        F1 {f:.4f}  precision {p:.4f}  recall {r:.4f}",
        f"  mean per scan: F1 {mf:.4f}  precision {mp:.4f}  recall {mr:.4f}",
        f"  {seconds / max(len(table.scans), 1) * 1000:.0f} ms a scan",
    ]
    worst = sorted(table.scans, key=lambda s: s.f1)[:3]
    if len(table.scans) > 1:
        lines.append("  lowest F1: " + ", ".join(f"{s.scan} {s.f1:.4f}" for s in worst))
    return lines


# ------------------------------------------------------------------------------------ the tasks


def render_find(result: FindResult) -> str:
    lines = [
        f"{counted(len(result.objects), 'object')} for {counted(len(result.queries), 'query', 'queries')} "
        f"(method {result.method}, alpha {result.alpha:.3f})"
    ]
    for q, query in enumerate(result.queries):
        mine = [(i, o) for i, o in enumerate(result.objects) if o.query == q]
        lines.append(f"{query!r}: {counted(len(mine), 'object')}")
        for i, o in mine:
            c, s = o.center, o.size
            lines.append(
                f"  #{i:<3d} score {o.score:.3f}  centre ({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}) m  "
                f"size {s[0]:.2f} x {s[1]:.2f} x {s[2]:.2f} m  yaw {math.degrees(o.yaw):6.1f} deg  "
                f"{counted(o.point_count, 'point')}  place {o.place}"
            )
    if result.saved:
        lines.append(f"saved {counted(len(result.objects), 'object')} to the scene graph of {result.bundle}")
    return "\n".join(lines)


def render_monitor(result: MonitorResults) -> str:
    import numpy as np

    graph = result.graph
    lines = []
    for r in result.results:
        lines.append(
            f"{r.query!r} (method {result.method}, k {result.k}, alpha {result.alpha:.3f}): "
            f"{counted(len(r.regions), 'region')}, {counted(len(r.places), 'place')}"
        )
        for (level, index), score in zip(r.regions, r.region_scores):
            p = graph.regions[level - 1].position[index]
            count = int(np.count_nonzero(graph.place_region(level) == index))
            lines.append(
                f"  region level {level} #{index}  score {score:.3f}  centre ({p[0]:.1f}, {p[1]:.1f}) m  "
                f"{counted(count, 'place')}"
            )
        for c, members in enumerate(r.clusters):
            lines.append(f"  cluster {c}: {counted(len(members), 'place')}")
        if len(r.places):
            xy = graph.places.position[np.asarray(r.places, dtype=np.int64), :2]
            lines.append(f"  places: {' '.join(str(int(p)) for p in r.places)}")
            lines.append(
                f"  extent x {xy[:, 0].min():.1f}..{xy[:, 0].max():.1f} m, "
                f"y {xy[:, 1].min():.1f}..{xy[:, 1].max():.1f} m"
            )
    return "\n".join(lines)


def render_plan(result: PlanResult) -> str:
    goal, start, path = result.goal, result.start, result.plan
    lines = []
    if goal.object is not None:
        c = goal.object.center
        lines.append(
            f"goal: {goal.query!r} -> object at ({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}) m, score {goal.object.score:.3f}, "
            f"place {goal.place}"
        )
    else:
        lines.append(f"goal: place {goal.place}")
    for skipped in goal.skipped:
        c = skipped.object.center
        lines.append(
            f"  skipped {skipped.object.label!r} at ({c[0]:.2f}, {c[1]:.2f}) m, score {skipped.object.score:.3f}: "
            f"{skipped.reason}"
        )
    lines.append(f"start: place {start.place} ({start.how})")
    penalised = {k: v for k, v in result.penalty.items() if v > 0 and k not in result.forbidden}
    if penalised or result.forbidden:
        lines.append(
            "terrain: "
            + ", ".join(
                [f"{k} penalty {v:g}" for k, v in penalised.items()] + [f"{k} forbidden" for k in result.forbidden]
            )
        )
    along = ", ".join(f"{k} {v:.1f} m" for k, v in path.edge_length_by_terrain.items())
    lines.append(
        f"path: {counted(len(path.places), 'place')}, {path.length_m:.1f} m straight between them; "
        f"{path.edge_length_m:.1f} m along the graph ({along}), cost {path.cost:.1f}"
    )
    if result.robot is not None:
        lines.append(result.robot.limits())
    if path.ground is not None:
        g = path.ground
        unobserved = g.max_unobserved_m
        lines.append(
            f"ground: largest step {g.max_step_m:.2f} m, steepest climb {g.max_climb_deg:.1f} deg, "
            f"steepest descent {g.max_descent_deg:.1f} deg"
            + ("" if g.max_cross_slope_deg is None else f", steepest side slope {g.max_cross_slope_deg:.1f} deg")
            + ("" if unobserved is None else f", longest stretch over unobserved ground {unobserved:.1f} m")
        )
    if path.bridges:
        lines.append(
            f"bridges: {counted(path.bridges, 'step')} ({path.bridge_length_m:.1f} m) only a bridge joins, over ground "
            "the map did not join: what lies there, steps included, is unknown"
        )
    for i, (p, w, t) in enumerate(zip(path.places, path.waypoints, path.terrain)):
        lines.append(f"  {i:3d}  place {int(p):<6d} ({w[0]:8.2f}, {w[1]:8.2f}, {w[2]:6.2f})  {t}")
    return "\n".join(lines)


def render_node(info: NodeInfo) -> str:
    f = info.fields
    if info.kind == "place":
        p = f["position"]
        regions = " < ".join(r["id"] for r in f["regions"]) or "none"
        lines = [
            f"place {info.id}: {f['terrain']} at ({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f}) m, "
            f"clearance {f['clearance']:.2f} m"
            + ("" if f.get("room") is None else f", {f['room']:.2f} m from the nearest obstacle"),
            f"  regions: {regions}",
            "  neighbours: "
            + (", ".join(f"p{n['place']} ({n['weight']:.1f} m, {n['kind']})" for n in f["neighbors"]) or "none"),
        ]
        if f["objects"]:
            lines.append(f"  objects: {' '.join(f['objects'])}")
        return "\n".join(lines)
    if info.kind == "region":
        p = f["position"]
        return "\n".join(
            [
                f"region {info.id}: level {f['level']} at ({p[0]:.1f}, {p[1]:.1f}) m, "
                f"{counted(len(f['places']), 'place')}, "
                f"parent {f['parent']}",
                f"  children: {' '.join(f['children'])}",
            ]
        )
    if info.kind == "object":
        c, s = f["center"], f["size"]
        return (
            f"object {info.id}: {f['label']!r} at ({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}) m, "
            f"size {s[0]:.2f} x {s[1]:.2f} x "
            f"{s[2]:.2f} m, score {f['score']:.3f}, place {f['place']}"
        )
    return f"{info.kind} {info.id}: children {' '.join(f.get('children', []))}"


def render_location(location: Location) -> str:
    return f"({location.xy[0]:g}, {location.xy[1]:g}) m is {location.distance_m:.2f} m from\n" + render_node(
        location.place
    )
