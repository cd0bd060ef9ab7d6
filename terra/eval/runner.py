"""`terra eval`: every metric of the paper's evaluation on one bundle against the simulator's
ground truth, written as report.md, summary.json and figures (terra.eval.report).
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from terra.bundle import Bundle
from terra.datasets.ground_truth import TerrainRaster
from terra.errors import TerraError
from terra.eval.config import EvalConfig
from terra.eval.inputs import EvalInputs
from terra.eval.metrics.memory import mapped_area, memory_summary
from terra.eval.navigation import plan_with, preference_case, preference_routes, start_place, terrain_route_pairs
from terra.eval.regions import MonitoringRun, MonitorParams, region_truth, run_monitoring
from terra.eval.report import SUMMARY, write_report
from terra.eval.results import EvalResult
from terra.eval.retrieval import RetrievalRun, RetrievalTask, retrieval_task, run_retrieval
from terra.eval.tuning import TUNED, TunedParameters, alpha_grid, best_point
from terra.loaded import LoadedBundle
from terra.progress import StageTimer

NOT_IN_KITTI = {
    "segmentation": "needs images labelled with terrain classes",
    "regions": "needs named regions with their descriptions",
    "navigation": "needs the ground-truth terrain along the path",
}


def _raster(inputs: EvalInputs) -> TerrainRaster:
    """The ground-truth terrain raster (the sections that read it run only when there is one)."""
    if inputs.gt.terrain is None:
        raise TerraError(f"{inputs.gt_root}: the ground truth has no terrain raster")
    return inputs.gt.terrain


def not_evaluated(inputs: EvalInputs) -> dict[str, str]:
    """Sections the ground truth cannot score, each with the reason in words (never numbers)."""
    if not inputs.objects_only:
        return {}
    return {
        key: f"{reason}, which this dataset's labels do not have; not evaluated" for key, reason in NOT_IN_KITTI.items()
    }


# ---------------------------------------------------------------------------- Table II


def retrieval_runs(
    inputs: EvalInputs,
    task: RetrievalTask,
    methods: Sequence[str],
    alphas: Mapping[str, float | None],
    tasks_config=None,
) -> dict[str, RetrievalRun]:
    return {
        m: run_retrieval(inputs.msm, inputs.graph, task.queries, m, alphas.get(m), inputs.embedder, tasks_config)
        for m in methods
    }


def retrieval_section(
    inputs: EvalInputs, config: EvalConfig, tuned: TunedParameters | None, tasks_config=None
) -> tuple[dict, RetrievalTask, dict[str, RetrievalRun]]:
    task = retrieval_task(inputs.gt, config.retrieval)
    methods = config.retrieval.methods
    alphas = {m: _retrieval_alpha(m, inputs, tuned, tasks_config) for m in methods}
    runs = retrieval_runs(inputs, task, methods, alphas, tasks_config) if task.queries else {}
    from terra.eval.metrics.retrieval import accuracy_matches, iou_by_distance
    from terra.eval.navigation import robot_path

    path = robot_path(inputs.msm)
    section = {
        "template": config.retrieval.template,
        "queries": task.queries,
        "num_gt": task.num_gt,
        "methods": {
            m: {
                **run.evaluate(task, config.retrieval.precision_ratio).to_json(),
                "alpha": alphas[m],
                "runtime_ms": 1000.0 * run.seconds,
                "smallest_box_side_m": float(run.boxes.size.min()) if len(run.boxes) else None,
                "iou_by_distance": iou_by_distance(accuracy_matches(run.boxes, run.scores, task.gt), task.gt, path),
            }
            for m, run in runs.items()
        },
    }
    return section, task, runs


def _retrieval_alpha(method: str, inputs: EvalInputs, tuned: TunedParameters | None, tasks_config) -> float:
    from terra.tasks.config import TasksConfig, alpha_for

    alpha = tuned.retrieval_alpha(method) if tuned is not None else None
    if alpha is not None:
        return float(alpha)
    cfg = (tasks_config or TasksConfig()).retrieval
    return alpha_for(cfg.alpha, cfg.default_alpha, inputs.msm.embedder)


# ---------------------------------------------------------------------------- Table III

METHOD_LABELS = {
    "aib": "AIB (Clio) on Terra places",
    "spectral": "Terra spectral",
    "agglomerative": "Terra agglomerative",
}


def monitoring_run(
    inputs: EvalInputs,
    method: str,
    truth: list[np.ndarray],
    params: MonitorParams,
    monitor_method: str,
    tasks_config=None,
    regions: list | None = None,
) -> MonitoringRun:
    """One Table III row: AIB on the places layer, or `monitor_method` on a rebuilt hierarchy.
    `regions` and `truth`: the evaluable labelled regions and their places (evaluable_regions)."""
    regions = inputs.gt.regions if regions is None else regions
    if method == "aib":
        return run_monitoring(inputs.graph, regions, truth, "aib", params, inputs.embedder, tasks_config)
    graph, build_seconds = inputs.hierarchy(method)
    run = run_monitoring(graph, regions, truth, monitor_method, params, inputs.embedder, tasks_config)
    run.build_seconds = build_seconds
    return run


def monitoring_params(method: str, embedder: str, tuned: TunedParameters | None, tasks_config) -> MonitorParams:
    """Tuned alpha / k / levels of `method`, else the tasks stage's defaults (all levels)."""
    from terra.tasks.config import TasksConfig, alpha_for

    cfg = (tasks_config or TasksConfig()).monitoring
    alpha, k = tuned.monitoring_params(method) if tuned is not None else (None, None)
    if method == "aib":
        default = alpha_for(cfg.aib.null_score, cfg.aib.default_null_score, embedder)
        return MonitorParams(float(alpha) if alpha is not None else default)
    return MonitorParams(
        float(alpha) if alpha is not None else alpha_for(cfg.alpha, cfg.default_alpha, embedder),
        int(k) if k is not None else cfg.k,
        tuned.monitoring_levels(method) if tuned is not None else None,
        tuned.monitoring_min_level(method) if tuned is not None else None,
    )


