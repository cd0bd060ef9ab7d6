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
missing: about 2 minutes per small seed, 6 for the campus); graphs are rebuilt with this checkout.

Usage: python benchmarks/bench_regions_nav.py [--cache DIR] [--seeds 0,2,3] [--no-campus]
Writes benchmarks/results/regions_nav.json and prints a table.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT.parent))
from benchmarks.benchtable import report  # noqa: E402

TARGETS = {"agglomerative_f1": 0.70, "spectral_f1": 0.60, "matched_iou": 0.5, "retrieval_f1": 0.75, "sidewalk_share": 0.8,
           "connectivity": 0.99, "box_side": 0.05}


def ensure_map(cache: Path, preset: str, seed: int) -> tuple[Path, Path]:
    """The cached dataset and map of a preset and seed, simulated and mapped when missing."""
    folder = cache / f"{preset}-seed{seed}"
    dataset, bundle = folder / "dataset", folder / "map.terra"
    folder.mkdir(parents=True, exist_ok=True)
    if not dataset.exists():
        subprocess.run([sys.executable, "-m", "terra", "sim", "--preset", preset, "--seed", str(seed), "--out", str(dataset)], check=True)
    if not bundle.exists():
        subprocess.run([sys.executable, "-m", "terra", "map", str(dataset), "--out", str(bundle), "--noise", "realistic", "-q"], check=True)
    return dataset, bundle


def graph_bundle(cache: Path, preset: str, seed: int, work: Path) -> tuple[Path, Path, float]:
    """A copy of the cached map with a scene graph built by this checkout (default config)."""
    from terra.graph.pipeline import build_graph

    dataset, bundle = ensure_map(cache, preset, seed)
    out = work / f"{preset}-seed{seed}.terra"
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(bundle, out)
    start = time.perf_counter()
    build_graph(out, progress=False)
    return dataset, out, time.perf_counter() - start


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
    return [len(level) for level in build_levels(region_assignments(p.position, p.embedding, p.terrain, graph.place_edges, config), p.position, p.embedding)]


def connectivity(bundle: Path, dataset: Path) -> dict:
    from terra.bundle import Bundle
    from terra.datasets.ground_truth import load_ground_truth
    from terra.eval.metrics.places import observed_cells, same_terrain_connectivity
    from terra.graph.storage import load_scene_graph
    from terra.mapping.storage import load_map

    graph, msm, gt = load_scene_graph(Bundle(bundle)), load_map(Bundle(bundle)), load_ground_truth(dataset)
    seen = observed_cells(gt.terrain, msm.points[msm.terrain_index(0.5) >= 0])
    return {"places": len(graph.places), "whole_raster": same_terrain_connectivity(graph, gt.terrain).to_json(),
            "labelled_ground": same_terrain_connectivity(graph, gt.terrain, seen).to_json()}


