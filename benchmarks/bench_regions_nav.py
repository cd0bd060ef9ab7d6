"""Regions, places, navigation and retrieval boxes on the small preset (issue 14's targets).

Parameters are tuned on the small campus seed 1 (`terra eval --tune`) and applied unchanged to
seeds 0, 2 and 3, like `terra demo` (maps with realistic perception noise). Per test seed it
records Table III (F1 of AIB, spectral and agglomerative regions, and their runtimes: building the
regions plus one query), retrieval (F1, mean IoU of matched boxes, the thinnest box side),
navigation (share of sidewalk on plans preferring it between sidewalk places joined by a sidewalk
route, and whether a case shows the preference), and the places' same-terrain connectivity
against the ground-truth raster. It also builds the tiny and campus presets' graphs for their
connectivity and region counts per level, and the paper's fixed cuts on the small campus.

Datasets and maps come from --cache (made with `terra sim` and `terra map --noise realistic` when
missing: about 2 minutes per small seed, 6 for the campus); graphs are rebuilt once with this
checkout's default build under --work. Two task configurations run on the same graphs: "before"
is main's before session 4 (planner default penalty 1, every retrieval cluster kept, Terra-3DSG
never widened), "after" this checkout's defaults; each is tuned on the validation seed. Beside the
targets it records how many places sit on their own ground-truth terrain
(terra.eval.metrics.places.place_terrain_agreement) and, on the validation seed only, the sweep
that chose the planner's default penalty (terra.eval.navigation.penalty_sweep).

Usage: python benchmarks/bench_regions_nav.py [--cache DIR] [--work DIR] [--seeds 0,2,3] [--no-campus] [--out JSON]
Writes --out (default benchmarks/results/regions_nav.json) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT.parent))
from benchmarks.benchtable import report  # noqa: E402

TARGETS = {
    "agglomerative_f1": 0.70,
    "spectral_f1": 0.60,
    "matched_iou": 0.5,
    "retrieval_f1": 0.75,
    "sidewalk_share": 0.8,
    "connectivity": 0.99,
    "box_side": 0.05,
}
# Session 4 compares, on the same graphs (the default build), main's task settings ("before":
# planner penalty 1, every retrieval cluster kept, 3DSG never widened) with this checkout's defaults.
CONFIGS = {
    "before": {
        "build": {},
        "tasks": {"planning": {"default_penalty": 1.0}, "retrieval": {"standing_only": False, "sg_widen": False}},
    },
    "after": {"build": {}, "tasks": {}},
}
PENALTY_GRID = [0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0]  # planner penalties swept on the validation seed


def ensure_map(cache: Path, preset: str, seed: int) -> tuple[Path, Path]:
    """The cached dataset and map of a preset and seed, simulated and mapped when missing."""
    folder = cache / f"{preset}-seed{seed}"
    dataset, bundle = folder / "dataset", folder / "map.terra"
    folder.mkdir(parents=True, exist_ok=True)
    if not dataset.exists():
        subprocess.run(
            [sys.executable, "-m", "terra", "sim", "--preset", preset, "--seed", str(seed), "--out", str(dataset)],
            check=True,
        )
    if not bundle.exists():
        subprocess.run(
            [sys.executable, "-m", "terra", "map", str(dataset), "--out", str(bundle), "--noise", "realistic", "-q"],
            check=True,
        )
    return dataset, bundle


def graph_bundle(cache: Path, preset: str, seed: int, work: Path, config: dict) -> tuple[Path, Path, float]:
    """A copy of the cached map with a scene graph built by this checkout (`config`: build
    configuration overrides)."""
    from terra.graph.config import BuildConfig
    from terra.graph.pipeline import build_graph

    dataset, bundle = ensure_map(cache, preset, seed)
    out = work / f"{preset}-seed{seed}.terra"
    key = (str(out), repr(config))
    if key in BUILT:  # built by this run already, with the same configuration
        return dataset, out, BUILT[key]
    if out.exists():
        shutil.rmtree(out)
    work.mkdir(parents=True, exist_ok=True)
    shutil.copytree(bundle, out)
    start = time.perf_counter()
    build_graph(out, BuildConfig.model_validate(config), progress=False)
    BUILT[key] = time.perf_counter() - start
    return dataset, out, BUILT[key]


BUILT: dict[tuple[str, str], float] = {}  # graphs built by this run: seconds


def levels_of(bundle: Path, method: str, cuts: list[float] | None = None) -> list[int]:
    """Regions per level of `method` rebuilt on the bundle's places."""
    from terra.bundle import Bundle
    from terra.graph.config import BuildConfig
    from terra.graph.pipeline import region_assignments
    from terra.graph.regions import build_levels
    from terra.graph.storage import load_scene_graph

    graph = load_scene_graph(Bundle(bundle))
    config = BuildConfig.model_validate({"regions": {"method": method, "cuts": cuts}})
    p = graph.places
    return [
        len(level)
        for level in build_levels(
            region_assignments(p.position, p.embedding, p.terrain, graph.place_edges, config), p.position, p.embedding
        )
    ]