NOT_EVALUABLE = "no place of the scene graph lies inside it, so no prediction can be right or wrong there"


def evaluable_regions(inputs: EvalInputs) -> tuple[list, list[np.ndarray], list[dict]]:
    """The labelled regions that can be scored (at least one place inside), their places, and
    the others with the reason: a region with no place has no recall, and every place predicted
    for it would count against the method, so it is listed as not evaluable and left out of the
    averages (and of tuning) instead."""
    regions, truth, skipped = [], [], []
    for region, places in zip(inputs.gt.regions, region_truth(inputs.graph, inputs.gt.regions)):
        if len(places):
            regions.append(region)
            truth.append(places)
        else:
            skipped.append({"name": region.name, "description": region.description, "reason": NOT_EVALUABLE})
    return regions, truth, skipped


def regions_section(
    inputs: EvalInputs, config: EvalConfig, tuned: TunedParameters | None, tasks_config=None
) -> tuple[dict, dict[str, MonitoringRun]]:
    regions, truth, skipped = evaluable_regions(inputs)
    runs = {}
    for method in config.regions.methods:
        params = monitoring_params(method, inputs.embedder.name, tuned, tasks_config)
        runs[method] = monitoring_run(
            inputs, method, truth, params, config.regions.monitor_method, tasks_config, regions
        )
    section = {
        "not_evaluable": skipped,
        "queries": [
            {"name": r.name, "description": r.description, "num_gt_places": int(len(t))} for r, t in zip(regions, truth)
        ],
        "monitor_method": config.regions.monitor_method,
        "methods": {m: run.to_json(METHOD_LABELS[m]) for m, run in runs.items()},
        "regions_per_level": {m: [len(level) for level in inputs.hierarchy(m)[0].regions] for m in runs if m != "aib"},
    }
    return section, runs


# ---------------------------------------------------------------------------- navigation


def navigation_section(
    inputs: EvalInputs, config: EvalConfig, tuned: TunedParameters | None, tasks_config=None
) -> dict:
    """The task's plan (goal: the best reachable object for it) shortest and with the preferred
    terrains, the preference measured over place pairs joined by a route on the first preferred
    terrain, and the pair that shows the preference best (eval/navigation.py)."""
    from terra.tasks.config import TasksConfig

    cfg = config.navigation
    tasks = tasks_config or TasksConfig()
    section: dict = {"task": cfg.task, "prefer": list(cfg.prefer), "find_method": tasks.planning.find_method}
    section.update(_task_plans(inputs, cfg, tuned, tasks, tasks_config))
    if cfg.prefer:
        from terra.eval.metrics.places import observed_cells

        seen = observed_cells(_raster(inputs), inputs.msm.points[inputs.msm.terrain_index(0.5) >= 0])
        pairs = terrain_route_pairs(inputs.graph, _raster(inputs), cfg.prefer[0], seen, cfg.route_pairs)
        routes = preference_routes(
            inputs.graph, _raster(inputs), pairs, cfg.prefer[0], cfg.step, tasks.planning.default_penalty
        )
        section["preference_routes"] = routes.to_json(cfg.min_share)
        case = preference_case(routes, cfg.min_share)
        if case is not None:
            a, b = (int(v) for v in routes.pairs[case])
            section["preference_case"] = {
                "start_place": a,
                "goal_place": b,
                "start_xy": [round(float(v), 3) for v in inputs.graph.places.position[a, :2]],
                "goal_xy": [round(float(v), 3) for v in inputs.graph.places.position[b, :2]],
                "plans": {
                    "shortest": routes.shortest[case].to_json(),
                    routes.preferred[case].name: routes.preferred[case].to_json(),
                },
            }
    return section


