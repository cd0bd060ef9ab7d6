"""Ground geometry (issue 27): ground segmentation, the LiDAR-only build of real scans, wheelchair
plans judged against the simulator's ground, and what the geometry layers add to `terra build`.

Sections (each skipped when its input is not given):
- segmentation: F1 of terra.graph.ground.segment_ground for ground (the simulator's terrain
  classes and crosswalk paint) against everything else, on `--frames` frames of a simulated
  preset fused in the map frame; and, with `--kitti DIR` (KITTI .bin scans), its agreement with
  Patchwork++ (pypatchworkpp, when installed) on each scan.
- labelled: with `--labelled SEQ` (a SemanticKITTI sequence with velodyne/ and labels/), the
  scores of `terra eval --ground-only` (terra.eval.ground_segmentation) for segment_ground and, when
  pypatchworkpp is installed, for Patchwork++ on the same scans and labels; and the step layer
  on each scan's road, where the labels say what it should read (`steps_on_labelled_road`).
- lidar-only: `terra map --poses odometry` (KISS-ICP) and `terra build` of the KITTI scans in
  `--kitti DIR`, and the share of the largest connected patch of densely observed ground cells
  (>= 60 % of a 9 x 9 window observed) within 3, 5 and 10 m of a place; and the share of its
  place edges each of the wheelchair's rules refuses.
- wheelchair: `--pairs` random start-goal place pairs on the graph of `--wheelchair-map` (a map
  of the simulated `--wheelchair-preset` with the `sim:` section of `--sim-config`, e.g. a larger
  `ground_relief_m` for slopes beyond the wheelchair's), planned with and without the wheelchair
  profile; each path is judged
  on the simulator's own ground (its analytic height field, sampled every 0.25 m, slopes over 1 m):
  paths over the profile's slope, and pairs whose free path is legal on that ground but for which
  the wheelchair got no path (a legal route missed).
- build-time: `build_scene_graph` on `--campus-map` with build.ground.layers true and false, and
  true without the level routes (build.linking.level_route_length null), alternating, best of
  `--repeat` runs each (wall and CPU seconds); with `--ground-before FILE`
  (terra/graph/ground.py of another commit) its segmentation and layers as a third run. Then the
  whole `terra build` command, layers false and true, `--repeat` runs each in turn: the medians
  and the median of the paired ratios (what a user waits for: the map's loading and the
  bundle's writing included).

Usage:
  python benchmarks/bench_geometry.py [--preset tiny] [--frames 40] [--kitti DIR] [--labelled SEQ]
      [--campus-map BUNDLE] [--repeat 3] [--ground-before FILE]
      [--wheelchair-map BUNDLE --wheelchair-preset small --sim-config FILE --pairs 200]
Writes benchmarks/results/geometry.json (or --out) and prints it.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from importlib.metadata import version as package_version
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from terra.bundle import Bundle

RESULTS = Path(__file__).resolve().parent / "results" / "geometry.json"


def f1_score(found: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    tp = int((found & truth).sum())
    fp, fn = int((found & ~truth).sum()), int((~found & truth).sum())
    return {
        "precision": round(tp / max(tp + fp, 1), 4),
        "recall": round(tp / max(tp + fn, 1), 4),
        "f1": round(2 * tp / max(2 * tp + fp + fn, 1), 4),
    }


def segmentation_sim(preset: str, seed: int, frames: int) -> dict[str, Any]:
    """segment_ground on the first `frames` frames of a simulated drive, against its labels."""
    from terra.datasets.sim_classes import SIM_CLASSES, class_id
    from terra.graph.ground import segment_ground
    from terra.sim import simulate
    from terra.sim.config import SimConfig

    dataset = simulate(preset, seed, SimConfig.model_validate({"route": {"max_frames": frames}, "cameras": []}))
    ground_ids = [c.id for c in SIM_CLASSES if c.terrain] + [class_id("crosswalk")]
    points, labels = [], []
    for i in range(len(dataset)):
        frame = dataset[i]
        T = frame.T_map_lidar
        points.append(frame.points @ T[:3, :3].T + T[:3, 3])
        labels.append(frame.point_labels)
    cloud = np.vstack(points)
    start = time.perf_counter()
    found = segment_ground(cloud)
    seconds = time.perf_counter() - start
    truth = np.isin(np.concatenate(labels), ground_ids)
    return {"preset": preset, "frames": len(dataset), "points": len(cloud), "seconds": round(seconds, 3)} | f1_score(
        found, truth
    )


def patchwork() -> tuple[Callable[[np.ndarray], np.ndarray], str] | None:
    """Patchwork++ (pypatchworkpp, default parameters) as a ground segmenter of one scan, (N, 4) x, y,
    z, reflectance or (N, 3) without it (then 0), and its name; None when it is not installed."""
    try:
        import pypatchworkpp  # pyright: ignore[reportMissingImports]  # optional: pip install pypatchworkpp
    except ImportError:
        return None
    params = pypatchworkpp.Parameters()
    params.verbose = False
    estimator = pypatchworkpp.patchworkpp(params)

    def ground(scan: np.ndarray) -> np.ndarray:
        if scan.shape[1] == 3:
            scan = np.column_stack([scan, np.zeros(len(scan))])
        estimator.estimateGround(np.asarray(scan, dtype=np.float32))
        found = np.zeros(len(scan), dtype=bool)
        found[np.asarray(estimator.getGroundIndices(), dtype=np.int64)] = True
        return found

    return ground, f"Patchwork++ (pypatchworkpp {package_version('pypatchworkpp')})"


def segmentation_kitti(folder: Path) -> dict[str, Any]:
    """Agreement of segment_ground with Patchwork++ on every KITTI scan in `folder`."""
    from terra.graph.ground import segment_ground

    reference_method = patchwork()
    if reference_method is None:
        return {"skipped": "pypatchworkpp is not installed"}
    reference_ground, name = reference_method
    rows = []
    for path in sorted(folder.glob("*.bin")):
        scan = np.fromfile(path, dtype=np.float32).reshape(-1, 4)
        reference = reference_ground(scan)
        start = time.perf_counter()
        found = segment_ground(scan[:, :3])
        seconds = time.perf_counter() - start
        rows.append({"scan": path.name, "points": len(scan), "seconds": round(seconds, 3)} | f1_score(found, reference))
    mean = {k: round(float(np.mean([r[k] for r in rows])), 4) for k in ("precision", "recall", "f1")}
    return {"reference": name, "scans": rows, "mean": mean}


ROAD, SIDEWALK = 40, 48  # SemanticKITTI ids


def steps_on_labelled_road(sequence: Path, cell_size: float = 0.4) -> dict[str, Any]:
    """The step layer (terra.graph.ground.ground_layers on segment_ground's ground, one scan at a
    time, its steps across gaps on their high edges as a build leaves them, held_across_gaps;
    cells of `cell_size` metres) on real labelled scans, where the labels say what it should
    read: cells whose ground points are all road with no other labelled ground within two cells
    (a road's interior: no step there), and road cells beside a sidewalk cell (where curbs are).
    Per scan: the cells, the 50th/90th/99th percentiles of their step (metres) and the share
    above the wheelchair's 5 cm."""
    from scipy import ndimage

    from terra.eval.ground_segmentation import labelled_scans, read_labelled_scan
    from terra.graph.grid import GridFrame
    from terra.graph.ground import ground_layers, held_across_gaps, segment_ground

    _, pairs = labelled_scans(sequence)
    rows = []
    for scan, label in pairs:
        points, labels = read_labelled_scan(scan, label)
        ground = segment_ground(points)
        xy, labels = points[ground, :2].astype(np.float64), labels[ground]
        low = xy.min(axis=0) - 2 * cell_size
        size = np.ceil((xy.max(axis=0) + 2 * cell_size - low) / cell_size).astype(int)
        shape = (int(size[1]), int(size[0]))
        frame = GridFrame((float(low[0]), float(low[1])), shape, cell_size)
        layers = held_across_gaps(ground_layers(points[ground], frame))  # as a build leaves it
        cell = np.floor((xy - low) / cell_size).astype(np.int64)
        flat = cell[:, 1] * shape[1] + cell[:, 0]
        road = np.bincount(flat, labels == ROAD, shape[0] * shape[1]) == np.bincount(flat, None, shape[0] * shape[1])
        held = np.bincount(flat, None, shape[0] * shape[1]) > 0
        road, held = np.asarray(road & held, dtype=bool).reshape(shape), held.reshape(shape)
        walk = (np.bincount(flat[labels == SIDEWALK], None, shape[0] * shape[1]) > 0).reshape(shape)
        other = held & ~road
        kinds = {
            "road_interior": road
            & ~np.asarray(ndimage.binary_dilation(other, np.ones((5, 5), dtype=bool)), dtype=bool),
            "road_beside_sidewalk": road & ndimage.binary_dilation(walk, np.ones((3, 3), dtype=bool)),
        }
        step = layers.as_grid(layers.step)
        row: dict[str, Any] = {"scan": f"{scan.parent.parent.name}/{scan.stem}"}
        for name, mask in kinds.items():
            read = step[mask & np.isfinite(step)]
            row[name] = {
                "cells": len(read),
                "step_m_percentiles_50_90_99": [round(float(v), 3) for v in np.percentile(read, [50, 90, 99])]
                if len(read)
                else None,
                "share_over_5cm": round(float(np.mean(read > 0.05)), 4) if len(read) else None,
            }
        rows.append(row)
    return {"sequence": str(sequence), "scans": rows}


def segmentation_labelled(sequence: Path) -> dict[str, Any]:
    """`terra eval --ground-only` scores of segment_ground, and of Patchwork++ when installed, on the
    labelled scans of a SemanticKITTI sequence."""
    from terra.eval.ground_segmentation import ground_table

    tables = {"segment_ground": ground_table(sequence)}
    reference_method = patchwork()
    if reference_method is not None:
        reference_ground, name = reference_method
        tables[name] = ground_table(sequence, segment=reference_ground, method=name)
    out: dict[str, Any] = {}
    for name, table in tables.items():
        keys = ("precision", "recall", "f1")
        out[name] = {
            "scans": len(table.scans),
            "points": sum(s.scored for s in table.scans),
            "pooled": {k: round(v, 4) for k, v in zip(keys, table.pooled())},
            "mean_per_scan": {k: round(v, 4) for k, v in zip(keys, table.mean())},
            "seconds_per_scan": round(sum(s.seconds for s in table.scans) / max(len(table.scans), 1), 4),
        }
    return {"sequence": str(sequence), "methods": out}


def lidar_only_build(folder: Path, work: Path) -> dict[str, Any]:
    """Map the KITTI scans with odometry, build, and measure how much of the ground has places."""
    from terra.bundle import Bundle
    from terra.graph.storage import load_scene_graph

    sequence = work / "sequences" / "00" / "velodyne"
    sequence.mkdir(parents=True)
    for path in sorted(folder.glob("*.bin")):
        shutil.copy(path, sequence / path.name)
    bundle = work / "kitti.terra"
    seconds = {}
    for name, argv in (
        ("map", ["map", str(sequence.parent), "-o", str(bundle), "--poses", "odometry"]),
        ("build", ["build", str(bundle)]),
    ):
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "terra", *argv], check=True, capture_output=True)
        seconds[name] = round(time.perf_counter() - start, 2)
    graph = load_scene_graph(Bundle(bundle))
    return (
        {"scans": len(list(sequence.glob("*.bin"))), "places": len(graph.places), "seconds": seconds}
        | coverage(Bundle(bundle), graph.places.position)
        | {"wheelchair_edges": wheelchair_edge_rules(graph.place_edge_geometry)}
    )


