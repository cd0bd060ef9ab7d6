"""Wheelchair plans on a simulated world with curbs, curb cuts, stairs with ramps and a steep hill
(issue 27), judged on the simulator's true per-cell geometry.

Simulates `--preset` with `sim.geometry` on (and `--relief` for the smooth hills, `--frames`
frames), maps it (`terra map`, labels backend), builds it (`terra build`), draws `--pairs` random
start-goal place pairs and plans each with the wheelchair profile. Each path is judged on the true
ground raster (terra.datasets.ground_truth.neighbour_geometry: the step and slope of every move
between 4-neighbour cells; `neighbour_side_slope`: the ground's tilt across it): a path crosses a
true step above the profile's limit, a true slope above it, or a true side slope above its side
slope limit (`max_cross_slope`) (expected: 0 each). Independently, the true raster is searched for
legal routes: cells farther than the profile's half width from every object (the exact distance
from the cell's centre to the box), not water and not within the half width of a true step above
the limit (the wheels would meet it), joined where the move's true step, slope and side slope are
within the limits (scipy.sparse.csgraph connected components); a pair whose places lie in one
component has a legal route, and one that got no path is a legal route missed (expected: 0).
The same again over the ground the map's cameras labelled only (`with_labelled_ground`: a legal
route on labelled ground; missed; on a LiDAR-only map, its ground): a camera map's places stand on
labelled terrain (the paper's rule), so a route that needs ground only the LiDAR saw (beside and
behind a forward camera) is none its graph could give; the figure tells those misses from the graph's.
The all-pairs share once more over labelled ground that is level in every direction (`level`): a
stricter judge, no steeper than the slope limit along or across any axis move nor in between (a
move along x across a flank whose fall line runs 45 degrees off the axes climbs and tips by less
than the flank's own slope).
Pairs are drawn among the places inside the world's square: the sensor sees ground past its edge,
where the truth says nothing (counted: places beyond the world, paths that leave it).
Beyond the sampled pairs, every place edge the wheelchair may take is judged as a path of its own
(`legal_edges_judged`: over a step, a slope or a side slope; expected 0 each): a plan uses only
those edges. Paths and edges that pass a cell whose centre lies inside an object's box are counted
too (`through_an_object`; trees' crowns and street lights' arms left out). Also counted: paths
through a curb cut, paths over a stairs tread, paths on the ramp beside stairs, paths over the
steep hill, and the same pairs planned without a profile (over steps, over stairs).

Usage:
  python benchmarks/bench_curbs.py [--preset tiny] [--seed 0] [--frames 0] [--relief 0.3]
      [--pairs 200] [--work DIR] [--lidar-only]
Writes benchmarks/results/curbs-<preset>.json (curbs-<preset>-lidar.json with `--lidar-only`: the
world simulated without cameras and mapped without the simulator's point labels, so the map has no
terrain classes and its places stand on the ground segmented from its points; a `--seed` other
than 0 adds -seed<N>, so other worlds do not replace the default one's figures) and prints it.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, cast

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from terra.datasets.ground_truth import NEIGHBOURS, TerrainRaster, neighbour_side_slope, path_geometry
from terra.sim.world import World
from terra.tasks.robot import RobotProfile

RESULTS = Path(__file__).resolve().parent / "results"  # curbs-<preset>.json


@dataclass
class TrueGround:
    """The true per-cell geometry of a world: raster, step and slope (H, W, 4) of each move
    (NEIGHBOURS order), side (H, W, 4) degrees: the tilt across each move, legal (H, W, 4) moves
    for the robot, edge (H, W) cells whose centre lies within the robot's half width of a step
    above its limit (its wheels would meet the step),
    free (H, W) cells (clear of objects by the half width, not water, not edge), the component
    (H, W) int of each free cell (-1: not free), the masks of what the world has where, and
    labelled_component: the same components over the ground the cameras labelled (with_labelled_ground);
    level (H, W) cells whose ground is no steeper than the robot's slope limit in any direction
    (the per-move slopes and side slopes of `legal` let a path cross a slope steeper than the limit
    whose fall line runs between the axes, in moves that each climb and tilt less), and
    level_labelled_component: the components over
    labelled cells that are level."""

    raster: TerrainRaster
    step: np.ndarray
    slope: np.ndarray
    side: np.ndarray
    legal: np.ndarray
    edge: np.ndarray
    free: np.ndarray
    component: np.ndarray
    features: dict[str, np.ndarray]
    labelled_component: np.ndarray | None = None
    level: np.ndarray | None = None
    # (H, W) metres from each cell centre to the nearest object standing on its whole box, not
    # OVERHANGING: the boxes a path must not enter (0 inside one)
    standing_clearance: np.ndarray | None = None
    level_labelled_component: np.ndarray | None = None


GROUND_RETURN = 0.3  # metres: a map point this close to the true ground is a return from it


def true_ground(world: World, robot: RobotProfile) -> TrueGround:
    """Legal moves and their connected components on the world's ground truth (module docstring)."""
    from terra.sim.classes import class_id

    raster = world.ground_truth().terrain
    assert raster is not None and world.ground.steps is not None
    step, slope = raster.neighbour_geometry()
    side = neighbour_side_slope(slope)
    xs = raster.origin[0] + (np.arange(raster.classes.shape[1]) + 0.5) * raster.resolution
    ys = raster.origin[1] + (np.arange(raster.classes.shape[0]) + 0.5) * raster.resolution
    gx, gy = np.meshgrid(xs, ys)
    clearance = object_distance(world, xs, ys, reach=robot.min_width)
    standing = object_distance(world, xs, ys, reach=raster.resolution, skip=GROUND_PAINT + OVERHANGING)
    edge = _near_steps(step, robot.max_step, robot.min_width / 2, raster.resolution)
    free = (clearance > robot.min_width / 2) & (raster.classes != class_id("water")) & ~edge
    limit = min(robot.max_slope_up, robot.max_slope_down)
    legal = (np.nan_to_num(step, nan=np.inf) <= robot.max_step) & (np.nan_to_num(slope, nan=np.inf) <= limit)
    legal &= np.nan_to_num(side, nan=np.inf) <= robot.cross_limit
    component = _components(free, legal)
    dz_dy, dz_dx = np.gradient(raster.ground_height, raster.resolution)
    level = np.degrees(np.arctan(np.nan_to_num(np.hypot(dz_dx, dz_dy)))) <= limit
    stairs = np.isfinite(world.stairs_tops(gx, gy))
    st = world.ground.steps
    features = {"curb_cut": st.curb_cut, "stairs": stairs, "ramp": st.ramp, "hill": st.hill}
    return TrueGround(
        raster, step, slope, side, legal, edge, free, component, features, level=level, standing_clearance=standing
    )