def _task_plans(inputs: EvalInputs, cfg, tuned: TunedParameters | None, tasks, tasks_config) -> dict:
    """Plans for the navigation task: its candidates tried best first (terra.tasks.planning)."""
    from terra.errors import NoPathError
    from terra.tasks.planning import CostGraph, TerrainCosts, plan_to_objects
    from terra.tasks.retrieval import find_objects

    method = tasks.planning.find_method
    alpha = _retrieval_alpha(method, inputs, tuned, tasks_config)
    found = [
        o
        for o in find_objects(
            inputs.msm, inputs.graph, [cfg.task], method=method, alpha=alpha, config=tasks, embedder=inputs.embedder
        )
        if o.query == 0
    ]
    out: dict = {"alpha": alpha, "candidates": len(found)}
    if not found:
        return {**out, "error": f"no object found for {cfg.task!r} with {method} at alpha {alpha:g}"}
    start = start_place(inputs.msm, inputs.graph)
    costs = TerrainCosts.from_preferences(inputs.graph.terrain_classes)
    try:
        goal = plan_to_objects(
            inputs.graph, CostGraph.build(inputs.graph, costs), start, found, tasks.planning.goal_radius
        )
    except NoPathError as exc:
        return {**out, "error": str(exc)}
    plans = [
        plan_with(
            inputs.graph,
            start,
            goal.goal_place,
            "shortest",
            _raster(inputs),
            [],
            cfg.step,
            tasks.planning.default_penalty,
        ),
        plan_with(
            inputs.graph,
            start,
            goal.goal_place,
            f"prefer {', '.join(cfg.prefer)}",
            _raster(inputs),
            cfg.prefer,
            cfg.step,
            tasks.planning.default_penalty,
        ),
    ]
    return {
        **out,
        "start_place": start,
        "goal_place": goal.goal_place,
        "goal_object": {"center": [float(v) for v in goal.goal_object.center], "score": float(goal.goal_object.score)},
        "skipped": [s.to_json() for s in goal.skipped],
        "plans": {p.name: p.to_json() for p in plans},
    }


def places_section(inputs: EvalInputs) -> dict:
    """Same-terrain connectivity of the places against the ground-truth raster
    (terra.eval.metrics.places): over the whole raster, and over the ground the cameras labelled."""
    from terra.eval.metrics.places import observed_cells, same_terrain_connectivity
    from terra.eval.regions import region_truth

    seen = observed_cells(_raster(inputs), inputs.msm.points[inputs.msm.terrain_index(0.5) >= 0])
    return {
        "places": len(inputs.graph.places),
        "connectivity": same_terrain_connectivity(inputs.graph, _raster(inputs)).to_json(),
        "connectivity_seen": same_terrain_connectivity(inputs.graph, _raster(inputs), seen).to_json(),
        "places_per_region": {
            r.name: int(len(t)) for r, t in zip(inputs.gt.regions, region_truth(inputs.graph, inputs.gt.regions))
        },
    }


# ---------------------------------------------------------------------------- tuning


def tune(inputs: EvalInputs, config: EvalConfig, tasks_config=None, show_progress: bool = False) -> TunedParameters:
    """Grid-search alpha (and k and levels) on a validation bundle: see terra.eval.tuning."""
    from terra.progress import progress

    grid = alpha_grid(config.tune)
    tuned = TunedParameters(
        inputs.embedder.name,
        validation={
            "bundle": inputs.bundle.path.name,
            "dataset": inputs.dataset_name or inputs.gt_root.name,
            **inputs.fingerprint_record(),
        },
    )
    task = retrieval_task(inputs.gt, config.retrieval)
    if task.queries:
        for method in config.retrieval.methods:
            points = []
            for alpha in progress(grid, f"tuning {method} retrieval", enabled=show_progress, unit="alphas"):
                run = run_retrieval(
                    inputs.msm, inputs.graph, task.queries, method, alpha, inputs.embedder, tasks_config
                )
                points.append({"alpha": alpha, "f1": run.evaluate(task, config.retrieval.precision_ratio).f1})
            tuned.retrieval[method] = best_point(points)
    regions, truth, _ = evaluable_regions(inputs)
    if regions:
        for method in config.regions.methods:
            points = []
            grid_points = _monitor_grid(method, grid, config, inputs)
            for params in progress(grid_points, f"tuning {method} monitoring", enabled=show_progress, unit="settings"):
                run = monitoring_run(
                    inputs, method, truth, params, config.regions.monitor_method, tasks_config, regions
                )
                points.append({**params.to_json(), "f1": run.total.f1})
            # The alpha chosen depends on how queries are embedded (tasks.monitoring.query).
            tuned.monitoring[method] = {**best_point(points), "query": _query_mode(tasks_config)}
    return tuned


