"""`terra eval`: every metric of the paper's evaluation on one bundle against the simulator's
ground truth, written as report.md, summary.json and figures (terra.eval.report).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from terra.bundle import Bundle
from terra.datasets.base import Dataset
from terra.datasets.ground_truth import GroundTruth, load_ground_truth
from terra.errors import TerraError
from terra.eval.config import EvalConfig
from terra.eval.metrics.memory import mapped_area, memory_summary
from terra.eval.navigation import plan_with, start_place
from terra.eval.regions import MonitoringRun, MonitorParams, region_truth, run_monitoring
from terra.eval.report import SUMMARY, write_report
from terra.eval.retrieval import RetrievalRun, RetrievalTask, retrieval_task, run_retrieval
from terra.eval.tuning import TUNED, TunedParameters, alpha_grid, best_point
from terra.graph.scene_graph import SceneGraph
from terra.loaded import LoadedBundle
from terra.mapping.semantic_map import MetricSemanticMap
from terra.perception.text import TextEmbedder
from terra.progress import StageTimer

def mapped_dataset_name(bundle: Bundle) -> str:
    """Name of the dataset a bundle's map was built from ("" when not recorded)."""
    if not bundle.has("map/meta.json"):
        return ""
    meta = bundle.json("map/meta.json")
    return str(meta.get("dataset", "")) if isinstance(meta, dict) else ""


@dataclass
class EvalInputs:
    """What evaluation reads: the loaded bundle (map, graph, query embedder) and the ground truth."""

    loaded: LoadedBundle
    gt: GroundTruth
    gt_root: Path
    hierarchies: dict[str, tuple[SceneGraph, float | None]] = field(default_factory=dict)

    dataset: Dataset | None = None
    dataset_name: str = ""

    @property
    def bundle(self) -> Bundle:
        return self.loaded.bundle

    @property
    def msm(self) -> MetricSemanticMap:
        return self.loaded.msm

    @property
    def graph(self) -> SceneGraph:
        return self.loaded.require_graph("evaluation")

    @property
    def embedder(self) -> TextEmbedder:
        return self.loaded.embedder

    @classmethod
    def load(cls, bundle_path: str | Path, gt_root: str | Path, loaded: LoadedBundle | None = None) -> "EvalInputs":
        """Open everything, cheapest checks first, so bad input fails before any work: the bundle
        must hold a scene graph, `gt_root` must be a dataset written by `terra sim`, and it must
        be the dataset the bundle was mapped from (by its recorded name). `loaded`: an already
        opened bundle to share (its map, graph and embedder are not loaded again)."""
        from terra.datasets import open_dataset

        loaded = loaded or LoadedBundle(bundle_path)
        loaded.require_graph("evaluation")
        gt = load_ground_truth(gt_root)
        dataset = open_dataset(gt_root)
        mapped = mapped_dataset_name(loaded.bundle)
        if mapped and mapped != dataset.name:
            raise TerraError(f"{gt_root}: dataset {dataset.name!r} is not the one {loaded.path} was mapped from "
                             f"({mapped!r})")
        loaded.require_map("evaluation")
        loaded.embedder  # noqa: B018 (loaded now: evaluation embeds many texts)
        return cls(loaded, gt, Path(gt_root), dataset=dataset, dataset_name=dataset.name)

    def hierarchy(self, method: str) -> tuple[SceneGraph, float | None]:
        """The scene graph with `method` region levels on the bundle's places, and the seconds
        it took to build them (cached)."""
        if method not in self.hierarchies:
            from terra.eval.regions import rebuild_regions

            self.hierarchies[method] = rebuild_regions(self.bundle, self.graph, method)
        return self.hierarchies[method]


# ---------------------------------------------------------------------------- Table II


def retrieval_runs(inputs: EvalInputs, task: RetrievalTask, methods: list[str], alphas: dict[str, float | None],
                   tasks_config=None) -> dict[str, RetrievalRun]:
    return {m: run_retrieval(inputs.msm, inputs.graph, task.queries, m, alphas.get(m), inputs.embedder, tasks_config)
            for m in methods}


def retrieval_section(inputs: EvalInputs, config: EvalConfig, tuned: TunedParameters | None, tasks_config=None
                      ) -> tuple[dict, RetrievalTask, dict[str, RetrievalRun]]:
    task = retrieval_task(inputs.gt, config.retrieval)
    methods = config.retrieval.methods
    alphas = {m: _retrieval_alpha(m, inputs, tuned, tasks_config) for m in methods}
    runs = retrieval_runs(inputs, task, methods, alphas, tasks_config) if task.queries else {}
    section = {
        "template": config.retrieval.template,
        "queries": task.queries,
        "num_gt": task.num_gt,
        "methods": {m: {**run.evaluate(task, config.retrieval.precision_ratio).to_json(), "alpha": alphas[m],
                        "runtime_ms": 1000.0 * run.seconds} for m, run in runs.items()},
    }
    return section, task, runs