GROUND_PAINT = ("crosswalk", "stairs")  # boxes that are ground: judged by their steps
OVERHANGING = ("tree", "street light")  # boxes of a crown or an arm, high above a pole or a trunk


def object_distance(
    world: World, xs: np.ndarray, ys: np.ndarray, reach: float, skip: tuple[str, ...] = GROUND_PAINT
) -> np.ndarray:
    """(H, W) metres from each cell centre (xs (W,), ys (H,), map frame) to the nearest object's
    footprint (its box seen from above; the classes `skip` left out: crosswalk paint and stairs
    treads are ground, judged by their steps), exact: a distance transform of the cells whose
    centre lies in a box would read a cell beside a car's side as a whole cell clear of it. Beyond
    `reach` metres of every box: inf."""
    distance = np.full((len(ys), len(xs)), np.inf)
    res = xs[1] - xs[0] if len(xs) > 1 else 1.0
    for box in world.objects:
        if box.class_name in skip:
            continue
        half = np.hypot(box.size[0], box.size[1]) / 2 + reach
        cols = slice(*np.searchsorted(xs, [box.center[0] - half - res, box.center[0] + half + res]))
        rows = slice(*np.searchsorted(ys, [box.center[1] - half - res, box.center[1] + half + res]))
        rx, ry = np.meshgrid(xs[cols] - box.center[0], ys[rows] - box.center[1])
        c, s = np.cos(box.yaw), np.sin(box.yaw)
        u = np.maximum(np.abs(c * rx + s * ry) - box.size[0] / 2, 0.0)
        v = np.maximum(np.abs(-s * rx + c * ry) - box.size[1] / 2, 0.0)
        np.minimum(distance[rows, cols], np.hypot(u, v), out=distance[rows, cols])
    return distance