def test_scene(summary: dict) -> dict:
    """The figures of one evaluated test scene."""
    reg, ret, nav = summary["regions"]["methods"], summary["retrieval"]["methods"], summary["navigation"]
    routes = nav.get("preference_routes", {})
    return {
        "regions": {m: {k: reg[m][k] for k in ("precision", "recall", "f1", "regions_ms", "query_ms", "runtime_ms", "parameters")} for m in reg},
        "regions_per_level": summary["regions"]["regions_per_level"],
        "retrieval": {m: {k: ret[m][k] for k in ("f1", "iou", "matched_iou", "relaxed_accuracy", "relaxed_precision", "smallest_box_side_m",
                                                 "alpha", "iou_by_distance")} for m in ret},
        "navigation": {"preference_routes": routes, "case": nav.get("preference_case"), "task_plans": nav.get("plans"),
                       "skipped": nav.get("skipped", [])},
        "places": summary["places"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, default=Path(os.environ.get("TERRA_BENCH_CACHE", "/work/bench-cache/issue-14")))
    parser.add_argument("--seeds", default="0,2,3")
    parser.add_argument("--validation-seed", type=int, default=1)
    parser.add_argument("--no-campus", action="store_true")
    args = parser.parse_args()
    from terra.eval.config import EvalConfig
    from terra.eval.runner import EvalInputs, evaluate, tune

    result = {"machine": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count(),
              "load_average_1min_at_start": os.getloadavg()[0], "date": time.strftime("%Y-%m-%d"), "targets": TARGETS}
    work = args.cache / "bench"
    work.mkdir(parents=True, exist_ok=True)
    config = EvalConfig.model_validate({"figures": False, "segmentation": {"max_images": 0}})
    val_data, val_bundle, _ = graph_bundle(args.cache, "small", args.validation_seed, work)
    start = time.perf_counter()
    tuned = tune(EvalInputs.load(val_bundle, val_data), config)
    result["tune_seconds"] = time.perf_counter() - start
    result["tuned"] = tuned.to_json()
    result["small"] = {}
    for seed in [int(s) for s in args.seeds.split(",")]:
        dataset, bundle, build_s = graph_bundle(args.cache, "small", seed, work)
        summary = evaluate(bundle, dataset, work / f"report-seed{seed}", config, tuned, show_progress=False)
        result["small"][seed] = {**test_scene(summary), "build_seconds": build_s}
    result["small_paper_cuts"] = {"seed": seed, "regions_per_level": levels_of(bundle, "agglomerative", [50.0, 100.0, 200.0, 400.0])}
    presets = ["tiny"] + ([] if args.no_campus else ["campus"])
    result["presets"] = {}
    for preset in presets:
        dataset, bundle, build_s = graph_bundle(args.cache, preset, 0, work)
        result["presets"][preset] = {**connectivity(bundle, dataset), "build_seconds": build_s,
                                     "regions_per_level": {m: levels_of(bundle, m) for m in ("agglomerative", "spectral")}}
    report(rows(result), result, ROOT / "results" / "regions_nav.json")


def rows(result: dict) -> list[tuple[str, str, str]]:
    out = []
    seeds = result["small"]
    for seed, s in seeds.items():
        reg, ret = s["regions"], s["retrieval"]
        out.append((f"seed {seed}: regions F1 agglomerative / spectral / AIB",
                    f"{reg['agglomerative']['f1']:.3f} / {reg['spectral']['f1']:.3f} / {reg['aib']['f1']:.3f}", ">= 0.70 / >= 0.60 / below both"))
        out.append((f"seed {seed}: regions runtime ms (build + query) agg / spec / AIB",
                    " / ".join(f"{reg[m]['runtime_ms']:.0f}" for m in ("agglomerative", "spectral", "aib")), "-"))
        out.append((f"seed {seed}: regions per level agg / spec", " ; ".join("/".join(map(str, c)) for c in s["regions_per_level"].values()),
                    "strictly decreasing"))
        for m in ("ms-avg", "3dsg"):
            r = ret[m]
            out.append((f"seed {seed}: retrieval {m} F1 / matched IoU / thinnest side m", f"{r['f1']:.3f} / {r['matched_iou']:.3f} / {r['smallest_box_side_m']:.2f}",
                        ">= 0.75 / >= 0.5 / >= 0.05"))
        routes = s["navigation"]["preference_routes"]
        out.append((f"seed {seed}: sidewalk preferred: mean share / pairs >= 80%", f"{routes.get('preferred_mean_share', 0):.3f} / "
                    f"{routes.get('fraction_meeting', 0):.3f} of {routes.get('pairs', 0)}", ">= 0.8 where a sidewalk route exists"))
        case = s["navigation"]["case"]
        if case:
            plans = case["plans"]
            out.append((f"seed {seed}: case {case['start_place']}->{case['goal_place']} sidewalk m shortest / preferred",
                        " / ".join(f"{p['gt_terrain_m'].get('sidewalk', 0):.1f} of {p['length_m']:.1f}" for p in plans.values()), "a change"))
        c = s["places"]
        out.append((f"seed {seed}: places same-terrain pairs joined (labelled ground / raster)",
                    f"{c['connectivity_seen']['joined_share']:.3f} / {c['connectivity']['joined_share']:.3f}", ">= 0.99"))
    paper = result["small_paper_cuts"]
    out.append((f"seed {paper['seed']}: regions per level with --cuts 50,100,200,400", "/".join(map(str, paper["regions_per_level"])), "the paper's"))
    for preset, p in result["presets"].items():
        out.append((f"{preset}: places same-terrain pairs joined (labelled ground / raster)",
                    f"{p['labelled_ground']['joined_share']:.3f} / {p['whole_raster']['joined_share']:.3f}", ">= 0.99"))
        out.append((f"{preset}: regions per level agg / spec", " ; ".join("/".join(map(str, c)) for c in p["regions_per_level"].values()),
                    "strictly decreasing"))
        out.append((f"{preset}: terra build (s)", f"{p['build_seconds']:.1f}", "-"))
    return out


if __name__ == "__main__":
    main()