def connectivity(bundle: Path, dataset: Path) -> dict:
    from terra.bundle import Bundle
    from terra.datasets.ground_truth import load_ground_truth
    from terra.eval.metrics.places import observed_cells, place_terrain_agreement, same_terrain_connectivity
    from terra.graph.storage import load_scene_graph
    from terra.mapping.storage import load_map

    graph, msm, gt = load_scene_graph(Bundle(bundle)), load_map(Bundle(bundle)), load_ground_truth(dataset)
    terrain = _terrain(gt, dataset)
    seen = observed_cells(terrain, msm.points[msm.terrain_index(0.5) >= 0])
    return {
        "places": len(graph.places),
        "whole_raster": same_terrain_connectivity(graph, terrain).to_json(),
        "labelled_ground": same_terrain_connectivity(graph, terrain, seen).to_json(),
        "terrain_agreement": place_terrain_agreement(graph, terrain).to_json(),
    }


def _terrain(gt, dataset: Path):
    """The ground truth's terrain raster; these measures need one."""
    if gt.terrain is None:
        raise SystemExit(f"{dataset}: the ground truth has no terrain raster")
    return gt.terrain


def scene_extras(bundle: Path, dataset: Path) -> dict:
    """What the evaluation report does not hold: how many places sit on their own terrain."""
    from terra.eval.inputs import EvalInputs
    from terra.eval.metrics.places import place_terrain_agreement

    inputs = EvalInputs.load(bundle, dataset)
    return {"terrain_agreement": place_terrain_agreement(inputs.graph, _terrain(inputs.gt, dataset)).to_json()}


def validation_penalty_sweep(bundle: Path, dataset: Path, config) -> dict:
    """The planner penalty chosen on the validation scene: every place pair joined by a sidewalk
    route over the labelled ground, planned preferring sidewalk under each penalty of PENALTY_GRID
    (terra.eval.navigation.penalty_sweep, choose_penalty)."""
    from terra.eval.inputs import EvalInputs
    from terra.eval.metrics.places import observed_cells
    from terra.eval.navigation import choose_penalty, penalty_sweep, terrain_route_pairs

    inputs = EvalInputs.load(bundle, dataset)
    nav = config.navigation
    terrain = _terrain(inputs.gt, dataset)
    seen = observed_cells(terrain, inputs.msm.points[inputs.msm.terrain_index(0.5) >= 0])
    pairs = terrain_route_pairs(inputs.graph, terrain, nav.prefer[0], seen, max_pairs=10**9)
    points = penalty_sweep(inputs.graph, terrain, pairs, nav.prefer[0], PENALTY_GRID, nav.min_share, nav.step)
    return {
        "terrain": nav.prefer[0],
        "pairs": len(pairs),
        "chosen": choose_penalty(points),
        "points": [p.to_json() for p in points],
    }


def test_scene(summary: dict) -> dict:
    """The figures of one evaluated test scene."""
    reg, ret, nav = summary["regions"]["methods"], summary["retrieval"]["methods"], summary["navigation"]
    routes = nav.get("preference_routes", {})
    return {
        "regions": {
            m: {
                k: reg[m][k]
                for k in ("precision", "recall", "f1", "regions_ms", "query_ms", "runtime_ms", "parameters")
            }
            for m in reg
        },
        "regions_per_level": summary["regions"]["regions_per_level"],
        "retrieval": {
            m: {
                k: ret[m][k]
                for k in (
                    "f1",
                    "iou",
                    "matched_iou",
                    "relaxed_accuracy",
                    "relaxed_precision",
                    "smallest_box_side_m",
                    "alpha",
                    "iou_by_distance",
                )
            }
            for m in ret
        },
        "navigation": {
            "preference_routes": routes,
            "case": nav.get("preference_case"),
            "task_plans": {k: nav[k] for k in ("plans", "goal_object", "error", "candidates", "alpha") if k in nav},
            "skipped": nav.get("skipped", []),
        },
        "places": summary["places"],
    }