def wheelchair_edge_rules(geometry: np.ndarray) -> dict[str, Any]:
    """How the place edges' ground geometry (E, 5) (terra.graph.ground.edge_geometry) reads on real
    scans, and the share of edges each of the wheelchair's rules refuses (an edge can fail several):
    the step, the climb or descent either way, the side slope, the unobserved stretch."""
    from terra.tasks.robot import ROBOTS

    chair = ROBOTS["wheelchair"]
    g = np.asarray(geometry, dtype=np.float64)
    if len(g) == 0:
        return {"edges": 0}
    rules = {
        "step": g[:, 0] > chair.max_step,
        "slope_along": np.maximum(g[:, 1], g[:, 2]) > chair.max_slope_up,
        "side_slope": g[:, 4] > chair.cross_limit,
        "unobserved": g[:, 3] > chair.max_unobserved,
    }
    _, legal = chair.edge_rules(g)
    return {
        "edges": len(g),
        "refused_share_by": {k: round(float(v.mean()), 4) for k, v in rules.items()},
        "refused_only_by_side_slope": int((rules["side_slope"] & ~rules["step"] & ~rules["slope_along"]).sum()),
        "legal_both_ways_share": round(float((legal[: len(g)] & legal[len(g) :]).mean()), 4),
        "side_slope_deg_percentiles_50_90_99": [round(float(v), 2) for v in np.percentile(g[:, 4], [50, 90, 99])],
        "slope_along_deg_percentiles_50_90_99": [
            round(float(v), 2) for v in np.percentile(np.maximum(g[:, 1], g[:, 2]), [50, 90, 99])
        ],
    }


