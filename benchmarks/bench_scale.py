"""Issue 18: a 10 km^2 map within one machine.

`large`: `terra build` on the large preset (2 km x 2 km) in one piece (`build.tiles.size: null`)
and in tiles (the default `build.tiles`), each in its own process under /usr/bin/time -v (wall
time, peak RSS), and whether both give the same places, edges and regions.

`growth`: Phase 2 (`terra build`) on growing maps: the campus preset (0.25 km^2), the large preset
(4 km^2) and a synthetic 10.24 km^2 map made of 2 x 2 copies of the large preset's map (shifted by
the world's side, cropped to 3.2 km x 3.2 km; images and visibility copied with it), each in one
piece and in tiles, under /usr/bin/time -v, then a `terra find` query on the tiled 10 km^2 bundle.
It reports peak RSS and wall time per km^2 and the growth from the large map to the 10 km^2 one.

`huge`: the huge preset (3.2 km x 3.2 km, 10.24 km^2, 76,955 objects, 3,106 frames) end to end:
`terra sim`, `terra map`, `terra build` (tiles) and a `terra find` query, each under /usr/bin/time -v
(wall, CPU seconds, peak RSS, output size, 1-minute load average before and after: the machine is
shared, so wall time also counts other jobs).

`memory`: `terra build` (default tiles) of this checkout side by side with an earlier commit
(`--baseline`, unpacked with `git archive`) on the campus, large and huge maps (each copied into
--cache first; `--map NAME=BUNDLE` points at a mapped bundle), alternating the two trees per map, each
build in its own process under /usr/bin/time -v. It reports peak RSS, MB per km^2 and the growth
per km^2 between the maps, and whether both trees give the same places (positions, terrains,
clearances, embeddings), edges (pairs, weights, kinds) and every region level.

Datasets and bundles are cached under --cache and reused (sim and map are skipped when present;
--fresh redoes them). Every command runs as `python -m terra` from this checkout.

Usage:
  python benchmarks/bench_scale.py large [--cache /work/bench-cache/issue-18b]
  python benchmarks/bench_scale.py growth [--cache /work/bench-cache/issue-18b] [--skip-one-piece-10km2]
  python benchmarks/bench_scale.py huge [--cache /work/bench-cache/issue-18c] [--fresh]
  python benchmarks/bench_scale.py memory --baseline COMMIT --cache DIR --map campus=B --map large=B --map huge=B
Writes benchmarks/results/scale_<preset>.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.benchtable import report  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
TIME = "/usr/bin/time"


def timed(args: list[str], log: Path, tree: Path = ROOT) -> dict:
    """Run `python -m terra ARGS` (the checkout at `tree`) under /usr/bin/time -v; wall seconds,
    peak RSS (MB), exit code."""
    cmd = [TIME, "-v", sys.executable, "-m", "terra", *args]
    load_before = os.getloadavg()[0]
    start = time.perf_counter()
    with log.open("w") as out:
        done = subprocess.run(cmd, cwd=tree, stdout=out, stderr=subprocess.STDOUT)
    wall = time.perf_counter() - start
    text = log.read_text()
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", text)
    # CPU seconds beside wall time: on a shared machine the wall time also counts other jobs.
    cpu = sum(float(x) for x in re.findall(r"(?:User|System) time \(seconds\): ([\d.]+)", text))
    return {
        "command": "terra " + " ".join(args),
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1),
        "peak_rss_mb": round(int(rss.group(1)) / 1024, 1) if rss else None,
        "exit_code": done.returncode,
        "load_average_1min": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        "log": str(log),
    }


def size_mb(path: Path) -> float:
    if path.is_file():
        return round(path.stat().st_size / 1e6, 1)
    return round(sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) / 1e6, 1)


def ensure(stage: dict | None, what: str) -> None:
    if stage is not None and stage["exit_code"] != 0:
        raise SystemExit(f"{what} failed (exit {stage['exit_code']}); see {stage['log']}")


def sim_and_map(preset: str, cache: Path, fresh: bool) -> tuple[Path, dict]:
    data, bundle = cache / f"{preset}-data", cache / f"{preset}.terra"
    stages = {}
    if not fresh and (bundle / "manifest.json").exists():
        return bundle, stages  # mapped before: the simulation is not needed again
    if fresh or not (data / "terra_dataset.json").exists():
        stages["sim"] = timed(
            ["sim", "--preset", preset, "--seed", "0", "--out", str(data), "--overwrite"],  # timing table in the log
            cache / f"{preset}-sim.log",
        )
        ensure(stages["sim"], "terra sim")
    if fresh or not (bundle / "manifest.json").exists():
        if bundle.exists():
            shutil.rmtree(bundle)
        stages["map"] = timed(["map", str(data), "--out", str(bundle)], cache / f"{preset}-map.log")
        ensure(stages["map"], "terra map")
    for name, path in (("sim", data), ("map", bundle)):
        if name in stages:
            stages[name]["output_mb"] = size_mb(path)
    return bundle, stages


def same_content(a: Path, b: Path) -> bool:
    """Whether two bundles' graphs hold the same places with clearances and embeddings, edges with
    weights and kinds, and region levels (same_graph checks these but for clearance and embedding)."""
    from terra.bundle import Bundle
    from terra.graph.storage import load_scene_graph

    ga, gb = load_scene_graph(Bundle(a)), load_scene_graph(Bundle(b))
    same = same_graph(a, b)
    return bool(
        same["places"]
        and same["edges"]
        and same["regions"]
        and np.array_equal(ga.places.clearance, gb.places.clearance)
        and np.array_equal(ga.places.embedding, gb.places.embedding)
    )


def same_graph(a: Path, b: Path) -> dict:
    """Whether two bundles hold the same places, edges and regions."""
    from terra.bundle import Bundle
    from terra.graph.storage import load_scene_graph

    ga, gb = load_scene_graph(Bundle(a)), load_scene_graph(Bundle(b))
    checks: dict[str, object] = {
        "places": np.array_equal(ga.places.position, gb.places.position)
        and np.array_equal(ga.places.terrain, gb.places.terrain),
        "edges": np.array_equal(ga.place_edges, gb.place_edges)
        and np.array_equal(ga.place_edge_weight, gb.place_edge_weight)
        and np.array_equal(ga.place_edge_kind, gb.place_edge_kind),
        "regions": len(ga.regions) == len(gb.regions)
        and all(np.array_equal(ga.place_region(k), gb.place_region(k)) for k in range(1, len(ga.regions) + 1)),
    }
    checks["counts"] = {
        "places": len(ga.places),
        "edges": int(len(ga.place_edges)),
        "regions": [len(r) for r in ga.regions],
    }
    return checks


def build_stats(bundle: Path) -> dict:
    manifest = json.loads((bundle / "manifest.json").read_text())
    return manifest["components"]["graph"]["stats"]


def run_large(cache: Path, fresh: bool) -> None:
    bundle, stages = sim_and_map("large", cache, fresh)
    work = cache / "large-builds"
    work.mkdir(exist_ok=True)
    builds = build_both(bundle, work, "large")
    same = builds.pop("same")
    rows = [
        (f"{s} large preset", f"{v['wall_s']} s, {v['peak_rss_mb']} MB peak, {v['output_mb']} MB", "-")
        for s, v in stages.items()
    ]
    rows += [
        (f"terra build large, {name}", f"{b['wall_s']} s, {b['peak_rss_mb']:.0f} MB peak", "<= 2048 MB (tiles)")
        for name, b in builds.items()
    ]
    rows.append(
        (
            "tiles == one piece (places, edges, regions)",
            f"{same['places']}, {same['edges']}, {same['regions']}",
            "all True",
        )
    )
    rows.append(
        (
            "places / edges / regions per level",
            f"{same['counts']['places']} / {same['counts']['edges']} / {same['counts']['regions']}",
            "-",
        )
    )
    report(
        rows,
        {**machine(), "preset": "large", "stages": stages, "builds": builds, "same": same},
        RESULTS / "scale_large.json",
    )


def run_huge(cache: Path, fresh: bool) -> None:
    start = time.perf_counter()
    bundle, stages = sim_and_map("huge", cache, fresh)
    stages["build"] = timed(["build", str(bundle)], cache / "huge-build.log")
    ensure(stages["build"], "terra build")
    stages["build"]["output_mb"] = size_mb(bundle)
    stages["build"]["stats"] = build_stats(bundle)
    stages["find"] = timed(
        ["find", str(bundle), "get bike from the bicycle rack", "--method", "3dsg", "--json"], cache / "huge-find.log"
    )
    ensure(stages["find"], "terra find")
    text = Path(stages["find"]["log"]).read_text()
    answer = json.loads(text[text.index("{") : text.rindex("}") + 1])
    stages["find"]["answer"] = f"{len(answer['objects'])} objects"
    total = time.perf_counter() - start
    rows = [
        (
            f"terra {s} (huge)",
            f"{v['wall_s']} s ({v['cpu_s']} s CPU, load {v['load_average_1min'][0]}-{v['load_average_1min'][1]}), "
            f"{v['peak_rss_mb']} MB peak" + (f", {v['output_mb']} MB" if "output_mb" in v else ""),
            "-",
        )
        for s, v in stages.items()
    ]
    peak = max(v["peak_rss_mb"] for v in stages.values())
    wall = sum(v["wall_s"] for v in stages.values())
    cpu = sum(v["cpu_s"] for v in stages.values())
    rows.append(
        ("end to end (stages run here)", f"{wall:.0f} s ({cpu:.0f} s CPU), {peak:.0f} MB peak", "< 3600 s, < 8192 MB")
    )
    g = stages["build"]["stats"]
    rows.append(
        (
            "huge map: grid cells, places",
            f"{g['grid_cells'][0]} x {g['grid_cells'][1]}, {sum(g['places_per_terrain'].values())}",
            "-",
        )
    )
    report(
        rows,
        {
            **machine(),
            "preset": "huge",
            "stages": stages,
            "end_to_end_wall_s": round(wall, 1),
            "end_to_end_cpu_s": round(cpu, 1),
            "this_run_wall_s": round(total, 1),
            "peak_rss_mb": peak,
            "cached_stages_reused": [s for s in ("sim", "map") if s not in stages],
        },
        RESULTS / "scale_huge.json",
    )


def twin_map(source: Path, target: Path, world: float, side: float) -> dict:
    """Write a synthetic map `side` x `side` metres into bundle `target`: 2 x 2 copies of the map of
    bundle `source` (a world `world` metres square from (0, 0)), each cut to its world, shifted by
    (i world, j world) and cropped to [0, side)^2. Images (poses shifted) and the visibility index go with each copy, so
    place embeddings still come from images. Returns its size (points, images, km^2)."""
    import scipy.sparse as sp

    from terra.bundle import Bundle, BundleWriter
    from terra.mapping.semantic_map import ImageTable, MetricSemanticMap
    from terra.mapping.storage import load_map, write_map
    from terra.mapping.visibility import VisibilityIndex

    msm = load_map(Bundle(source))
    vis, images = msm.visibility, msm.images
    shifts = [(i * world, j * world) for j in range(2) for i in range(2)]
    rows, points, T, keys, owners = [], [], [], [], []
    pair_images = np.repeat(np.arange(len(vis.indptr) - 1), np.diff(vis.indptr)) if vis is not None else None
    for k, (dx, dy) in enumerate(shifts):
        p = msm.points + np.array([dx, dy, 0.0], dtype=np.float32)
        inside = (msm.points[:, :2] >= 0).all(axis=1) & (msm.points[:, :2] < world).all(
            axis=1
        )  # no overlap between copies
        keep = np.flatnonzero(inside & (p[:, 0] < side) & (p[:, 1] < side))
        rows.append(keep)
        points.append(p[keep])
        t = images.T_map_cam.copy()
        t[:, 0, 3] += dx
        t[:, 1, 3] += dy
        T.append(t)
        if vis is not None:  # voxel keys pack x, y in 21-bit fields: a whole-cell shift adds to the key
            cx, cy = int(round(dx / vis.cell_size)), int(round(dy / vis.cell_size))
            keys.append(vis.cell_keys[pair_images] + (cx << 42) + (cy << 21))
            owners.append(vis.images.astype(np.int64) + k * len(images))
    table = ImageTable(
        stamp=np.concatenate([images.stamp + k * 1e6 for k in range(len(shifts))]),
        camera=np.tile(images.camera, len(shifts)),
        T_map_cam=np.concatenate(T),
        embedding=np.tile(images.embedding, (len(shifts), 1)),
        camera_names=images.camera_names,
    )
    index = None
    if vis is not None:
        index = VisibilityIndex.from_pairs(np.concatenate(keys), np.concatenate(owners), vis.cell_size, table.position)
    twin = MetricSemanticMap(
        points=np.vstack(points),
        terrain_classes=msm.terrain_classes,
        terrain_votes=np.vstack([msm.terrain_votes[r] for r in rows]),
        terrain_embeddings=msm.terrain_embeddings,
        counts=sp.csr_matrix(sp.vstack([msm.counts[r] for r in rows]).tocsr()),
        bank=msm.bank,
        images=table,
        embedder=msm.embedder,
        voxel_size=msm.voxel_size,
        visibility=index,
    )
    if target.exists():
        shutil.rmtree(target)
    base = Bundle(source)
    with BundleWriter(target) as writer:
        write_map(
            writer,
            twin,
            dataset=f"2 x 2 copies of {source.name}, cropped to {side:g} m",
            classes=base.json("map/meta.json")["classes"],
        )
        writer.set_perception(base.model.perception or {})
    return {"points": len(twin), "images": len(table), "km2": round(side * side / 1e6, 2)}


def build_both(bundle: Path, work: Path, label: str, one_piece: bool = True) -> dict:
    """`terra build` on copies of `bundle` in tiles and (when asked) in one piece."""
    builds = {}
    for name, tiles in (("tiles", None), ("one piece", "null"))[: 2 if one_piece else 1]:
        stem = f"{label}-{name.replace(' ', '-')}"
        target = work / f"{stem}.terra"
        if target.exists():
            shutil.rmtree(target)
        shutil.copytree(bundle, target)
        config = work / f"{stem}.yaml"
        config.write_text("build: {}\n" if tiles is None else f"build:\n  tiles:\n    size: {tiles}\n")
        builds[name] = timed(["build", str(target), "--config", str(config), "-q"], work / f"{stem}.log")
        ensure(builds[name], f"terra build ({label}, {name})")
        builds[name]["stats"] = build_stats(target)
        builds[name]["bundle"] = str(target)
    if one_piece:
        builds["same"] = same_graph(work / f"{label}-one-piece.terra", work / f"{label}-tiles.terra")
    return builds


def query_twin(bundle: str, work: Path) -> dict:
    """Retrieval, monitoring (regions) and navigation on the 10 km^2 map: a find, a monitor and a
    plan from the far corner (3.1 km, 3.1 km) to the object a task names, across the whole map."""
    task = "get bike from the bicycle rack"
    commands = {
        "find": ["find", bundle, task, "--method", "3dsg", "--json"],
        "monitor": ["monitor", bundle, "Large parking lot surrounded by buildings", "--json"],
        "plan": ["plan", bundle, "--to", task, "--from-xy", "3100", "3100", "--prefer", "sidewalk", "--json"],
    }
    out = {}
    for name, args in commands.items():
        log = work / f"twin-{name}.log"
        out[name] = timed(args, log)
        ensure(out[name], f"terra {name}")
        text = log.read_text()
        body = json.loads(text[text.index("{") : text.rindex("}") + 1])
        if name == "find":
            out[name]["answer"] = f"{len(body['objects'])} objects"
        elif name == "monitor":
            regions = sum(len(r["regions"]) for r in body["results"])
            out[name]["answer"] = f"{regions} regions, {sum(len(r['places']) for r in body['results'])} places"
        else:
            out[name]["answer"] = f"path of {len(body['places'])} places, {body['length_m']:.0f} m"
    return out


def run_growth(cache: Path, fresh: bool, one_piece_10km2: bool = True) -> None:
    from terra.sim.presets import get_preset

    work = cache / "growth"
    work.mkdir(exist_ok=True)
    maps = {}
    for preset in ("campus", "large"):
        bundle, stages = sim_and_map(preset, cache, fresh)
        size = get_preset(preset).size
        maps[preset] = {"bundle": bundle, "km2": round(size * size / 1e6, 2), "stages": stages}
    twin = work / "twin-10km2-map.terra"
    start = time.perf_counter()
    maps["10 km2 twin"] = {"bundle": twin, **twin_map(maps["large"]["bundle"], twin, get_preset("large").size, 3200.0)}
    maps["10 km2 twin"]["make_s"] = round(time.perf_counter() - start, 1)
    rows = []
    for label, m in maps.items():
        m["builds"] = build_both(
            m["bundle"], work, label.replace(" ", "-"), one_piece=one_piece_10km2 or label != "10 km2 twin"
        )
        m["bundle"] = str(m["bundle"])
        for name in ("tiles", "one piece"):
            if name in m["builds"]:
                b = m["builds"][name]
                g = b["stats"]
                rows.append(
                    (
                        f"terra build {label} ({m['km2']} km2), {name}",
                        f"{b['wall_s']} s ({b['cpu_s']} s CPU), {b['peak_rss_mb']:.0f} MB peak; "
                        f"grid {g['grid_cells'][0]} x {g['grid_cells'][1]}, "
                        f"{sum(g['places_per_terrain'].values())} places",
                        "<= 2048 MB (large, tiles)" if label == "large" and name == "tiles" else "-",
                    )
                )
        if "same" in m["builds"]:
            same = m["builds"]["same"]
            rows.append(
                (
                    f"{label}: tiles == one piece (places, edges, regions)",
                    f"{same['places']}, {same['edges']}, {same['regions']}",
                    "all True",
                )
            )
    queries = query_twin(maps["10 km2 twin"]["builds"]["tiles"]["bundle"], work)
    for name, q in queries.items():
        rows.append(
            (f"terra {name} on the 10 km2 twin", f"{q['wall_s']} s, {q['peak_rss_mb']:.0f} MB peak; {q['answer']}", "-")
        )
    growth = {}
    for name in ("tiles", "one piece"):
        a, b = maps["large"]["builds"].get(name), maps["10 km2 twin"]["builds"].get(name)
        if a and b:
            dkm2 = maps["10 km2 twin"]["km2"] - maps["large"]["km2"]
            growth[name] = {
                "mb_per_km2": round((b["peak_rss_mb"] - a["peak_rss_mb"]) / dkm2, 1),
                "s_per_km2": round((b["wall_s"] - a["wall_s"]) / dkm2, 1),
                "cpu_s_per_km2": round((b["cpu_s"] - a["cpu_s"]) / dkm2, 1),
            }
            rows.append(
                (
                    f"growth large -> 10 km2, {name}",
                    f"{growth[name]['mb_per_km2']} MB/km2, {growth[name]['s_per_km2']} s/km2 "
                    f"({growth[name]['cpu_s_per_km2']} s CPU/km2)",
                    "-",
                )
            )
    report(rows, {**machine(), "maps": maps, "queries": queries, "growth": growth}, RESULTS / "scale_growth.json")


def run_memory(cache: Path, baseline: str, maps: dict[str, Path]) -> None:
    from terra.sim.presets import get_preset

    work = cache / "memory"
    work.mkdir(parents=True, exist_ok=True)
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
    ).stdout.strip()
    result = {"baseline": baseline, "this": commit, "maps": {}}
    rows = []
    with tempfile.TemporaryDirectory(prefix="terra-baseline-") as tmp:
        old_tree = Path(tmp)
        archive = subprocess.run(["git", "archive", baseline], cwd=ROOT, capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(old_tree)], input=archive, check=True)
        for name, bundle in maps.items():
            km2 = round(get_preset(name).size ** 2 / 1e6, 2)
            entry = {"bundle": str(bundle), "km2": km2}
            for label, tree in (("before", old_tree), ("after", ROOT)):
                target = work / f"{name}-{label}.terra"
                if target.exists():
                    shutil.rmtree(target)
                shutil.copytree(bundle, target)
                entry[label] = timed(["build", str(target), "-q", "--overwrite"], work / f"{name}-{label}.log", tree)
                ensure(entry[label], f"terra build ({name}, {label})")
                entry[label]["mb_per_km2"] = round(entry[label]["peak_rss_mb"] / km2, 1)
                entry[label]["grid_cells"] = build_stats(target)["grid_cells"]
            entry["same_graph"] = same_content(work / f"{name}-before.terra", work / f"{name}-after.terra")
            for label in ("before", "after"):
                shutil.rmtree(work / f"{name}-{label}.terra")
            result["maps"][name] = entry
            b, a = entry["before"], entry["after"]
            rows.append(
                (
                    f"terra build {name} ({km2} km2, grid {a['grid_cells'][0]} x {a['grid_cells'][1]})",
                    f"before {b['peak_rss_mb']:.0f} MB, {b['wall_s']} s ({b['cpu_s']} s CPU); "
                    f"after {a['peak_rss_mb']:.0f} MB, {a['wall_s']} s ({a['cpu_s']} s CPU); "
                    f"same graph: {entry['same_graph']}",
                    "same graph",
                )
            )
    names = list(result["maps"])
    result["growth_mb_per_km2"] = {}
    for lo, hi in zip(names, names[1:]):
        m0, m1 = result["maps"][lo], result["maps"][hi]
        growth = {
            label: round((m1[label]["peak_rss_mb"] - m0[label]["peak_rss_mb"]) / (m1["km2"] - m0["km2"]), 1)
            for label in ("before", "after")
        }
        result["growth_mb_per_km2"][f"{lo} -> {hi}"] = growth
        rows.append(
            (f"growth {lo} -> {hi}", f"before {growth['before']} MB/km2, after {growth['after']} MB/km2", "lower")
        )
    report(rows, {**machine(), **result}, RESULTS / "scale_memory.json")


def machine() -> dict:
    return {
        "machine": platform.node(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "load_average_1min_at_start": os.getloadavg()[0],
        "date": time.strftime("%Y-%m-%d"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("preset", choices=["large", "huge", "growth", "memory"])
    parser.add_argument("--cache", type=Path, default=Path("/work/bench-cache/issue-18b"))
    parser.add_argument("--fresh", action="store_true", help="simulate and map again even when cached")
    parser.add_argument(
        "--skip-one-piece-10km2", action="store_true", help="growth: build the 10 km^2 map in tiles only"
    )
    parser.add_argument("--baseline", default="HEAD", help="memory: the commit to compare this checkout with")
    parser.add_argument(
        "--map",
        action="append",
        default=[],
        metavar="NAME=BUNDLE",
        help="memory: a preset's mapped bundle (campus, large, huge), smallest first",
    )
    args = parser.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    if args.preset == "memory":
        if not args.map:
            raise SystemExit("memory: give at least one --map NAME=BUNDLE")
        run_memory(args.cache, args.baseline, {m.split("=", 1)[0]: Path(m.split("=", 1)[1]) for m in args.map})
    elif args.preset == "growth":
        run_growth(args.cache, args.fresh, not args.skip_one_piece_10km2)
    else:
        (run_large if args.preset == "large" else run_huge)(args.cache, args.fresh)


if __name__ == "__main__":
    main()