def with_labelled_ground(truth: TrueGround, points: np.ndarray, fill: float = 1.0) -> TrueGround:
    """`truth` with `labelled_component`: the legal components again, over the free cells holding a
    labelled map point (points (N, 3) metres, map frame: those with a terrain vote; on a LiDAR-only
    map, every point) within GROUND_RETURN of the cell's true ground height, the cells so found
    closed by a disk of radius `fill` metres (the gaps between a LiDAR's rings)."""
    rows, cols, inside = truth.raster.cell_of(points)
    near = np.abs(points[:, 2] - truth.raster.ground_height[rows, cols]) <= GROUND_RETURN
    labelled = np.zeros(truth.free.shape, dtype=bool)
    labelled[rows[inside & near], cols[inside & near]] = True
    r = int(np.ceil(fill / truth.raster.resolution))
    disk = np.hypot(*np.mgrid[-r : r + 1, -r : r + 1]) <= r
    labelled = ndimage.binary_closing(np.pad(labelled, r), structure=disk)[r:-r, r:-r]
    assert truth.level is not None
    return replace(
        truth,
        labelled_component=_components(truth.free & labelled, truth.legal),
        level_labelled_component=_components(truth.free & labelled & truth.level, truth.legal),
    )


def _near_steps(step: np.ndarray, limit: float, reach: float, resolution: float) -> np.ndarray:
    """(H, W) bool: cells whose centre lies within `reach` metres of a cell edge with a step above
    `limit` metres (the edge lies half a cell beyond the centres of the two cells beside it)."""
    beside = (np.nan_to_num(step) > limit).any(axis=-1)
    cells = cast(np.ndarray, ndimage.distance_transform_edt(~beside))
    return cells * resolution + resolution / 2 <= reach


def _components(free: np.ndarray, legal: np.ndarray) -> np.ndarray:
    """(H, W) int: the connected component of each free cell over legal moves between free cells, -1 elsewhere."""
    h, w = free.shape
    index = np.arange(h * w).reshape(h, w)
    src, dst = [], []
    for k, (dr, dc) in enumerate(NEIGHBOURS[:2]):  # +x and +y: each move once (they are symmetric)
        a = index[: h - dr, : w - dc]
        b = index[dr:, dc:]
        ok = legal[: h - dr, : w - dc, k] & free[: h - dr, : w - dc] & free[dr:, dc:]
        src.append(a[ok])
        dst.append(b[ok])
    s, d = np.concatenate(src), np.concatenate(dst)
    graph = coo_matrix((np.ones(len(s)), (s, d)), shape=(h * w, h * w))
    _, labels = connected_components(graph, directed=False)
    return np.where(free, labels.reshape(h, w), -1)


def judge_path(truth: TrueGround, waypoints: np.ndarray) -> dict[str, Any]:
    """The largest true step (m), slope and side slope (degrees) of the cell moves a path makes
    (terra.datasets.ground_truth.path_geometry), whether it passes within the robot's half width of
    a step above its limit (truth.edge), whether it passes a cell whose centre lies inside the box
    of an object standing on all of it (truth.standing_clearance 0: not a tree's crown nor a street
    light's arm, which a robot passes under), and which features (truth.features) it passes over."""
    found = path_geometry(truth.raster, truth.step, truth.slope, waypoints, truth.side)
    over = {name: int(mask[found.rows, found.cols].any()) for name, mask in truth.features.items()}
    beside = bool(truth.edge[found.rows, found.cols].any())
    standing = truth.standing_clearance
    inside = bool(standing is not None and (standing[found.rows, found.cols] == 0).any())
    judged = {"step": found.step, "slope": found.slope, "side": found.side_slope, "beside_step": beside}
    return judged | {"through_an_object": inside} | over