def coverage(bundle: Bundle, places: np.ndarray) -> dict[str, Any]:
    """Share of the largest connected patch of densely observed ground cells within 3, 5, 10 m of a place."""
    from scipy import ndimage
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled module

    graph = bundle.model.components.graph
    info = graph.ground if graph is not None else None
    if info is None:
        return {"skipped": "the graph has no ground layers"}
    observed = np.zeros(int(np.prod(info.shape)), dtype=bool)
    observed[np.asarray(bundle.array("graph/ground_cells"), dtype=np.int64)] = True
    observed = observed.reshape(info.shape)
    dense = observed & (ndimage.uniform_filter(observed.astype(np.float32), 9) >= 0.6)
    from terra.graph.raster import label

    labels, _ = label(dense, structure=np.ones((3, 3), dtype=bool))
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    rows, cols = np.nonzero(labels == sizes.argmax())
    offset = info.offset
    xy = np.asarray(info.origin) + (np.column_stack([cols + offset[1], rows + offset[0]]) + 0.5) * info.cell_size
    distance = cKDTree(places[:, :2]).query(xy)[0]
    return {
        "observed_cells": int(observed.sum()),
        "dense_patch_cells": len(rows),
        "covered_within_m": {str(r): round(float((distance <= r).mean()), 4) for r in (3, 5, 10)},
    }


