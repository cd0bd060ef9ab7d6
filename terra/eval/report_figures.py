"""The report's figures, drawn from the evaluation's inputs and results (terra.viz.figures)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from terra.datasets.ground_truth import TerrainRaster
from terra.eval.config import EvalConfig
from terra.eval.inputs import EvalInputs
from terra.eval.regions import MonitoringRun
from terra.eval.report import ordered, terrain_shares
from terra.eval.retrieval import RetrievalRun, RetrievalTask
from terra.graph.scene_graph import SceneGraph
from terra.viz import figures
from terra.viz.places import extent_with_places
from terra.viz.raster import TopDownImage, point_classes, terrain_points_image
from terra.viz.style import Extent, view_extent

FIGURES = "figures"


def write_figures(
    out: Path,
    inputs: EvalInputs,
    summary: dict,
    task: RetrievalTask,
    retrieval: dict[str, RetrievalRun],
    monitoring: dict[str, MonitoringRun],
    config: EvalConfig,
) -> dict[str, str]:
    """Write every figure under out/figures/; returns {title: path relative to out}."""
    folder = Path(out) / FIGURES
    dpi = config.dpi
    msm = inputs.msm
    background = terrain_points_image(msm.points, point_classes(msm), msm.terrain_classes, cell=msm.voxel_size)
    written, extent = _terrain_figure(folder, inputs, dpi)
    written.update(_graph_figures(folder, inputs, background, dpi, extent))
    if retrieval:
        written.update(_boxes_figure(folder, summary, task, retrieval, background, dpi, extent, msm.terrain_classes))
    written.update(_monitoring_figure(folder, inputs, monitoring, background, dpi, extent))
    written.update(_paths_figure(folder, inputs.graph, summary.get("navigation", {}), background, dpi, extent))
    mem = summary["memory"]
    parts = mem.get("parts_bytes") or mem["components_bytes"]
    written["Memory"] = figures.memory_figure(
        folder / "7_memory.png", parts, mem["area_m2"], inputs.bundle.path.name, dpi
    )
    return {title: path.relative_to(out).as_posix() for title, path in written.items()}


def _terrain_figure(folder: Path, inputs: EvalInputs, dpi: int) -> tuple[dict[str, Path], Extent]:
    """The terrain map against the ground truth, and the view every figure shares: the evaluated
    world (the ground-truth raster, else the map) grown to hold every place (shared_extent)."""
    msm = inputs.msm
    raster = inputs.gt.terrain
    extent = shared_extent(raster, inputs.graph, msm.points)
    if raster is None:
        return {}, extent
    path = figures.terrain_map_figure(
        folder / "1_terrain_map.png",
        msm.terrain_classes,
        msm.points,
        point_classes(msm),
        inputs.gt,
        dpi,
        extent,
        cell=max(msm.voxel_size, raster.resolution),
    )
    return {"Terrain map vs ground truth": path}, extent


def shared_extent(raster: TerrainRaster | None, graph: SceneGraph, points: np.ndarray) -> Extent:
    """The view every report figure shares (x0, x1, y0, y1 metres, map frame): the evaluated world
    (the ground-truth terrain raster, else the map's points) grown to hold every place, so no
    figure crops places built from LiDAR returns beyond the labelled world."""
    if raster is None:
        return view_extent(points, margin=0.03)
    corners = raster.origin + np.array([[0.0, 0.0], raster.classes.shape[::-1]]) * raster.resolution
    extent = extent_with_places(view_extent(corners, margin=0.03), graph)
    assert extent is not None  # a view stays a view
    return extent


def _graph_figures(
    folder: Path, inputs: EvalInputs, background: TopDownImage, dpi: int, extent: Extent
) -> dict[str, Path]:
    """The places layer, and the region levels of each Terra hierarchy evaluated (else the bundle's)."""
    graph = inputs.graph
    written = {
        "Places layer by terrain": figures.places_figure(folder / "2_places.png", graph, background, dpi, extent)
    }
    for method in ("spectral", "agglomerative"):
        if method in inputs.hierarchies:
            written[f"Region levels ({method})"] = figures.region_levels_figure(
                folder / f"3_regions_{method}.png", inputs.hierarchies[method][0], background, dpi, extent
            )
    if not any(t.startswith("Region levels") for t in written) and graph.regions:
        written["Region levels"] = figures.region_levels_figure(
            folder / "3_regions.png", graph, background, dpi, extent
        )
    return written


def _boxes_figure(
    folder: Path,
    summary: dict,
    task: RetrievalTask,
    retrieval: dict[str, RetrievalRun],
    background: TopDownImage,
    dpi: int,
    extent: Extent,
    terrain_classes: list[str],
) -> dict[str, Path]:
    """Each method's retrieved boxes against the ground truth, with Table II's counts per query."""
    gt_boxes, gt_query = task.gt_boxes()
    predictions = {m: (run.boxes, run.query) for m, run in retrieval.items()}
    counts = {
        m: [(r["num_predictions"], r["relaxed_hits"]) for r in s["per_query"]]
        for m, s in summary.get("retrieval", {}).get("methods", {}).items()
    }
    path = figures.boxes_figure(
        folder / "4_boxes.png",
        gt_boxes,
        predictions,
        task.queries,
        gt_query,
        background,
        dpi,
        extent,
        counts,
        terrain_classes=terrain_classes,
    )
    return {"Retrieved boxes vs ground truth": path}


def _monitoring_figure(
    folder: Path,
    inputs: EvalInputs,
    monitoring: dict[str, MonitoringRun],
    background: TopDownImage,
    dpi: int,
    extent: Extent,
) -> dict[str, Path]:
    """The places the bundle's own hierarchy predicted per region, as `terra monitor` answers
    (none without a monitoring run)."""
    best = _shown_hierarchy(monitoring, inputs.graph.region_method)
    if best is None:
        return {}
    graph = inputs.hierarchies[best][0] if best in inputs.hierarchies else inputs.graph
    run = monitoring[best]
    path = figures.monitoring_figure(
        folder / "5_monitoring.png",
        graph,
        run.regions or inputs.gt.regions,
        run.predicted,
        best,
        background,
        dpi,
        extent,
        [(sc.precision, sc.recall) for sc in run.scores],
        run.parameters,
    )
    return {f"Region monitoring ({best})": path}


def _paths_figure(
    folder: Path, graph: SceneGraph, nav: dict, background: TopDownImage, dpi: int, extent: Extent
) -> dict[str, Path]:
    """The navigation task's plans with their ground-truth terrain shares, and below them the pair
    of places where preferring the terrain changes the path most (the report's navigation case;
    the task's own plans often coincide). None without plans."""
    if "plans" not in nav:
        return {}
    plans, notes = _plans_and_notes(nav["plans"])
    case = nav.get("preference_case")
    row = None
    if case:
        case_plans, case_notes = _plans_and_notes(case["plans"])
        row = figures.PathCase(
            f"where preferring {', '.join(nav.get('prefer', [])) or 'a terrain'} changes the path",
            case["start_place"],
            case["goal_place"],
            case_plans,
            case_notes,
        )
    path = figures.paths_figure(
        folder / "6_paths.png",
        graph,
        nav["start_place"],
        nav["goal_place"],
        plans,
        nav["task"],
        background,
        dpi,
        extent,
        notes,
        case=row,
    )
    return {"Terrain-aware navigation": path}


def _plans_and_notes(plans: dict) -> tuple[list[tuple[str, np.ndarray, float]], list[str]]:
    """(name, place indices, length) per plan in the report's order, and its ground-truth shares."""
    shown = ordered(plans)
    rows = [(name, np.asarray(p["place_indices"]), p["length_m"]) for name, p in shown.items()]
    return rows, ["ground truth: " + terrain_shares(p["gt_terrain_m"], p["length_m"]) for p in shown.values()]


def _shown_hierarchy(monitoring: dict[str, MonitoringRun], own: str) -> str | None:
    """The hierarchy the figure shows: the bundle's own (`own`, what `terra monitor` and the demo
    rank), when it was evaluated; else the Terra hierarchy with the best F1 (first on ties), else
    any monitoring method run. Table III lists every method."""
    if own in monitoring:
        return own
    candidates = [m for m in ("spectral", "agglomerative") if m in monitoring] or list(monitoring)
    if not candidates:
        return None
    return max(candidates, key=lambda m: (monitoring[m].total.f1, -candidates.index(m)))