def _query_mode(tasks_config) -> str:
    from terra.tasks.config import TasksConfig

    return (tasks_config or TasksConfig()).monitoring.query


def _monitor_grid(method: str, alphas: list[float], config: EvalConfig, inputs: EvalInputs) -> list[MonitorParams]:
    """Grid points in tie-breaking order: ranking from level 1 before from level 2, all levels
    before caps 1, 2, ... (so a restriction is chosen only when it scores strictly better), within
    each the smallest k, then the smallest alpha."""
    if method == "aib":
        return [MonitorParams(a) for a in alphas]
    n_levels = len(inputs.hierarchy(method)[0].regions)
    levels = [None] + list(range(1, n_levels))
    lows = [None] + ([2] if n_levels >= 2 else [])
    return [
        MonitorParams(a, k, lv, lo)
        for lo in lows
        for lv in levels
        if (lv or n_levels) >= (lo or 1)
        for k in range(1, config.tune.k_max + 1)
        for a in alphas
    ]


# ---------------------------------------------------------------------------- the report


def segmentation_section(inputs: EvalInputs, config: EvalConfig, show_progress: bool) -> dict | None:
    """Table I for the perception backend recorded in the bundle (None when the dataset has no
    labelled images or the table is switched off)."""
    if config.segmentation.max_images == 0:
        return None
    from terra.datasets import open_dataset
    from terra.eval.segmentation import evaluate_segmenter
    from terra.mapping.config import MappingConfig
    from terra.perception.registry import get_terrain_segmenter

    dataset = inputs.dataset or open_dataset(inputs.gt_root)
    mapping = MappingConfig.model_validate(inputs.bundle.component_config("map"))
    if not any(c.semantic is not None for c in dataset[0].cameras):
        return None
    segmenter = get_terrain_segmenter(mapping.perception, dataset.classes)  # no mask or embedding model is loaded
    scores = evaluate_segmenter(
        segmenter, dataset, config.segmentation.max_images, mapping.perception.noise.seed, show_progress
    )
    label = f"{mapping.perception.backend} (noise: " + ("on" if mapping.perception.noise.enabled else "none") + ")"
    return {"images": scores.images, "methods": {label: scores.to_json()}}


def parameter_source(tuned: TunedParameters | None) -> dict:
    """Where alpha and k came from, for summary.json and the report's header."""
    if tuned is None:
        return {"source": "defaults (the tasks stage's configuration)"}
    return {
        "source": f"tuned on validation scene {tuned.validation_dataset}",
        "validation": dict(tuned.validation),
        "tuned": tuned.to_json(),
    }


def perception_section(bundle: Bundle) -> dict:
    """Which perception produced the map, from the bundle: the backend, its noise (labels) or its
    model files (models), and whether its masks come from the ground truth itself (the labels
    backend reads the dataset's label images, so Tables I and II then grade ground-truth masks)."""
    perception = bundle.component_config("map").get("perception") or {}
    recorded = bundle.model.perception or {}
    backend = str(recorded.get("backend") or perception.get("backend") or "unknown")
    models = [
        {k: m.get(k) for k in ("role", "name", "sha256") if k in m}
        for m in recorded.get("models", [])
        if isinstance(m, dict)
    ]
    section: dict = {"backend": backend, "ground_truth_masks": backend == "labels", "models": models}
    noise = perception.get("noise")
    if backend == "labels" and isinstance(noise, dict):
        section["noise"] = {k: noise.get(k) for k in ("dilate_px", "miss_rate", "confusion_rate")}
    return section


def summary_header(inputs: EvalInputs, tuned: TunedParameters | None) -> dict:
    """What was evaluated with what, and the sections the ground truth cannot score (and why)."""
    summary: dict = {
        "bundle": inputs.bundle.path.name,
        "dataset": inputs.dataset_name or inputs.gt_root.name,
        "embedder": inputs.embedder.name,
        "perception": perception_section(inputs.bundle),
        "parameters": parameter_source(tuned),
    }
    skipped = not_evaluated(inputs)
    if skipped:
        summary["not_evaluated"] = {**skipped, "notes": list(inputs.gt.notes)}
    return summary