def truth_slopes(world, waypoints: np.ndarray, spacing: float = 0.25, base: float = 1.0) -> tuple[float, float]:
    """Steepest climb and descent (degrees) along a path on the simulator's height field: samples
    every `spacing` m along the waypoints' segments, slopes over `base` m of travel."""
    xy = np.asarray(waypoints, dtype=np.float64)[:, :2]
    pieces = [xy[:1]]
    for a, b in zip(xy[:-1], xy[1:]):
        n = max(int(np.ceil(np.linalg.norm(b - a) / spacing)), 1)
        pieces.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
    samples = np.vstack(pieces)
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(samples, axis=0), axis=1))])
    height = world.ground.height(samples)
    ahead = np.searchsorted(travelled, travelled + base)
    ok = ahead < len(samples)
    if not ok.any():
        return 0.0, 0.0
    rise = (height[ahead[ok]] - height[ok]) / (travelled[ahead[ok]] - travelled[ok])
    degrees = np.degrees(np.arctan(rise))
    return float(max(degrees.max(), 0.0)), float(max(-degrees.min(), 0.0))


def wheelchair_pairs(graph, world, pairs: int, seed: int = 0) -> dict[str, Any]:
    """Plans between random place pairs with and without the wheelchair, judged on the true ground."""
    from terra.errors import NoPathError
    from terra.tasks.planning import CostGraph, TerrainCosts, plan_on
    from terra.tasks.robot import ROBOTS

    chair = ROBOTS["wheelchair"]
    costs = TerrainCosts.from_preferences(graph.terrain_classes)
    free_graph, chair_graph = CostGraph.build(graph, costs), CostGraph.build(graph, costs, chair)
    rng = np.random.default_rng(seed)
    counts: dict[str, float] = {"pairs": pairs, "free_paths": 0, "wheelchair_paths": 0, "over_limit_on_true_ground": 0}
    counts |= {"over_limit_by_graph": 0, "legal_route_missed": 0, "no_path_and_free_path_illegal": 0}
    worst = 0.0
    start = time.perf_counter()
    for _ in range(pairs):
        a, b = (int(v) for v in rng.choice(len(graph.places), 2, replace=False))
        try:
            free = plan_on(graph, free_graph, a, b)
        except NoPathError:
            free = None
        try:
            plan = plan_on(graph, chair_graph, a, b)
        except NoPathError:
            plan = None
        counts["free_paths"] += free is not None
        if plan is not None:
            counts["wheelchair_paths"] += 1
            climb, descent = truth_slopes(world, plan.waypoints)
            worst = max(worst, climb, descent)
            counts["over_limit_on_true_ground"] += climb > chair.max_slope_up or descent > chair.max_slope_down
            g = plan.ground
            counts["over_limit_by_graph"] += g is not None and (
                g.max_step_m > chair.max_step or g.max_slope_deg > chair.max_slope_up
            )
        elif free is not None:
            climb, descent = truth_slopes(world, free.waypoints)
            legal = climb <= chair.max_slope_up and descent <= chair.max_slope_down
            counts["legal_route_missed" if legal else "no_path_and_free_path_illegal"] += 1
    counts["steepest_true_slope_on_wheelchair_paths_deg"] = round(worst, 2)
    counts["seconds"] = round(time.perf_counter() - start, 2)
    return counts


