"""Phase 3 speed: cold query commands, warm object/monitor/plan queries, bundle loading.

Targets (issue 15): `terra find/monitor/plan` on a campus bundle <= 1.5 s wall from a fresh
process, `terra --help` <= 0.5 s; warm: one object query over a 2M-point map <= 50 ms, one monitor
query <= 10 ms, one plan over 20,000 places <= 20 ms (the cost graph of a set of preferences is
built once per process, as LoadedBundle keeps it). Loading a campus bundle <= 2 s.

Usage: python benchmarks/bench_tasks.py [--bundle PATH ...] [--cold BUNDLE] [--points 2000000] [--places 20000]
Writes benchmarks/results/tasks.json and prints a table. Run from the repository root.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np
import scipy.sparse as sp
from benchtable import report

OBJECT_NAMES = ["dumpster", "car", "bicycle rack", "bench", "trash can", "street lamp", "fire hydrant", "picnic table"]
TERRAINS = ["sidewalk", "grass", "asphalt", "dirt", "water"]
T = TypeVar("T")


def timed(fn: Callable[[], T], repeat: int, cpu: list[float] | None = None) -> tuple[list[float], T]:
    """Wall-clock seconds of `repeat` (at least one) calls, their CPU seconds appended to `cpu`, and the last result."""
    times: list[float] = []
    out = _timed_call(fn, times, cpu)
    for _ in range(repeat - 1):
        out = _timed_call(fn, times, cpu)
    return times, out


def _timed_call(fn: Callable[[], T], times: list[float], cpu: list[float] | None) -> T:
    c0, t0 = time.process_time(), time.perf_counter()
    out = fn()
    times.append(time.perf_counter() - t0)
    if cpu is not None:
        cpu.append(time.process_time() - c0)
    return out


def synthetic_map(n_points: int, n_bank: int, embedder, seed: int = 0):
    """A 2 km x 1 km map: ground points observed with random bank entries (far from any query),
    plus planted objects (100 points in 2 x 2 x 1.6 m, about the density of a 0.4 m voxel map)
    observed with object-name embeddings."""
    from terra.mapping.semantic_map import ImageTable, MetricSemanticMap
    from terra.perception.text import normalize_rows

    rng = np.random.default_rng(seed)
    d = embedder.dim
    bank = np.empty((n_bank, d), dtype=np.float32)
    bank[: len(OBJECT_NAMES)] = embedder.embed_text(OBJECT_NAMES)
    bank[len(OBJECT_NAMES) :] = normalize_rows(rng.standard_normal((n_bank - len(OBJECT_NAMES), d)).astype(np.float32))
    n_objects, per_object = 1000, 100
    n_ground = n_points - n_objects * per_object
    ground = np.column_stack(
        [rng.uniform(0, 2000, n_ground), rng.uniform(0, 1000, n_ground), rng.normal(0, 0.05, n_ground)]
    )
    centres = np.column_stack(
        [rng.uniform(0, 2000, n_objects), rng.uniform(0, 1000, n_objects), np.full(n_objects, 0.8)]
    )
    objects = (centres[:, None, :] + rng.uniform(-1.0, 1.0, (n_objects, per_object, 3)) * [1.0, 1.0, 0.8]).reshape(
        -1, 3
    )
    points = np.vstack([ground, objects]).astype(np.float32)
    # Observations: 60 % of ground points see 1-4 random bank entries; object points 1-3 hits
    # of their class entry plus one random entry.
    observed = np.flatnonzero(rng.random(n_ground) < 0.6)
    per_row = rng.integers(1, 5, observed.size)
    rows = [np.repeat(observed, per_row)]
    cols = [rng.integers(len(OBJECT_NAMES), n_bank, int(per_row.sum()))]
    vals = [rng.integers(1, 4, int(per_row.sum()))]
    obj_rows = np.arange(n_ground, n_points)
    obj_class = np.repeat(np.arange(n_objects) % len(OBJECT_NAMES), per_object)
    rows += [obj_rows, obj_rows]
    cols += [obj_class, rng.integers(len(OBJECT_NAMES), n_bank, obj_rows.size)]
    vals += [rng.integers(2, 5, obj_rows.size), np.ones(obj_rows.size, dtype=np.int64)]
    counts = sp.csr_matrix(
        (np.concatenate(vals).astype(np.int32), (np.concatenate(rows), np.concatenate(cols))), shape=(n_points, n_bank)
    )
    counts.sum_duplicates()
    images = ImageTable(
        stamp=np.zeros(0),
        camera=np.zeros(0, dtype=np.int16),
        T_map_cam=np.zeros((0, 4, 4)),
        embedding=np.zeros((0, d), dtype=np.float32),
    )
    return MetricSemanticMap(
        points=points,
        terrain_classes=TERRAINS,
        terrain_votes=np.zeros((n_points, len(TERRAINS)), dtype=np.uint16),
        terrain_embeddings=embedder.embed_text(TERRAINS),
        counts=counts,
        bank=bank,
        images=images,
        embedder=embedder.name,
    )


def bench_query(n_points: int, embedder) -> dict:
    from terra.tasks.retrieval import find_objects
    from terra.tasks.scoring import PointScorer

    t0 = time.perf_counter()
    msm = synthetic_map(n_points, 20000, embedder)
    build_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    scorer = PointScorer(msm)  # row norms of counts @ bank, float32 counts
    _ = scorer.max_ids  # most observed bank id per point (computed on first access)
    warm_s = time.perf_counter() - t0
    embedder.embed_text(["find the dumpster"])  # the query text itself is cached after the first call
    out = {
        "points": n_points,
        "bank": int(msm.bank.shape[0]),
        "nnz": int(msm.counts.nnz),
        "build_s": build_s,
        "feature_cache_s": warm_s,
    }
    for method in ("ms-avg", "ms-max"):
        cpu: list[float] = []
        times, found = timed(
            lambda method=method: find_objects(
                msm, None, ["find the dumpster"], method=method, alpha=0.5, embedder=embedder, scorer=scorer
            ),
            9,
            cpu,
        )
        out[method] = {
            "median_ms": 1e3 * statistics.median(times),
            "max_ms": 1e3 * max(times),
            "cpu_median_ms": 1e3 * statistics.median(cpu),
            "objects": len(found),
            "matched_points": int(sum(o.point_count for o in found)),
        }
    fresh = ["a green dumpster behind the building"]
    times, _ = timed(
        lambda: find_objects(msm, None, fresh, method="ms-avg", alpha=0.5, embedder=embedder, scorer=scorer), 1
    )
    out["ms-avg_new_text_ms"] = 1e3 * times[0]
    return out


def bench_monitor(graph, embedder) -> dict:
    """Warm monitor queries (mix, k 1) on `graph`, query text already embedded."""
    from terra.tasks.monitoring import monitor_region

    embedder.embed_text(["large parking lot surrounded by buildings"])
    cpu: list[float] = []
    times, result = timed(
        lambda: monitor_region(
            graph, "large parking lot surrounded by buildings", method="mix", k=1, alpha=0.3, embedder=embedder
        ),
        21,
        cpu,
    )
    return {
        "places": len(graph.places),
        "regions": [len(r) for r in graph.regions],
        "median_ms": 1e3 * statistics.median(times),
        "max_ms": 1e3 * max(times),
        "cpu_median_ms": 1e3 * statistics.median(cpu),
        "chosen_places": int(len(result.places)),
    }


def with_regions(graph, embedder, seed: int = 0):
    """`graph` with two region levels over its places (blocks of ~100 and ~1000 places, random
    unit embeddings), so monitoring has a hierarchy to rank."""
    from dataclasses import replace

    from terra.graph.scene_graph import RegionLevel
    from terra.perception.text import normalize_rows

    rng = np.random.default_rng(seed)
    n, d = len(graph.places), embedder.dim
    places = replace(graph.places, embedding=normalize_rows(rng.standard_normal((n, d)).astype(np.float32)))
    xy = places.position[:, :2]
    block1 = (np.floor(xy[:, 0] / 50) * 1000 + np.floor(xy[:, 1] / 50)).astype(np.int64)
    _, parent1 = np.unique(block1, return_inverse=True)
    r1 = parent1.max() + 1
    pos1 = (
        np.stack([np.bincount(parent1, weights=places.position[:, a]) for a in range(3)], 1)
        / np.bincount(parent1)[:, None]
    )
    parent2 = np.unique(
        (np.floor(pos1[:, 0] / 160) * 1000 + np.floor(pos1[:, 1] / 160)).astype(np.int64), return_inverse=True
    )[1]
    pos2 = np.stack([np.bincount(parent2, weights=pos1[:, a]) for a in range(3)], 1) / np.bincount(parent2)[:, None]
    levels = [
        RegionLevel(1, pos1, normalize_rows(rng.standard_normal((r1, d)).astype(np.float32)), parent1),
        RegionLevel(2, pos2, normalize_rows(rng.standard_normal((parent2.max() + 1, d)).astype(np.float32)), parent2),
    ]
    return replace(
        graph,
        places=places,
        regions=levels,
        embedder=embedder.name,
        terrain_embeddings=normalize_rows(rng.standard_normal((len(graph.terrain_classes), d)).astype(np.float32)),
    )


def bench_cold(bundle: Path, repeat: int) -> dict:
    """Wall seconds of query commands in fresh processes (`python -m terra ...`, this checkout).
    The query texts were embedded before (their vectors are stored), except "new text"'s."""
    commands = {
        "terra --help": ["--help"],
        "terra find": ["find", str(bundle), "find the dumpster"],
        # A text never embedded before (its vector is not stored yet): onnxruntime starts.
        "terra find, new text": ["find", str(bundle), "find the dumpster {unique}"],
        "terra monitor": ["monitor", str(bundle), "large parking lot surrounded by buildings"],
        "terra plan": ["plan", str(bundle), "--to", "find the dumpster", "--prefer", "sidewalk"],
        "terra node": ["node", str(bundle), "p12"],
    }
    root = Path(__file__).resolve().parents[1]
    out = {}
    for label, args in commands.items():
        walls, cpus = [], []
        for _ in range(repeat):
            t0 = time.perf_counter()
            before = os.times()
            argv = [a.replace("{unique}", f"#{time.time_ns()}") for a in args]
            proc = subprocess.run([sys.executable, "-m", "terra", *argv], cwd=root, capture_output=True, text=True)
            after = os.times()
            walls.append(time.perf_counter() - t0)
            cpus.append((after.children_user - before.children_user) + (after.children_system - before.children_system))
            if proc.returncode != 0:
                raise SystemExit(f"{label} failed: {proc.stderr.strip()}")
        out[label] = {
            "median_s": statistics.median(walls),
            "min_s": min(walls),
            "max_s": max(walls),
            "cpu_median_s": statistics.median(cpus),
        }
    return out