def simulate_map_build(
    preset: str, seed: int, frames: int, relief: float, work: Path, lidar_only: bool = False
) -> tuple[Path, Path]:
    """`terra sim` (geometry on), `terra map` and `terra build` into `work`; (config, bundle).
    `lidar_only`: no camera, and the simulator's per-point labels moved out of the dataset before
    mapping (to `work/lidar_labels.withheld`), as a LiDAR-only log has none: the map has no
    terrain classes and its places stand on the ground segmented from its points."""
    config = work / "curbs.yaml"
    route = f"  route: {{max_frames: {frames}}}\n" if frames > 0 else ""
    cameras = "  cameras: []\n" if lidar_only else ""
    config.write_text(f"sim:\n  ground_relief_m: {relief}\n  geometry: {{}}\n{route}{cameras}")
    dataset, bundle = work / "dataset", work / "map.terra"
    for argv in (
        ["sim", "--preset", preset, "--seed", str(seed), "-c", str(config), "--out", str(dataset), "--overwrite"],
        ["map", str(dataset), "-o", str(bundle), "--overwrite"],
        ["build", str(bundle), "--overwrite"],
    ):
        if argv[0] == "build" or not (bundle if argv[0] == "map" else dataset).exists():
            subprocess.run([sys.executable, "-m", "terra", *argv], check=True, capture_output=True)
        if argv[0] == "sim" and lidar_only and (dataset / "lidar_labels").exists():
            (dataset / "lidar_labels").rename(work / "lidar_labels.withheld")
    return config, bundle


def wheelchair_pairs(graph, truth: TrueGround, pairs: int, seed: int = 0) -> dict[str, Any]:
    """Plans between random place pairs with the wheelchair, judged on the true geometry."""
    from terra.errors import NoPathError
    from terra.tasks.planning import CostGraph, TerrainCosts, plan_on
    from terra.tasks.robot import ROBOTS

    chair = ROBOTS["wheelchair"]
    costs = TerrainCosts.from_preferences(graph.terrain_classes)
    cost_graph, free_graph = CostGraph.build(graph, costs, chair), CostGraph.build(graph, costs)
    # Places beyond the world's square (ground the sensor saw past its edge) have no truth: a clipped
    # look-up would give them the border cell's component. Pairs are drawn among the others.
    rows, cols, inside = truth.raster.cell_of(graph.places.position)
    place_component = np.where(inside, truth.component[rows, cols], -1)
    labelled = truth.labelled_component if truth.labelled_component is not None else truth.component
    place_labelled = np.where(inside, labelled[rows, cols], -1)
    in_world = np.flatnonzero(inside)
    rng = np.random.default_rng(seed)
    counts: dict[str, Any] = {"pairs": pairs, "wheelchair_paths": 0, "over_step_limit": 0, "over_slope_limit": 0}
    counts |= {"over_side_slope_limit": 0, "within_half_width_of_a_step_over_the_limit": 0, "through_an_object": 0}
    counts |= {"legal_route_on_truth": 0, "legal_route_missed": 0, "place_off_the_legal_truth_grid": 0}
    counts |= {"legal_route_on_labelled_ground": 0, "labelled_legal_route_missed": 0}
    counts |= {f"paths_over_{name}": 0 for name in truth.features}
    worst = {"step": 0.0, "slope": 0.0, "side": 0.0}
    counts |= {"free_paths": 0, "free_paths_over_step_limit": 0, "free_paths_over_stairs": 0}
    counts |= {"places_beyond_the_world": int((~inside).sum()), "paths_leaving_the_world": 0}
    for _ in range(pairs):
        a, b = (int(v) for v in rng.choice(in_world, 2, replace=False))
        _count_free(graph, free_graph, truth, a, b, chair.max_step, counts)
        legal = bool(place_component[a] >= 0 and place_component[a] == place_component[b])
        counts["legal_route_on_truth"] += legal
        counts["place_off_the_legal_truth_grid"] += bool(place_component[a] < 0 or place_component[b] < 0)
        labelled_legal = bool(place_labelled[a] >= 0 and place_labelled[a] == place_labelled[b])
        counts["legal_route_on_labelled_ground"] += labelled_legal
        try:
            plan = plan_on(graph, cost_graph, a, b)
        except NoPathError:
            counts["legal_route_missed"] += legal
            counts["labelled_legal_route_missed"] += labelled_legal
            continue
        counts["wheelchair_paths"] += 1
        # a path whose waypoints lie in the square stays in it (straight segments)
        counts["paths_leaving_the_world"] += bool(not truth.raster.cell_of(plan.waypoints)[2].all())
        judged = judge_path(truth, plan.waypoints)
        over = over_limits(judged, chair)
        counts["over_step_limit"] += over["step"]
        counts["over_slope_limit"] += over["slope"]
        counts["over_side_slope_limit"] += over["side"]
        counts["within_half_width_of_a_step_over_the_limit"] += judged["beside_step"]
        counts["through_an_object"] += over["through_an_object"]
        worst = {k: max(v, judged[k]) for k, v in worst.items()}
        for name in truth.features:
            counts[f"paths_over_{name}"] += judged[name]
    counts |= all_pairs_missed(cost_graph, place_component)
    counts |= {f"{k}_on_labelled_ground": v for k, v in all_pairs_missed(cost_graph, place_labelled).items()}
    if truth.level_labelled_component is not None:
        level = truth.level_labelled_component[rows, cols]
        level = np.where(inside, level, -1)
        counts |= {f"{k}_on_labelled_level_ground": v for k, v in all_pairs_missed(cost_graph, level).items()}
    counts |= legal_edges_judged(graph, cost_graph, truth, chair)
    counts["largest_true_step_on_a_path_m"] = round(worst["step"], 4)
    counts["steepest_true_slope_on_a_path_deg"] = round(worst["slope"], 2)
    counts["steepest_true_side_slope_on_a_path_deg"] = round(worst["side"], 2)
    return counts