def wheelchair_on_map(bundle: Path, preset: str, seed: int, sim_config: Path | None, pairs: int) -> dict[str, Any]:
    """`wheelchair_pairs` on the graph built from the map in `bundle`, judged on the ground of the
    simulated world it was mapped from."""
    from terra.bundle import Bundle
    from terra.config import TerraConfig
    from terra.graph.pipeline import build_scene_graph
    from terra.mapping.storage import load_map
    from terra.sim import simulate

    graph = build_scene_graph(load_map(Bundle(bundle), max_ids=False)).graph
    config = TerraConfig.read(sim_config).sim if sim_config is not None else None
    world = simulate(preset, seed, config).world
    result = wheelchair_pairs(graph, world, pairs)
    steepest = np.degrees(np.arctan(np.linalg.norm(world.ground.gradient(graph.places.position), axis=1)))
    return {
        "preset": preset,
        "places": len(graph.places),
        "steepest_true_slope_at_a_place_deg": round(float(steepest.max()), 2),
    } | result


def _layers_on_grid_of(module: Any) -> Any:
    """The `layers_on_grid` of a ground module, or for an older one, its `beside_obstacles` (the
    grid's blocked cells as they are), or today's where it has neither."""
    if hasattr(module, "layers_on_grid"):
        return module.layers_on_grid
    if not hasattr(module, "beside_obstacles"):
        from terra.graph.ground import layers_on_grid

        return layers_on_grid
    return lambda layers, grid, points, **_: module.beside_obstacles(layers, grid.blocked)


def build_time(map_bundle: Path, repeat: int, before: Path | None = None) -> dict[str, Any]:
    """build_scene_graph seconds with the ground layers off, on, on without level routes, and on
    with the layers after the terrain grid instead of beside it on a second thread, the runs
    alternating (one of each per round, the order turning), best of `repeat` wall and CPU
    (process) seconds: on a loaded 2-core machine the wall time of one run moves by a third. `before`: a ground.py of
    another commit (`git show REV:terra/graph/ground.py > FILE`) whose segmentation and layers
    (points_ground, ground_layers, and layers_on_grid or, older, beside_obstacles where it has
    one) run one more configuration, "on_before", in the same process."""
    import importlib.util

    from terra.bundle import Bundle
    from terra.graph import ground, pipeline
    from terra.graph.config import BuildConfig
    from terra.mapping.storage import load_map

    msm = load_map(Bundle(map_bundle), max_ids=False)
    out: dict[str, Any] = {"points": len(msm)}
    runs: dict[str, tuple[Any, BuildConfig]] = {
        "off": (ground, BuildConfig.model_validate({"ground": {"layers": False}})),
        "on": (ground, BuildConfig()),
        # the layers without the level routes over them (terra.graph.level_routes)
        "on_without_routes": (ground, BuildConfig.model_validate({"linking": {"level_route_length": None}})),
        # the segmentation and the layers after the terrain grid, not beside it on a second thread
        "on_one_thread": (ground, BuildConfig.model_validate({"ground": {"beside_grid_points": 0}})),
    }
    if before is not None:
        spec = importlib.util.spec_from_file_location("ground_before", before)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules["ground_before"] = module  # dataclasses look their module up
        spec.loader.exec_module(module)
        runs["on_before"] = (module, BuildConfig())
    seconds: dict[str, list[tuple[float, float, float]]] = {name: [] for name in runs}
    names = list(runs)
    for round_ in range(repeat + 1):  # round 0 warms the caches and is not counted
        for name in names[round_ % len(names) :] + names[: round_ % len(names)]:
            module, config = runs[name]
            pipeline.points_ground, pipeline.ground_layers = module.points_ground, module.ground_layers
            pipeline.layers_on_grid = _layers_on_grid_of(module)
            wall, cpu = time.perf_counter(), time.process_time()
            build = pipeline.build_scene_graph(msm, config)
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            stages = sum(v for k, v in build.timer.seconds.items() if k in ("ground", "ground layers"))
            if round_ > 0:
                seconds[name].append((wall, cpu, stages))
            if name == "on":
                out["places"] = len(build.graph.places)
    pipeline.points_ground, pipeline.ground_layers = ground.points_ground, ground.ground_layers
    pipeline.layers_on_grid = ground.layers_on_grid
    for name, values in seconds.items():
        best = np.min(np.array(values), axis=0)
        out[name] = {"wall_s": round(float(best[0]), 3), "cpu_s": round(float(best[1]), 3)}
        out[name]["ground_stages_s"] = round(float(best[2]), 3)
        out[name]["cpu_median_s"] = round(float(np.median([v[1] for v in values])), 3)
    for name in names[1:]:
        out["overhead_" + name] = {
            key: round(out[name][key] / out["off"][key] - 1.0, 4) for key in ("wall_s", "cpu_s", "cpu_median_s")
        }
    return out