def grid_graph(n_places: int, seed: int = 0):
    """A jittered grid of places 5 m apart (~n_places), 4-connected minus 15 % of the edges, with
    random terrain patches."""
    from terra.graph.scene_graph import EDGE_GVD, Places, SceneGraph

    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(n_places)))
    ii, jj = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    pos = np.column_stack([ii.ravel() * 5.0, jj.ravel() * 5.0, np.zeros(side * side)])[:n_places]
    pos[:, :2] += rng.uniform(-1, 1, (len(pos), 2))
    idx = np.arange(side * side).reshape(side, side)
    edges = np.vstack(
        [
            np.column_stack([idx[:-1].ravel(), idx[1:].ravel()]),
            np.column_stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()]),
        ]
    )
    edges = edges[(edges < n_places).all(axis=1)]
    edges = edges[rng.random(len(edges)) > 0.15]
    # Terrain by coarse noise: patches of ~10 x 10 places.
    coarse = rng.integers(0, 4, (side // 10 + 1, side // 10 + 1))
    terrain = coarse[ii.ravel() // 10, jj.ravel() // 10][:n_places]
    weight = np.linalg.norm(pos[edges[:, 0]] - pos[edges[:, 1]], axis=1)
    return SceneGraph(
        terrain_classes=TERRAINS,
        terrain_embeddings=np.zeros((5, 4), dtype=np.float32),
        places=Places(pos, terrain, np.ones(n_places), np.zeros((n_places, 4), dtype=np.float32)),
        place_edges=edges,
        place_edge_weight=weight,
        place_edge_kind=np.full(len(edges), EDGE_GVD),
    )


def bench_plan(n_places: int) -> dict:
    from terra.errors import NoPathError
    from terra.tasks.astar import prepare_adjacency
    from terra.tasks.planning import CostGraph, TerrainCosts, plan_on, plan_path

    graph = grid_graph(n_places)
    rng = np.random.default_rng(1)
    side = int(np.ceil(np.sqrt(n_places)))
    pairs = [(0, n_places - 1), (side - 1, n_places - side)] + [tuple(rng.integers(0, n_places, 2)) for _ in range(8)]
    out: dict = {"places": n_places, "edges": int(len(graph.place_edges))}
    cases: list[tuple[str, list[str], list[str]]] = [
        ("plain", [], []),
        ("prefer_sidewalk_forbid_water", ["sidewalk"], ["water"]),
    ]
    for label, prefer, forbid in cases:
        full, astar_only, lengths, cpu = [], [], [], []
        costs = TerrainCosts.from_preferences(graph.terrain_classes, prefer, None, forbid)
        cg = CostGraph.build(graph, costs)
        prepare_adjacency(cg.indptr, cg.indices, cg.cost)  # as LoadedBundle does for a reused cost graph
        for s, g in pairs:
            try:
                c0, t0 = time.process_time(), time.perf_counter()
                plan = plan_path(graph, int(s), int(g), prefer=prefer, forbid=forbid)
                full.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
                t0 = time.perf_counter()
                plan_on(graph, cg, int(s), int(g))
                astar_only.append(time.perf_counter() - t0)
                lengths.append(plan.length_m)
            except NoPathError:
                continue
        out[label] = {
            "plans": len(full),
            "median_ms": 1e3 * statistics.median(full),
            "max_ms": 1e3 * max(full),
            "cpu_median_ms": 1e3 * statistics.median(cpu),
            "cpu_max_ms": 1e3 * max(cpu),
            "warm_median_ms": 1e3 * statistics.median(astar_only),
            "warm_max_ms": 1e3 * max(astar_only),
            "astar_only_max_ms": 1e3 * max(astar_only),
            "longest_path_m": max(lengths),
        }
    return out


def bench_load(bundle: Path) -> dict:
    from terra.bundle import Bundle
    from terra.graph.storage import load_scene_graph
    from terra.mapping.storage import load_map

    def load():
        b = Bundle(bundle)
        msm = load_map(b)
        graph = load_scene_graph(b) if any(f.startswith("graph/") for f in b.files) else None
        return msm, graph

    times, (msm, graph) = timed(load, 3)
    t0 = time.perf_counter()
    msm.ms_avg_norms()
    cache_s = time.perf_counter() - t0
    from terra.loaded import LoadedBundle
    from terra.tasks.commands import find
    from terra.tasks.requests import FindRequest

    loaded = LoadedBundle(bundle)
    request = FindRequest(queries=["find the dumpster"])
    find(loaded, request)  # warm: map, graph, text model, scorer
    cpu: list[float] = []
    warm, _ = timed(lambda: find(loaded, request), 9, cpu)
    return {
        "bundle": str(bundle),
        "points": len(msm),
        "places": len(graph.places) if graph else 0,
        "load_median_s": statistics.median(times),
        "load_max_s": max(times),
        "feature_cache_s": cache_s,
        "warm_find_median_ms": 1e3 * statistics.median(warm),
        "warm_find_cpu_median_ms": 1e3 * statistics.median(cpu),
        "bytes": sum(Bundle(bundle).component_bytes().values()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bundle", type=Path, action="append", default=[], help="bundle(s) to time loading on")
    parser.add_argument("--cold", type=Path, help="bundle to time the query commands on from fresh processes")
    parser.add_argument("--repeat", type=int, default=5, help="fresh processes per cold command")
    parser.add_argument("--points", type=int, default=2_000_000)
    parser.add_argument("--places", type=int, default=20_000)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "tasks.json")
    args = parser.parse_args()

    from terra.perception.text import get_text_embedder

    t0 = time.perf_counter()
    embedder = get_text_embedder()
    getattr(embedder, "load", lambda: None)()  # the runtime's session (stored vectors would skip it)
    embedder.embed_text(["warm up"])
    embedder_s = time.perf_counter() - t0
    result = {
        "machine": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "load_average_1min_at_start": os.getloadavg()[0],
        "embedder": type(embedder).__name__,
        "embedder_load_s": embedder_s,
        "query": bench_query(args.points, embedder),
        "plan": bench_plan(args.places),
        "monitor": bench_monitor(with_regions(grid_graph(args.places), embedder), embedder),
        "load": [bench_load(b) for b in args.bundle],
    }
    for b in args.bundle:
        from terra.loaded import LoadedBundle

        result.setdefault("monitor_bundles", []).append(
            {"bundle": str(b), **bench_monitor(LoadedBundle(b).require_graph("bench"), embedder)}
        )
    if args.cold:
        result["cold"] = bench_cold(args.cold, args.repeat)
    q, p = result["query"], result["plan"]
    rows = [
        (f"embedder load ({result['embedder']}, once per process)", f"{embedder_s:.2f} s", "-"),
        (
            f"feature cache, {q['points']:,} points (once per map: terra map stores it)",
            f"{q['feature_cache_s']:.2f} s",
            "-",
        ),
        (
            f"object query ms-avg, {q['points']:,} points",
            f"{q['ms-avg']['median_ms']:.1f} ms (max {q['ms-avg']['max_ms']:.1f}, "
            f"cpu {q['ms-avg']['cpu_median_ms']:.1f})",
            "<= 50 ms",
        ),
        (
            f"object query ms-max, {q['points']:,} points",
            f"{q['ms-max']['median_ms']:.1f} ms (max {q['ms-max']['max_ms']:.1f}, "
            f"cpu {q['ms-max']['cpu_median_ms']:.1f})",
            "<= 50 ms",
        ),
        ("object query ms-avg, new query text", f"{q['ms-avg_new_text_ms']:.1f} ms", "-"),
        (
            f"plan, {p['places']:,} places, warm (cost graph built)",
            f"{p['plain']['warm_median_ms']:.1f} ms "
            f"(max {p['plain']['warm_max_ms']:.1f}); with the cost graph {p['plain']['median_ms']:.1f} ms",
            "<= 20 ms",
        ),
        (
            f"plan with prefer/forbid, {p['places']:,} places, warm",
            f"{p['prefer_sidewalk_forbid_water']['warm_median_ms']:.1f} ms "
            f"(max {p['prefer_sidewalk_forbid_water']['warm_max_ms']:.1f}); with the cost graph "
            f"{p['prefer_sidewalk_forbid_water']['median_ms']:.1f} ms",
            "<= 20 ms",
        ),
        (
            f"monitor (mix, k 1), {result['monitor']['places']:,} places, regions {result['monitor']['regions']}",
            f"{result['monitor']['median_ms']:.2f} ms (max {result['monitor']['max_ms']:.2f})",
            "<= 10 ms",
        ),
    ]
    for m in result.get("monitor_bundles", []):
        rows.append(
            (
                f"monitor (mix, k 1) on {Path(m['bundle']).name}, {m['places']:,} places",
                f"{m['median_ms']:.2f} ms",
                "<= 10 ms",
            )
        )
    for label, c in result.get("cold", {}).items():
        target = "<= 0.5 s" if "help" in label else "<= 1.5 s"
        rows.append(
            (
                f"cold {label} (fresh process)",
                f"{c['median_s']:.2f} s (min {c['min_s']:.2f}, cpu {c['cpu_median_s']:.2f})",
                target,
            )
        )
    for load in result["load"]:
        rows.append(
            (
                f"load {Path(load['bundle']).name} ({load['points']:,} points, {load['places']:,} places)",
                f"{load['load_median_s']:.2f} s (+{load['feature_cache_s']:.2f} s feature cache)",
                "<= 2 s",
            )
        )
        rows.append(
            (
                f"warm find on {Path(load['bundle']).name} (LoadedBundle)",
                f"{load['warm_find_median_ms']:.1f} ms (cpu {load['warm_find_cpu_median_ms']:.1f})",
                "-",
            )
        )
    report(rows, result, args.out)


if __name__ == "__main__":
    main()