def _retrieval_alpha(method: str, inputs: EvalInputs, tuned: TunedParameters | None, tasks_config) -> float:
    from terra.tasks.config import TasksConfig, alpha_for

    if tuned is not None and tuned.retrieval_alpha(method) is not None:
        return float(tuned.retrieval_alpha(method))
    cfg = (tasks_config or TasksConfig()).retrieval
    return alpha_for(cfg.alpha, cfg.default_alpha, inputs.msm.embedder)


# ---------------------------------------------------------------------------- Table III

METHOD_LABELS = {"aib": "AIB (Clio) on Terra places", "spectral": "Terra spectral", "agglomerative": "Terra agglomerative"}


def monitoring_run(inputs: EvalInputs, method: str, truth: list[np.ndarray], params: MonitorParams, monitor_method: str,
                   tasks_config=None) -> MonitoringRun:
    """One Table III row: AIB on the places layer, or `monitor_method` on a rebuilt hierarchy."""
    regions = inputs.gt.regions
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
    return MonitorParams(float(alpha) if alpha is not None else alpha_for(cfg.alpha, cfg.default_alpha, embedder),
                         int(k) if k is not None else cfg.k, tuned.monitoring_levels(method) if tuned is not None else None)


def regions_section(inputs: EvalInputs, config: EvalConfig, tuned: TunedParameters | None, tasks_config=None
                    ) -> tuple[dict, dict[str, MonitoringRun]]:
    truth = region_truth(inputs.graph, inputs.gt.regions)
    runs = {}
    for method in config.regions.methods:
        params = monitoring_params(method, inputs.embedder.name, tuned, tasks_config)
        runs[method] = monitoring_run(inputs, method, truth, params, config.regions.monitor_method, tasks_config)
    section = {
        "queries": [{"name": r.name, "description": r.description, "num_gt_places": int(len(t))}
                    for r, t in zip(inputs.gt.regions, truth)],
        "monitor_method": config.regions.monitor_method,
        "methods": {m: run.to_json(METHOD_LABELS[m]) for m, run in runs.items()},
    }
    return section, runs


# ---------------------------------------------------------------------------- navigation


def navigation_section(inputs: EvalInputs, config: EvalConfig, tuned: TunedParameters | None, tasks_config=None) -> dict:
    from terra.tasks.config import TasksConfig
    from terra.tasks.retrieval import best_object, find_objects

    cfg = config.navigation
    tasks = tasks_config or TasksConfig()
    method = tasks.planning.find_method
    alpha = _retrieval_alpha(method, inputs, tuned, tasks_config)
    found = find_objects(inputs.msm, inputs.graph, [cfg.task], method=method, alpha=alpha, config=tasks, embedder=inputs.embedder)
    target = best_object(found)
    section: dict = {"task": cfg.task, "prefer": list(cfg.prefer), "find_method": method, "alpha": alpha}
    if target is None:
        section["error"] = f"no object found for {cfg.task!r} with {method} at alpha {alpha:g}"
        return section
    start = start_place(inputs.msm, inputs.graph)
    plans = [plan_with(inputs.graph, start, target.place, "shortest", inputs.gt.terrain, (), cfg.step, tasks.planning.default_penalty),
             plan_with(inputs.graph, start, target.place, f"prefer {', '.join(cfg.prefer)}", inputs.gt.terrain, cfg.prefer,
                       cfg.step, tasks.planning.default_penalty)]
    section.update({
        "start_place": start,
        "goal_place": int(target.place),
        "goal_object": {"center": [float(v) for v in target.center], "score": float(target.score)},
        "plans": {p.name: p.to_json() for p in plans},
    })
    return section


# ---------------------------------------------------------------------------- tuning


def tune(inputs: EvalInputs, config: EvalConfig, tasks_config=None) -> TunedParameters:
    """Grid-search alpha (and k and levels) on a validation bundle: see terra.eval.tuning."""
    grid = alpha_grid(config.tune)
    tuned = TunedParameters(inputs.embedder.name, validation={"bundle": inputs.bundle.path.name,
                                                              "dataset": inputs.dataset_name or inputs.gt_root.name})
    task = retrieval_task(inputs.gt, config.retrieval)
    if task.queries:
        for method in config.retrieval.methods:
            points = []
            for alpha in grid:
                run = run_retrieval(inputs.msm, inputs.graph, task.queries, method, alpha, inputs.embedder, tasks_config)
                points.append({"alpha": alpha, "f1": run.evaluate(task, config.retrieval.precision_ratio).f1})
            tuned.retrieval[method] = best_point(points)
    truth = region_truth(inputs.graph, inputs.gt.regions)
    if inputs.gt.regions:
        for method in config.regions.methods:
            points = []
            for params in _monitor_grid(method, grid, config, inputs):
                run = monitoring_run(inputs, method, truth, params, config.regions.monitor_method, tasks_config)
                points.append({**params.to_json(), "f1": run.total.f1})
            tuned.monitoring[method] = best_point(points)
    return tuned