def command_time(map_bundle: Path, repeat: int) -> dict[str, Any]:
    """The whole `terra build --overwrite` command (a fresh process: imports, the map's loading,
    the build and the bundle's writing) with build.ground.layers false and true, each on its own
    copy of `map_bundle`, the runs alternating after one warm-up round each: wall and CPU
    (children's user + system) seconds, their medians and the medians of the paired ratios on/off."""
    runs: dict[str, list[tuple[float, float]]] = {"off": [], "on": []}
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(scratch)
        for name in runs:
            shutil.copytree(map_bundle, work / f"{name}.terra")
            (work / f"{name}.yaml").write_text(f"build:\n  ground:\n    layers: {str(name == 'on').lower()}\n")
        for round_ in range(repeat + 1):
            for name in runs:
                argv = ["build", str(work / f"{name}.terra"), "--overwrite", "-q", "-c", str(work / f"{name}.yaml")]
                before, wall = os.times(), time.perf_counter()
                subprocess.run([sys.executable, "-m", "terra", *argv], check=True, capture_output=True)
                wall, after = time.perf_counter() - wall, os.times()
                cpu = (after.children_user - before.children_user) + (after.children_system - before.children_system)
                if round_ > 0:
                    runs[name].append((wall, cpu))
    out: dict[str, Any] = {}
    for name, values in runs.items():
        array = np.array(values)
        out[name] = {"wall_median_s": round(float(np.median(array[:, 0])), 3)}
        out[name]["cpu_median_s"] = round(float(np.median(array[:, 1])), 3)
    ratio = np.array(runs["on"]) / np.array(runs["off"])
    out["overhead_on"] = {"wall": round(float(np.median(ratio[:, 0])) - 1.0, 4)}
    out["overhead_on"]["cpu"] = round(float(np.median(ratio[:, 1])) - 1.0, 4)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", default="tiny")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--kitti", type=Path, default=None)
    parser.add_argument("--labelled", type=Path, default=None)
    parser.add_argument("--campus-map", type=Path, default=None)
    parser.add_argument("--wheelchair-map", type=Path, default=None)
    parser.add_argument("--wheelchair-preset", default="small")
    parser.add_argument("--sim-config", type=Path, default=None)
    parser.add_argument("--pairs", type=int, default=200)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--ground-before", type=Path, default=None, help="a ground.py to time beside (build-time)")
    parser.add_argument("--out", type=Path, default=RESULTS, help="JSON written (default results/geometry.json)")
    args = parser.parse_args()
    result: dict[str, Any] = {
        "machine": f"{platform.node()} {platform.machine()} {platform.python_version()}",
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "argv": sys.argv[1:],
    }
    if args.frames > 0:
        result["segmentation_sim"] = segmentation_sim(args.preset, args.seed, args.frames)
    if args.kitti is not None:
        result["segmentation_kitti"] = segmentation_kitti(args.kitti)
        with tempfile.TemporaryDirectory() as work:
            result["lidar_only_kitti"] = lidar_only_build(args.kitti, Path(work))
    if args.labelled is not None:
        result["segmentation_labelled"] = segmentation_labelled(args.labelled)
        result["steps_on_labelled_road"] = steps_on_labelled_road(args.labelled)
    if args.campus_map is not None:
        result["build_time"] = build_time(args.campus_map, args.repeat, args.ground_before)
        result["build_command_time"] = command_time(args.campus_map, args.repeat)
    if args.wheelchair_map is not None:
        result["wheelchair"] = wheelchair_on_map(
            args.wheelchair_map, args.wheelchair_preset, args.seed, args.sim_config, args.pairs
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
