"""`terra demo`: the whole system on a simulated campus, with every step cached so that a second
run (or a run after an interruption) resumes where the last one stopped.

Steps, each calling the library in-process: simulate the test scene (`preset`, `seed`) and a
validation scene (same preset by default, seed + 1, frames twice as far apart to halve its cost;
see DemoConfig), map both, build both scene graphs, choose alpha
and k on the validation scene (`terra eval --tune`), run the demo tasks on the test scene with
those parameters, and evaluate the test scene with them, unchanged (`terra eval --tuned`).

Layout of the demo folder:

    <preset>-seed<seed>/dataset/        the simulated test scene (as `terra sim` writes it)
    <preset>-seed<seed>/map.terra/      its map and scene graph
    validation-<preset>-seed<seed+1>/   the validation scene: dataset/, map.terra/, tuned.json
    report/                             the evaluation report (report.md, summary.json, figures/)
    demo.json                           the demo tasks' results (what `terra demo` prints)
    .cache/<step>.json                  the key each finished step was made with

A step's key holds Terra's version, the preset and seed, its configuration and the keys of the
steps it reads; a step is redone when its key changed or its output is missing. Stamps are
written after the output is complete, and every output is written atomically, so an interrupted
step is simply redone (mapping itself resumes from its checkpoint).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from terra import __version__
from terra.bundle import atomic_write_bytes, dumps_json
from terra.datasets.ground_truth import GroundTruth, load_ground_truth
from terra.errors import TerraError
from terra.eval.config import EvalConfig
from terra.eval.judging import gt_class_of, nearest_gt_object
from terra.eval.metrics.regions import places_in_polygon, set_scores
from terra.eval.tuning import TUNED, TunedParameters
from terra.graph.config import BuildConfig
from terra.graph.scene_graph import SceneGraph
from terra.loaded import LoadedBundle
from terra.mapping.config import MappingConfig
from terra.progress import StageTimer
from terra.schemas import Section
from terra.sim.config import SimConfig
from terra.tasks.config import TasksConfig
from terra.words import counted

FIND_QUERIES = ("Get bike from the bicycle rack", "Find the dumpster")
MONITOR_QUERY = "Large parking lot surrounded by buildings"
PLAN_TARGET = "Get bike from the bicycle rack"
PLAN_PREFER = ("sidewalk",)
DEMO_JSON = "demo.json"
REPORT_DIR = "report"


@dataclass
class DemoConfig:
    """What the demo runs: the test scene (preset, seed), the validation scene (validation_preset,
    seed + 1, frames `validation_spacing` times further apart than the test scene's, which makes
    it about that much cheaper to simulate and map while covering the same kind of campus), and
    each stage's configuration section."""

    preset: str = "small"
    seed: int = 0
    validation_preset: str | None = None  # None: the test scene's preset
    validation_spacing: float = 2.0
    format: str = "terra-folder"  # how the scenes are written and read back: terra-folder, rosbag2 (mcap), rosbag1
    sim: SimConfig = field(default_factory=SimConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    build: BuildConfig = field(default_factory=BuildConfig)
    tasks: TasksConfig = field(default_factory=TasksConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)

    @classmethod
    def load(
        cls,
        path: Path | None,
        preset: str,
        seed: int,
        validation_preset: str | None = None,
        validation_spacing: float = 2.0,
        format: str = "terra-folder",
    ) -> DemoConfig:
        """Sections from a YAML file (defaults without one); TerraError for a bad argument."""
        from terra.config import TerraConfig
        from terra.sim.presets import get_preset

        get_preset(preset)
        get_preset(validation_preset or preset)
        if seed < 0:
            raise TerraError(f"--seed must be a non-negative integer, got {seed}")
        from terra.sim.writer import FORMATS

        if format not in FORMATS:
            raise TerraError(f"--format {format!r}: expected one of: {', '.join(FORMATS)}")
        if not validation_spacing >= 1.0:
            raise TerraError(
                f"--validation-spacing must be >= 1 (a factor on the frame spacing), got {validation_spacing}"
            )
        settings = TerraConfig.read(path)
        # The demo shows the method under realistic perception noise (bleeding masks, missed
        # instances, look-alike confusions) unless the user's file sets the noise itself.
        if not settings.sets("mapping", "perception", "noise"):
            settings = settings.with_overrides({"mapping": {"perception": {"noise": "realistic"}}})
        return cls(
            preset,
            int(seed),
            validation_preset or preset,
            float(validation_spacing),
            format,
            sim=settings.sim,
            build=settings.build,
            tasks=settings.tasks,
            eval=settings.eval,
            mapping=settings.mapping,
        )

    @property
    def validation_seed(self) -> int:
        return self.seed + 1

    def validation_sim(self) -> SimConfig:
        """The validation scene's simulator configuration: frames validation_spacing x further apart."""
        from terra.sim.presets import get_preset

        route = self.sim.route
        spacing = (
            route.frame_spacing or get_preset(self.validation_preset or self.preset).spacing
        ) * self.validation_spacing
        return self.sim.model_copy(update={"route": route.model_copy(update={"frame_spacing": spacing})})


def _dump(section: Section) -> dict:
    return section.model_dump(mode="json")


def check_demo_folder(out: Path) -> None:
    """The rule for existing outputs (terra.cli.outputs) as the demo applies it: its own folder
    resumes (`.cache/` stamps), an absent or empty one is created, anything else is refused."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise TerraError(f"{out}: exists and is not a folder; choose another --out")
    if out.is_dir() and any(out.iterdir()) and not ((out / ".cache").is_dir() or (out / DEMO_JSON).is_file()):
        raise TerraError(f"{out}: folder exists and is not a terra demo folder; choose another --out")


class StepCache:
    """Stamps of finished steps under `root/.cache`: a step is fresh when its stamp holds the same
    key and its outputs exist."""

    def __init__(self, root: Path) -> None:
        self.folder = Path(root) / ".cache"

    def _stamp(self, step: str) -> Path:
        return self.folder / (re.sub(r"[^a-z0-9]+", "-", step.lower()).strip("-") + ".json")

    def fresh(self, step: str, key: dict, *outputs: Path) -> bool:
        stamp = self._stamp(step)
        try:
            return all(p.exists() for p in outputs) and stamp.read_text() == dumps_json(key)
        except OSError:
            return False

    def done(self, step: str, key: dict) -> None:
        atomic_write_bytes(self._stamp(step), dumps_json(key).encode())


@dataclass
class Scene:
    """A simulated scene's dataset folder, its bundle, and the key of its last finished step."""

    label: str
    dataset: Path
    bundle: Path
    key: dict


class DemoRun:
    """Runs the demo's steps into `out`, recording each step's time (`timer`) and whether it ran
    or came from the cache (`steps`)."""

    def __init__(
        self,
        out: str | Path,
        config: DemoConfig,
        show_progress: bool = True,
        log: Callable[[str], None] | None = None,
        overwrite: bool = False,
    ) -> None:
        self.out = Path(out)
        self.config = config
        self.show_progress = show_progress
        self.log = log or (lambda line: None)
        self.cache = StepCache(self.out)
        self.timer = StageTimer()
        self.steps: dict[str, str] = {}
        self.current: str | None = None  # the step running now (for the Ctrl-C message)
        self.overwrite = overwrite  # redo every step, whatever the stamps say
        check_demo_folder(self.out)

    def step(
        self, name: str, key: dict, outputs: tuple[Path, ...], work: Callable[[], object], timed: bool = True
    ) -> None:
        """Run `work` unless the step is fresh; stamp it when done. `timed=False` for work that
        records its own stages in self.timer."""
        from terra.progress import working

        if not self.overwrite and self.cache.fresh(name, key, *outputs):
            self.steps[name] = "cached"
            self.timer.add(f"{name} (cached)", 0.0)
            return
        self.log(f"{name} ...")
        self.current = name
        with working(name, self.show_progress):
            if timed:
                with self.timer.stage(name):
                    work()
            else:
                work()
        self.cache.done(name, key)
        self.current = None
        self.steps[name] = "ran"

    def interrupted(self) -> str:
        """What an interruption keeps, for `terra demo`'s Ctrl-C line."""
        done = sum(1 for v in self.steps.values() if v == "ran") + sum(1 for v in self.steps.values() if v == "cached")
        step = f" from '{self.current}'" if self.current else ""
        return (
            f"{done} finished step{'s' if done != 1 else ''} kept in {self.out}; run the same command again to "
            f"continue{step}"
        )

    # ------------------------------------------------------------------ scenes

    def scene(self, label: str, folder: str, preset: str, seed: int, sim: SimConfig) -> Scene:
        """Simulate, map and build the graph of one scene (each step cached)."""
        from terra.datasets import open_dataset
        from terra.graph.pipeline import build_graph
        from terra.mapping.pipeline import build_map
        from terra.sim import simulate
        from terra.sim.writer import write_dataset

        cfg = self.config
        root = self.out / folder
        dataset, bundle = root / "dataset", root / "map.terra"
        root.mkdir(parents=True, exist_ok=True)
        sim_key = {"terra": __version__, "preset": preset, "seed": seed, "sim": _dump(sim), "format": cfg.format}
        self.step(
            f"{label}: simulate",
            sim_key,
            (dataset,),
            lambda: write_dataset(
                simulate(preset, seed, sim), dataset, format=cfg.format, overwrite=True, progress=self.show_progress
            ),
        )
        map_key = {"dataset": sim_key, "mapping": _dump(cfg.mapping)}
        self.step(
            f"{label}: map",
            map_key,
            (bundle,),
            lambda: build_map(open_dataset(dataset), cfg.mapping, bundle, progress=self.show_progress),
        )
        graph_key = {"map": map_key, "build": _dump(cfg.build)}
        self.step(
            f"{label}: graph", graph_key, (bundle,), lambda: build_graph(bundle, cfg.build, progress=self.show_progress)
        )
        return Scene(label, dataset, bundle, graph_key)

    # ------------------------------------------------------------------ the whole demo

    def run(self) -> dict:
        """Every step; returns the demo summary (demo.json) with the evaluation's summary under
        `evaluation`."""
        from terra.eval.report import SUMMARY

        cfg = self.config
        self.out.mkdir(parents=True, exist_ok=True)
        test = self.scene("test", f"{cfg.preset}-seed{cfg.seed}", cfg.preset, cfg.seed, cfg.sim)
        val, tune_key = self.validation()
        tuned = TunedParameters.load(val.bundle.parent / TUNED)

        report = self.out / REPORT_DIR
        demo_json = self.out / DEMO_JSON
        eval_key = {
            "scene": test.key,
            "tuned": tune_key,
            "eval": _dump(cfg.eval),
            "tasks": _dump(cfg.tasks),
            "queries": [list(FIND_QUERIES), MONITOR_QUERY, PLAN_TARGET, list(PLAN_PREFER)],
        }
        self.step(
            "test: tasks and evaluation",
            eval_key,
            (report / SUMMARY, demo_json),
            lambda: self._tasks_and_eval(test, val, tuned, report, demo_json),
            timed=False,
        )
        demo = json.loads(demo_json.read_text())
        demo["evaluation"] = json.loads((report / SUMMARY).read_text())
        return demo

    def live(self, speed: float, update_every: float = 2.0):
        """The test scene's drive replayed live (terra.live.replay) into `<scene>/live.terra`, asking the
        plan's target at each quarter of the drive with the tuned alpha; writes report/live.md and
        report/live.json and returns the replay. Run after `run()` (the tuned alpha is its output)."""
        from terra.datasets import open_dataset
        from terra.live.replay import format_replay, replay

        cfg = self.config
        test = self.out / f"{cfg.preset}-seed{cfg.seed}"
        dataset = open_dataset(test / "dataset")
        folder = f"validation-{cfg.validation_preset}-seed{cfg.validation_seed}"
        tuned = TunedParameters.load(self.out / folder / TUNED)
        first, last = float(dataset[0].stamp), float(dataset[len(dataset) - 1].stamp)
        ask_at = [round((last - first) * q, 3) for q in (0.25, 0.5, 0.75)]
        method = cfg.tasks.retrieval.method
        with self.timer.stage("live replay"):
            result = replay(
                dataset,
                test / "live.terra",
                load_ground_truth(test / "dataset"),
                PLAN_TARGET,
                ask_at=ask_at,
                speed=speed,
                update_every=update_every,
                alpha=tuned.retrieval_alpha(method),
                config=cfg.mapping,
            )
        report = self.out / REPORT_DIR
        report.mkdir(parents=True, exist_ok=True)
        (report / "live.json").write_text(json.dumps(result.to_json(), indent=1, sort_keys=True) + "\n")
        lines = ["# Live replay", "", "Each answer during the drive beside the final answer (the batch map's):", ""]
        (report / "live.md").write_text("\n".join([*lines, "```", *format_replay(result), "```", ""]))
        return result

    def validation(self) -> tuple[Scene, dict]:
        """The validation scene simulated, mapped and built, and alpha and k tuned on it
        (`tuned.json` beside its bundle), each step cached; returns the scene and the tuning's key.
        Also how Terra's shipped defaults are chosen (benchmarks/bench_defaults.py)."""
        cfg = self.config
        val = self.scene(
            "validation",
            f"validation-{cfg.validation_preset}-seed{cfg.validation_seed}",
            cfg.validation_preset or cfg.preset,
            cfg.validation_seed,
            cfg.validation_sim(),
        )
        tuned_path = val.bundle.parent / TUNED
        tune_key = {"scene": val.key, "eval": _dump(cfg.eval), "tasks": _dump(cfg.tasks)}
        self.step("validation: tune alpha and k", tune_key, (tuned_path,), lambda: self._tune(val, tuned_path))
        return val, tune_key

    def _tune(self, scene: Scene, path: Path) -> None:
        from terra.eval.inputs import EvalInputs
        from terra.eval.runner import tune

        inputs = EvalInputs.load(scene.bundle, scene.dataset)
        tune(inputs, self.config.eval, self.config.tasks, self.show_progress).save(path)

    def _tasks_and_eval(
        self, scene: Scene, validation: Scene, tuned: TunedParameters, report: Path, demo_json: Path
    ) -> None:
        from terra.eval.runner import evaluate
        from terra.loaded import LoadedBundle

        # One load of the bundle for the tasks and the evaluation.
        loaded = LoadedBundle(scene.bundle, embedder_name=self.config.tasks.embedder)
        with self.timer.stage("test: tasks"):
            tasks = run_tasks(loaded, load_ground_truth(scene.dataset), tuned, self.config.tasks)
        evaluate(
            scene.bundle,
            scene.dataset,
            report,
            self.config.eval,
            tuned,
            self.config.tasks,
            show_progress=self.show_progress,
            timer=self.timer,
            loaded=loaded,
        )
        cfg = self.config
        demo = {
            "test_scene": {
                "preset": cfg.preset,
                "seed": cfg.seed,
                "frames": _frames(scene.dataset),
                "dataset": _rel(scene.dataset, self.out),
                "bundle": _rel(scene.bundle, self.out),
            },
            "validation_scene": {
                "preset": cfg.validation_preset,
                "seed": cfg.validation_seed,
                "frames": _frames(validation.dataset),
                "frame_spacing_factor": cfg.validation_spacing,
                "dataset_name": tuned.validation_dataset,
            },
            "parameters": {"retrieval": tuned.retrieval, "monitoring": tuned.monitoring},
            "tasks": tasks,
            "report": _rel(report / "report.md", self.out),
        }
        atomic_write_bytes(demo_json, dumps_json(demo).encode())


def _frames(dataset: Path) -> int:
    from terra.datasets import open_dataset

    return len(open_dataset(dataset))


def _rel(path: Path, root: Path) -> str:
    return Path(path).relative_to(root).as_posix()


# ---------------------------------------------------------------------- the demo tasks


def _find(loaded: LoadedBundle, gt: GroundTruth, tuned: TunedParameters, config: TasksConfig) -> list[dict]:
    from terra.tasks.commands import find
    from terra.tasks.requests import FindRequest

    method = config.retrieval.method
    request = FindRequest(queries=list(FIND_QUERIES), method=method, alpha=tuned.retrieval_alpha(method))
    result = find(loaded, request, config)
    out = []
    for q, query in enumerate(result.queries):
        mine = [(i, o) for i, o in enumerate(result.objects) if o.query == q]
        rows = [dict(id=i, **o.to_json()) for i, o in mine]
        best = max(rows, key=lambda o: o["score"], default=None)
        entry: dict[str, Any] = {
            "query": query,
            "method": method,
            "alpha": result.alpha,
            "objects": len(mine),
            "best": best,
        }
        if best is not None:
            entry["nearest_gt"] = nearest_gt_object(np.asarray(best["center"]), gt, gt_class_of(query, gt), best)
        out.append(entry)
    return out


def _monitor(graph: SceneGraph, gt: GroundTruth, tuned: TunedParameters, config: TasksConfig, embedder) -> dict:
    from terra.eval.regions import MonitorParams, aib_config, up_to_level
    from terra.tasks.monitoring import monitor_region

    method = config.monitoring.method
    if method == "aib":
        alpha, _ = tuned.monitoring_params("aib")
        params = MonitorParams(alpha)
        if alpha is not None:
            config = aib_config(config, embedder.name, alpha)
    else:
        alpha, k = tuned.monitoring_params(graph.region_method)
        params = MonitorParams(
            alpha, k, tuned.monitoring_levels(graph.region_method), tuned.monitoring_min_level(graph.region_method)
        )
        graph = up_to_level(graph, params.levels)
    result = monitor_region(
        graph,
        MONITOR_QUERY,
        method=method,
        k=params.k,
        alpha=params.alpha,
        embedder=embedder,
        config=config,
        min_level=params.min_level,
    )
    places = np.asarray(result.places, dtype=np.int64)
    entry: dict[str, Any] = {
        "query": MONITOR_QUERY,
        "method": method,
        "parameters": params.to_json(),
        "regions": len(result.regions),
        "places": int(len(places)),
    }
    if gt.regions:
        # Score against the labelled region whose description reads most like the query.
        cos = embedder.embed_text([r.description for r in gt.regions]) @ embedder.embed_text([MONITOR_QUERY])[0]
        region = gt.regions[int(np.argmax(cos))]
        scores = set_scores(places, places_in_polygon(graph.places.position, region.polygon))
        entry["labelled_region"] = {
            "name": region.name,
            "description": region.description,
            "precision": scores.precision,
            "recall": scores.recall,
            "gt_places": scores.tp + scores.fn,
        }
    return entry


def _plan(loaded: LoadedBundle, tuned: TunedParameters, config: TasksConfig) -> dict:
    from terra.tasks.commands import plan
    from terra.tasks.requests import PlanRequest

    method = config.planning.find_method
    entry: dict[str, Any] = {"to": PLAN_TARGET, "prefer": list(PLAN_PREFER), "method": method}
    try:
        result = plan(
            loaded,
            PlanRequest(to=PLAN_TARGET, prefer=list(PLAN_PREFER), method=method, alpha=tuned.retrieval_alpha(method)),
            config,
        )
    except TerraError as exc:  # no object or no path: the demo reports it and goes on
        return {**entry, "error": str(exc)}
    path = result.plan.to_json()
    entry.update(
        {
            "length_m": path["length_m"],
            "places": len(path["places"]),
            "length_by_terrain": path["length_by_terrain"],
            "goal": result.goal.object.to_json()["center"] if result.goal.object is not None else None,
            "skipped": [
                f"{s.object.label!r} at ({s.object.center[0]:.1f}, {s.object.center[1]:.1f}): {s.reason}"
                for s in result.goal.skipped
            ],
        }
    )
    return entry


def run_tasks(loaded: LoadedBundle, gt: GroundTruth, tuned: TunedParameters, config: TasksConfig) -> dict:
    """The demo's tasks on the loaded bundle with the tuned parameters (as `terra find/monitor/plan` run them)."""
    graph = loaded.require_graph("terra demo")
    return {
        "find": _find(loaded, gt, tuned, config),
        "monitor": _monitor(graph, gt, tuned, config, loaded.embedder),
        "plan": _plan(loaded, tuned, config),
    }


# ---------------------------------------------------------------------- the printed summary


def format_demo(demo: dict, out: Path) -> list[str]:
    """The lines `terra demo` prints: what was found and where, the plan, the key table figures."""
    from terra.eval.report import headline, terrain_shares

    t, v = demo["test_scene"], demo["validation_scene"]
    lines = [
        f"terra demo: {t['preset']} campus, seed {t['seed']} "
        f"(parameters tuned on {v['preset']} campus, seed {v['seed']})"
    ]
    for f in demo["tasks"]["find"]:
        if f["best"] is None:
            lines.append(f"  find {f['query']!r}: nothing found ({f['method']}, alpha {f['alpha']:.2f})")
            continue
        c = f["best"]["center"]
        line = (
            f"  find {f['query']!r}: object at ({c[0]:.1f}, {c[1]:.1f}, {c[2]:.1f}) m, score {f['best']['score']:.2f}"
        )
        if f.get("nearest_gt"):
            line += "; " + _judged(f["nearest_gt"])
        row = _table_ii_row(demo.get("evaluation", {}), f["query"], f["method"])
        if row is not None:
            noun = f["nearest_gt"]["class"] if f.get("nearest_gt") else "object"
            line += (
                f" (Table II, {f['method']}: {row['num_predictions']} found, "
                f"{row['relaxed_hits']} of {counted(row['num_gt'], noun)} hit)"
            )
        lines.append(line)
    m = demo["tasks"]["monitor"]
    params = ", ".join(f"{k} {v:g}" for k, v in m["parameters"].items())
    line = (
        f"  monitor {m['query']!r}: {counted(m['places'], 'place')} in {counted(m['regions'], 'region')} "
        f"({m['method']}, {params})"
    )
    if "labelled_region" in m:
        r = m["labelled_region"]
        if r.get("gt_places", 1) == 0:
            line += f"; labelled region {r['name']!r} is not evaluable (no place inside it)"
        else:
            line += (
                f"; against labelled region {r['name']!r} ({counted(r['gt_places'], 'place')}): precision "
                f"{r['precision']:.2f}, recall {r['recall']:.2f}"
            )
    lines.append(line)
    p = demo["tasks"]["plan"]
    if "error" in p:
        lines.append(f"  plan to {p['to']!r} preferring {', '.join(p['prefer'])}: {p['error']}")
    else:
        lines.append(
            f"  plan to {p['to']!r} preferring {', '.join(p['prefer'])}: {p['length_m']:.1f} m over "
            f"{counted(p['places'], 'place')} "
            f"({terrain_shares(p['length_by_terrain'], p['length_m'])}, map terrain)"
        )
        lines += [f"    skipped {s}" for s in p.get("skipped", [])]
    ev = demo["evaluation"]
    lines.append(f"  evaluation ({ev['parameters']['source']}):")
    lines += ["  " + h for h in headline(ev)]
    lines.append(f"report: {out / demo['report']}")
    return lines


def _judged(nearest: dict) -> str:
    """'nearest true dumpster 0.5 m away, box IoU 0.31: a hit' as Table II would count it."""
    text = f"nearest true {nearest['class']} {nearest['distance_m']:.1f} m away"
    if "hit" not in nearest:
        return text
    if nearest["hit"]:
        return text + f", box IoU {nearest['iou']:.2f}: a hit"
    why = "the boxes do not overlap" if nearest["iou"] <= 0 else "the box does not hold its centre"
    return text + f", box IoU {nearest['iou']:.2f}: not a hit ({why})"


def _table_ii_row(evaluation: dict, query: str, method: str) -> dict | None:
    """Table II's per-query row for the same query text and method, when the evaluation has one."""
    retrieval = evaluation.get("retrieval", {})
    queries = [q.lower() for q in retrieval.get("queries", [])]
    rows = retrieval.get("methods", {}).get(method, {}).get("per_query", [])
    if query.lower() in queries and len(rows) == len(queries):
        return rows[queries.index(query.lower())]
    return None