def _monitor_grid(method: str, alphas: list[float], config: EvalConfig, inputs: EvalInputs) -> list[MonitorParams]:
    """Grid points in tie-breaking order: all levels first, then caps 1, 2, ... (so a cap is chosen
    only when it scores strictly better), within each the smallest k, then the smallest alpha."""
    if method == "aib":
        return [MonitorParams(a) for a in alphas]
    n_levels = len(inputs.hierarchy(method)[0].regions)
    levels = [None] + list(range(1, n_levels))
    return [MonitorParams(a, k, lv) for lv in levels for k in range(1, config.tune.k_max + 1) for a in alphas]


# ---------------------------------------------------------------------------- the report


def segmentation_section(inputs: EvalInputs, config: EvalConfig, show_progress: bool) -> dict | None:
    """Table I for the perception backend recorded in the bundle (None when the dataset has no
    labelled images or the table is switched off)."""
    if config.segmentation.max_images == 0:
        return None
    from terra.datasets import open_dataset
    from terra.eval.segmentation import evaluate_segmenter
    from terra.mapping.config import MappingConfig
    from terra.perception.registry import get_perception

    dataset = inputs.dataset or open_dataset(inputs.gt_root)
    mapping = MappingConfig.model_validate(inputs.bundle.manifest.get("components", {}).get("map", {}).get("config") or {})
    perception = get_perception(mapping.perception, dataset.classes)
    if not any(c.semantic is not None for c in dataset[0].cameras):
        return None
    scores = evaluate_segmenter(perception.terrain, dataset, config.segmentation.max_images, mapping.perception.noise.seed, show_progress)
    label = f"{mapping.perception.backend} (noise: " + ("on" if mapping.perception.noise.enabled else "none") + ")"
    return {"images": scores.images, "methods": {label: scores.to_json()}}


def parameter_source(tuned: TunedParameters | None) -> dict:
    """Where alpha and k came from, for summary.json and the report's header."""
    if tuned is None:
        return {"source": "defaults (the tasks stage's configuration)"}
    return {"source": f"tuned on validation scene {tuned.validation_dataset}", "validation": dict(tuned.validation),
            "tuned": tuned.to_json()}


def check_report_folder(out: Path) -> None:
    """TerraError unless `out` may be (re)placed by a report: absent, empty, or an earlier report."""
    if out.exists() and not (out.is_dir() and (not any(out.iterdir()) or (out / SUMMARY).is_file())):
        raise TerraError(f"{out}: exists and is not an evaluation report folder; choose another --out or remove it")


def evaluate(bundle_path: str | Path, gt_root: str | Path, out: str | Path, config: EvalConfig | None = None,
             tuned: TunedParameters | None = None, tasks_config=None, show_progress: bool = True,
             timer: StageTimer | None = None, loaded: LoadedBundle | None = None) -> dict:
    """Evaluate a bundle against a simulated dataset's ground truth; write the report to `out`.

    The report is written into a temporary sibling folder that replaces `out` at the end, so a
    failure never leaves a partial report (a tuned.json already in `out` is kept). Returns the
    summary (also written to out/summary.json).
    """
    from terra.sim.writer import atomic_folder

    config = config or EvalConfig()
    timer = timer or StageTimer()
    out = Path(out)
    check_report_folder(out)
    with timer.stage("eval: load"):
        inputs = EvalInputs.load(bundle_path, gt_root, loaded)
    if tuned is not None:
        tuned.check_embedder(inputs.embedder.name)
        tuned.check_not_tuned_on(inputs.dataset_name)
    summary: dict = {
        "bundle": inputs.bundle.path.name,
        "dataset": inputs.dataset_name or inputs.gt_root.name,
        "embedder": inputs.embedder.name,
        "parameters": parameter_source(tuned),
    }

    def fill(folder: Path) -> None:
        with timer.stage("eval: segmentation"):
            seg = segmentation_section(inputs, config, show_progress)
        if seg is not None:
            summary["segmentation"] = seg
        with timer.stage("eval: retrieval"):
            summary["retrieval"], task, retrieval = retrieval_section(inputs, config, tuned, tasks_config)
        with timer.stage("eval: regions"):
            summary["regions"], monitoring = regions_section(inputs, config, tuned, tasks_config)
        with timer.stage("eval: memory"):
            summary["memory"] = memory_summary(inputs.bundle, mapped_area(inputs.msm.points, config.map_cell))
        with timer.stage("eval: navigation"):
            summary["navigation"] = navigation_section(inputs, config, tuned, tasks_config)
        if config.figures:
            with timer.stage("eval: figures"):
                from terra.eval.report_figures import write_figures

                summary["figures"] = write_figures(folder, inputs, summary, task, retrieval, monitoring, config)
        if (out / TUNED).is_file():
            shutil.copyfile(out / TUNED, folder / TUNED)
        summary["timing"] = timer.to_json()
        write_report(folder, summary)

    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_folder(out, True, fill)
    return summary