def over_limits(judged: dict[str, Any], robot: RobotProfile) -> dict[str, bool]:
    """What a path judged by `judge_path` breaks of `robot`'s limits: a step above its step limit,
    a slope above the steeper of its climb and descent limits (the true slope is unsigned), a side
    slope above its side slope limit, and an object entered."""
    return {
        "step": bool(judged["step"] > robot.max_step + 1e-9),
        "slope": bool(judged["slope"] > max(robot.max_slope_up, robot.max_slope_down) + 1e-9),
        "side": bool(judged["side"] > robot.cross_limit + 1e-9),
        "through_an_object": bool(judged["through_an_object"]),
    }


def legal_edges_judged(graph, cost_graph, truth: TrueGround, robot: RobotProfile) -> dict[str, Any]:
    """Every place edge the robot may take (either way: in its cost graph) whose two places lie in
    the world, judged as a path of its own on the true ground (`judge_path`): how many cross a true
    step, slope or side slope above the robot's limits (expected: 0; a path uses only these
    edges, so this bounds every plan, not only the sampled pairs) and the worst few by step."""
    src = np.repeat(np.arange(len(cost_graph.indptr) - 1), np.diff(cost_graph.indptr))
    pairs = np.unique(np.sort(np.column_stack([src, cost_graph.indices]), axis=1), axis=0)
    position = np.asarray(graph.places.position, dtype=np.float64)
    inside = truth.raster.cell_of(position)[2]
    pairs = pairs[inside[pairs[:, 0]] & inside[pairs[:, 1]]]
    over = {"step": 0, "slope": 0, "side": 0, "through_an_object": 0}
    worst: list[tuple[float, int, int]] = []
    for a, b in pairs:
        judged = judge_path(truth, position[[a, b]])
        this = over_limits(judged, robot)
        over = {k: v + this[k] for k, v in over.items()}
        if this["step"]:
            worst.append((round(judged["step"], 3), int(a), int(b)))
    return {
        "legal_edges": len(pairs),
        "legal_edges_over_step_limit": over["step"],
        "legal_edges_over_slope_limit": over["slope"],
        "legal_edges_over_side_slope_limit": over["side"],
        "legal_edges_through_an_object": over["through_an_object"],
        "legal_edges_over_step_limit_worst": [list(w) for w in sorted(worst, reverse=True)[:5]],
    }