def run_config(name: str, overrides: dict, args, eval_config) -> dict:
    """Every figure of one build configuration: tuned on the validation seed, then the test seeds,
    the paper's cuts, and the other presets."""
    from terra.eval.inputs import EvalInputs
    from terra.eval.runner import evaluate, tune
    from terra.tasks.config import TasksConfig

    work = args.work / "graphs"
    tasks = TasksConfig.model_validate(overrides["tasks"])
    out: dict = {"build_config": overrides["build"], "tasks_config": overrides["tasks"]}
    overrides = overrides["build"]
    val_data, val_bundle, _ = graph_bundle(args.cache, "small", args.validation_seed, work, overrides)
    start = time.perf_counter()
    tuned = tune(EvalInputs.load(val_bundle, val_data), eval_config, tasks)
    out["tune_seconds"] = time.perf_counter() - start
    out["tuned"] = tuned.to_json()
    out["small"] = {}
    for seed in [int(s) for s in args.seeds.split(",")]:
        dataset, bundle, build_s = graph_bundle(args.cache, "small", seed, work, overrides)
        summary = evaluate(
            bundle, dataset, args.work / name / f"report-seed{seed}", eval_config, tuned, tasks, show_progress=False
        ).summary()
        out["small"][seed] = {**test_scene(summary), **scene_extras(bundle, dataset), "build_seconds": build_s}
    out["small_paper_cuts"] = {
        "seed": seed,
        "regions_per_level": levels_of(bundle, "agglomerative", [50.0, 100.0, 200.0, 400.0]),
    }
    out["presets"] = {}
    for preset in ["tiny"] + ([] if args.no_campus else ["campus"]):
        dataset, bundle, build_s = graph_bundle(args.cache, preset, 0, work, overrides)
        out["presets"][preset] = {
            **connectivity(bundle, dataset),
            "build_seconds": build_s,
            "regions_per_level": {m: levels_of(bundle, m) for m in ("agglomerative", "spectral")},
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument(
        "--cache", type=Path, default=Path(os.environ.get("TERRA_BENCH_CACHE", "/work/bench-cache/issue-14"))
    )
    parser.add_argument("--work", type=Path, default=None, help="where graphs and reports go (default: CACHE/bench)")
    parser.add_argument("--seeds", default="0,2,3")
    parser.add_argument("--validation-seed", type=int, default=1)
    parser.add_argument("--no-campus", action="store_true")
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "regions_nav.json", help="JSON written")
    args = parser.parse_args()
    args.work = args.work or args.cache / "bench"
    from terra.eval.config import EvalConfig

    result = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "load_average_1min_at_start": os.getloadavg()[0],
        "date": time.strftime("%Y-%m-%d"),
        "targets": TARGETS,
    }
    config = EvalConfig.model_validate({"figures": False, "segmentation": {"max_images": 0}})
    result["configs"] = {name: run_config(name, overrides, args, config) for name, overrides in CONFIGS.items()}
    val_data, val_bundle, _ = graph_bundle(args.cache, "small", args.validation_seed, args.work / "graphs", {})
    result["validation_penalty_sweep"] = validation_penalty_sweep(val_bundle, val_data, config)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")  # kept even if the table fails
    report(rows(result), result, args.out)


def side(result: dict, get, fmt: str = "{:.3f}") -> str:
    """'before -> after' of one figure."""
    values = []
    for c in result["configs"].values():
        try:
            values.append(fmt.format(get(c)))
        except (KeyError, TypeError):
            values.append("-")
    return " -> ".join(values)