@contextmanager
def _stage(timer: StageTimer, name: str, show_progress: bool) -> Iterator[None]:
    """A timed evaluation stage that reports it is still working in long runs (terra.progress)."""
    from terra.progress import working

    with timer.stage(name), working(name, show_progress):
        yield


def check_report_folder(out: Path) -> None:
    """TerraError unless `out` may be (re)placed by a report: absent, empty, or an earlier report."""
    if out.exists() and not (out.is_dir() and (not any(out.iterdir()) or (out / SUMMARY).is_file())):
        raise TerraError(f"{out}: exists and is not an evaluation report folder; choose another --out or remove it")


def evaluate(
    bundle_path: str | Path,
    gt_root: str | Path,
    out: str | Path,
    config: EvalConfig | None = None,
    tuned: TunedParameters | None = None,
    tasks_config=None,
    show_progress: bool = True,
    timer: StageTimer | None = None,
    loaded: LoadedBundle | None = None,
) -> EvalResult:
    """Evaluate a bundle against a simulated dataset's ground truth; write the report to `out`.

    The report is written into a temporary sibling folder that replaces `out` at the end, so a
    failure never leaves a partial report (a tuned.json already in `out` is kept). Returns the
    result, whose JSON is the summary written to out/summary.json.
    """
    from terra.bundle import atomic_folder

    config = config or EvalConfig()
    timer = timer or StageTimer()
    out = Path(out)
    check_report_folder(out)
    with timer.stage("eval: load"):
        inputs = EvalInputs.load(bundle_path, gt_root, loaded)
    if tuned is not None:
        tuned.check_embedder(inputs.embedder.name)
        tuned.check_not_tuned_on(inputs.dataset_name, fingerprint=inputs.dataset_fingerprint)
        tuned.check_query_mode(_query_mode(tasks_config))
    summary = summary_header(inputs, tuned)
    run = _ReportRun(inputs, config, tuned, tasks_config, timer, show_progress)

    def fill(folder: Path) -> None:
        run.score(summary, folder)
        if (out / TUNED).is_file():
            shutil.copyfile(out / TUNED, folder / TUNED)
        summary["timing"] = timer.to_json()
        write_report(folder, summary)

    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_folder(out, fill, "report")
    result = EvalResult.from_json(summary)
    result.bundle, result.gt, result.report, result.timer = Path(bundle_path), Path(gt_root), out, timer
    return result


@dataclass
class _ReportRun:
    """The sections of one report, each a timed stage: segmentation, retrieval, regions, memory,
    places, navigation, figures (the ground truth decides which it can score)."""

    inputs: EvalInputs
    config: EvalConfig
    tuned: TunedParameters | None
    tasks_config: Any
    timer: StageTimer
    show_progress: bool

    def stage(self, name: str):
        return _stage(self.timer, name, self.show_progress)

    def score(self, summary: dict, folder: Path) -> None:
        """Every section the ground truth can score into `summary`, the figures into `folder`."""
        inputs, config, tuned, tasks = self.inputs, self.config, self.tuned, self.tasks_config
        skipped = summary.get("not_evaluated", {})
        monitoring: dict[str, MonitoringRun] = {}
        if "segmentation" not in skipped:
            with self.stage("eval: segmentation"):
                seg = segmentation_section(inputs, config, self.show_progress)
            if seg is not None:
                summary["segmentation"] = seg
        with self.stage("eval: retrieval"):
            summary["retrieval"], task, retrieval = retrieval_section(inputs, config, tuned, tasks)
        if "regions" not in skipped:
            with self.stage("eval: regions"):
                summary["regions"], monitoring = regions_section(inputs, config, tuned, tasks)
        with self.stage("eval: memory"):
            summary["memory"] = memory_summary(inputs.bundle, mapped_area(inputs.msm.points, config.map_cell))
        if not inputs.objects_only:  # place connectivity is judged on the ground-truth terrain raster
            with self.stage("eval: places"):
                summary["places"] = places_section(inputs)
        if "navigation" not in skipped:
            with self.stage("eval: navigation"):
                summary["navigation"] = navigation_section(inputs, config, tuned, tasks)
        if config.figures:
            with self.stage("eval: figures"):
                from terra.eval.report_figures import write_figures

                summary["figures"] = write_figures(folder, inputs, summary, task, retrieval, monitoring, config)