def all_pairs_missed(cost_graph, place_component: np.ndarray) -> dict[str, Any]:
    """Over every ordered pair of places in one legal component of the truth (the steadier
    figure: random pairs follow the places drawn), the share the wheelchair cannot reach from the
    first (directed reachability on its cost graph, scipy.sparse.csgraph)."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import shortest_path

    n = len(place_component)
    adjacency = csr_matrix((np.ones(len(cost_graph.indices)), cost_graph.indices, cost_graph.indptr), shape=(n, n))
    reach = np.isfinite(shortest_path(adjacency, method="D", unweighted=True))
    same = (place_component[:, None] == place_component[None, :]) & (place_component[:, None] >= 0)
    np.fill_diagonal(same, False)
    return {
        "all_pairs_with_legal_route": int(same.sum()),
        "all_pairs_legal_route_missed_share": round(float((same & ~reach).sum() / max(int(same.sum()), 1)), 4),
    }


def _count_free(graph, free_graph, truth: TrueGround, a: int, b: int, max_step: float, counts: dict) -> None:
    """Count the plan without a robot profile between places a and b: found, over the step limit on
    the true ground, over stairs (what the profile avoids)."""
    from terra.errors import NoPathError
    from terra.tasks.planning import plan_on

    try:
        plan = plan_on(graph, free_graph, a, b)
    except NoPathError:
        return
    judged = judge_path(truth, plan.waypoints)
    counts["free_paths"] += 1
    counts["free_paths_over_step_limit"] += bool(judged["step"] > max_step + 1e-9)
    counts["free_paths_over_stairs"] += judged["stairs"]


def world_figures(truth: TrueGround, world: World) -> dict[str, Any]:
    """What the world holds: cells of each feature, curb cut and hill slopes, steps > 5 cm."""
    st = world.ground.steps
    assert st is not None
    return {
        "cells": int(truth.free.size),
        "free_cells": int(truth.free.sum()),
        "legal_components_over_100_cells": int((np.bincount(truth.component[truth.free]) >= 100).sum()),
        "cell_moves_with_step_over_5cm": int((np.nan_to_num(truth.step[..., :2]) > 0.05).sum()),
        "steepest_slope_in_curb_cuts_deg": round(float(np.nanmax(truth.slope[st.curb_cut])), 2),
        "steepest_slope_on_hill_deg": round(float(np.nanmax(truth.slope[st.hill])), 2) if st.hill.any() else None,
    } | {f"{name}_cells": int(mask.sum()) for name, mask in truth.features.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", default="tiny")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--frames", type=int, default=0, help="frames to simulate (0: the preset's)")
    parser.add_argument("--relief", type=float, default=0.3, help="sim.ground_relief_m")
    parser.add_argument("--pairs", type=int, default=200)
    parser.add_argument("--work", type=Path, default=None, help="keep (and reuse) the dataset and map here")
    parser.add_argument("--lidar-only", action="store_true", help="simulate no camera: places on the LiDAR ground")
    args = parser.parse_args()
    from terra.bundle import Bundle
    from terra.config import TerraConfig
    from terra.graph.ground import has_terrain_votes
    from terra.graph.storage import load_scene_graph
    from terra.mapping.storage import load_map
    from terra.sim.presets import generate_world
    from terra.tasks.robot import ROBOTS

    result: dict[str, Any] = {
        "machine": f"{platform.node()} {platform.machine()} {platform.python_version()}",
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "argv": sys.argv[1:],
    }
    with tempfile.TemporaryDirectory() as scratch:
        work = args.work or Path(scratch)
        work.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        config, bundle = simulate_map_build(args.preset, args.seed, args.frames, args.relief, work, args.lidar_only)
        result["sim_map_build_s"] = round(time.perf_counter() - start, 1)
        world = generate_world(args.preset, args.seed, TerraConfig.read(config).sim)
        truth = true_ground(world, ROBOTS["wheelchair"])
        msm = load_map(Bundle(bundle))
        labelled = msm.points[msm.terrain_votes.any(axis=1)] if has_terrain_votes(msm) else msm.points
        truth = with_labelled_ground(truth, labelled)
        del msm, labelled
        graph = load_scene_graph(Bundle(bundle))
        result["world"] = world_figures(truth, world) | {"places": len(graph.places)}
        start = time.perf_counter()
        result["wheelchair"] = wheelchair_pairs(graph, truth, args.pairs, args.seed)
        result["wheelchair"]["seconds"] = round(time.perf_counter() - start, 2)
    RESULTS.mkdir(parents=True, exist_ok=True)
    name = f"curbs-{args.preset}{'-lidar' if args.lidar_only else ''}{f'-seed{args.seed}' if args.seed else ''}.json"
    (RESULTS / name).write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