def rows(result: dict) -> list[tuple[str, str, str]]:
    out = []
    first = next(iter(result["configs"].values()))
    for seed in first["small"]:

        def sc(c, seed=seed):
            return c["small"][seed]

        for m, target in (("agglomerative", ">= 0.70"), ("spectral", ">= 0.60"), ("aib", "below both")):
            out.append((f"seed {seed}: regions F1 {m}", side(result, lambda c, m=m: sc(c)["regions"][m]["f1"]), target))
        out.append(
            (
                f"seed {seed}: regions runtime ms (build + query) agg / spec / AIB",
                side(
                    result,
                    lambda c: " / ".join(
                        f"{sc(c)['regions'][m]['runtime_ms']:.0f}" for m in ("agglomerative", "spectral", "aib")
                    ),
                    "{}",
                ),
                "-",
            )
        )
        out.append(
            (
                f"seed {seed}: regions per level agg ; spec",
                side(
                    result,
                    lambda c: " ; ".join("/".join(map(str, v)) for v in sc(c)["regions_per_level"].values()),
                    "{}",
                ),
                "strictly decreasing",
            )
        )
        for m in ("ms-avg", "3dsg"):
            out.append(
                (
                    f"seed {seed}: retrieval {m} F1 / matched IoU / thinnest side m",
                    side(
                        result,
                        lambda c, m=m: "{:.3f} / {:.3f} / {:.2f}".format(
                            *(sc(c)["retrieval"][m][k] for k in ("f1", "matched_iou", "smallest_box_side_m"))
                        ),
                        "{}",
                    ),
                    ">= 0.75 / >= 0.5 / >= 0.05",
                )
            )
        out.append(
            (
                f"seed {seed}: sidewalk preferred: mean share / pairs >= 80%",
                side(
                    result,
                    lambda c: "{:.3f} / {:.3f}".format(
                        sc(c)["navigation"]["preference_routes"]["preferred_mean_share"],
                        sc(c)["navigation"]["preference_routes"]["fraction_meeting"],
                    ),
                    "{}",
                ),
                ">= 0.8 where a sidewalk route exists",
            )
        )
        out.append(
            (
                f"seed {seed}: task plan: goal object score (or why none)",
                side(
                    result,
                    lambda c: (
                        "{:.3f}".format(sc(c)["navigation"]["task_plans"]["goal_object"]["score"])
                        if "goal_object" in (sc(c)["navigation"]["task_plans"] or {})
                        else "none"
                    ),
                    "{}",
                ),
                "an object",
            )
        )
        out.append(
            (
                f"seed {seed}: navigation case sidewalk m shortest / preferred",
                side(
                    result,
                    lambda c: " / ".join(
                        f"{p['gt_terrain_m'].get('sidewalk', 0):.1f} of {p['length_m']:.1f}"
                        for p in sc(c)["navigation"]["case"]["plans"].values()
                    ),
                    "{}",
                ),
                "a change",
            )
        )
        out.append(
            (
                f"seed {seed}: places / same-terrain pairs joined (labelled ground ; raster)",
                side(
                    result,
                    lambda c: "{} / {:.3f} ; {:.3f}".format(
                        sc(c)["places"]["places"],
                        sc(c)["places"]["connectivity_seen"]["joined_share"],
                        sc(c)["places"]["connectivity"]["joined_share"],
                    ),
                    "{}",
                ),
                ">= 0.99",
            )
        )
        out.append(
            (
                f"seed {seed}: places on their own terrain / > 1 m from it",
                side(
                    result,
                    lambda c: "{:.3f} / {}".format(
                        sc(c)["terrain_agreement"]["share"], sc(c)["terrain_agreement"]["farther_than_m"]["1"]
                    ),
                    "{}",
                ),
                "-",
            )
        )
    out.append(
        (
            "small: regions per level with --cuts 50,100,200,400",
            side(result, lambda c: "/".join(map(str, c["small_paper_cuts"]["regions_per_level"])), "{}"),
            "the paper's",
        )
    )
    for preset in first["presets"]:

        def pc(c, preset=preset):
            return c["presets"][preset]

        out.append(
            (
                f"{preset}: places / same-terrain pairs joined (labelled ground ; raster)",
                side(
                    result,
                    lambda c: "{} / {:.3f} ; {:.3f}".format(
                        pc(c)["places"], pc(c)["labelled_ground"]["joined_share"], pc(c)["whole_raster"]["joined_share"]
                    ),
                    "{}",
                ),
                ">= 0.99",
            )
        )
        out.append(
            (
                f"{preset}: places on their own terrain / > 1 m from it",
                side(
                    result,
                    lambda c: "{:.3f} / {}".format(
                        pc(c)["terrain_agreement"]["share"], pc(c)["terrain_agreement"]["farther_than_m"]["1"]
                    ),
                    "{}",
                ),
                "-",
            )
        )
        out.append(
            (
                f"{preset}: regions per level agg ; spec",
                side(
                    result,
                    lambda c: " ; ".join("/".join(map(str, v)) for v in pc(c)["regions_per_level"].values()),
                    "{}",
                ),
                "strictly decreasing",
            )
        )
        out.append((f"{preset}: terra build (s)", side(result, lambda c: pc(c)["build_seconds"], "{:.1f}"), "-"))
    sweep = result["validation_penalty_sweep"]
    for p in sweep["points"]:
        out.append(
            (
                f"validation seed: penalty {p['penalty']:g}: pairs >= 80 % / mean detour / max detour",
                f"{p['meeting']} of {p['pairs']} / {p['mean_detour']:.3f} / {p['max_detour']:.2f}",
                "chosen" if p["penalty"] == sweep["chosen"] else "-",
            )
        )
    return out


if __name__ == "__main__":
    main()
