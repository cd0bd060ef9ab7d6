"""Issue 18: a 10 km^2 map within one machine.

`large`: `terra build` on the large preset (2 km x 2 km) in one piece (`build.tiles.size: null`)
and in tiles (the default `build.tiles`), each in its own process under /usr/bin/time -v (wall
time, peak RSS), and whether both give the same places, edges and regions.

`huge`: the huge preset (3.2 km x 3.2 km, 10.24 km^2) end to end: `terra sim`, `terra map`,
`terra build` and a `terra find` query, each under /usr/bin/time -v (wall, peak RSS, output size).

Datasets and bundles are cached under --cache and reused (sim and map are skipped when present;
--fresh redoes them). Every command runs as `python -m terra` from this checkout.

Usage:
  python benchmarks/bench_scale.py large [--cache /work/bench-cache/issue-18b]
  python benchmarks/bench_scale.py huge [--cache /work/bench-cache/issue-18b] [--fresh]
Writes benchmarks/results/scale_<preset>.json and prints a table.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.benchtable import report  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
TIME = "/usr/bin/time"


def timed(args: list[str], log: Path) -> dict:
    """Run `python -m terra ARGS` under /usr/bin/time -v; wall seconds, peak RSS (MB), exit code."""
    cmd = [TIME, "-v", sys.executable, "-m", "terra", *args]
    start = time.perf_counter()
    with log.open("w") as out:
        done = subprocess.run(cmd, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
    wall = time.perf_counter() - start
    text = log.read_text()
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", text)
    return {"command": "terra " + " ".join(args), "wall_s": round(wall, 1), "peak_rss_mb": round(int(rss.group(1)) / 1024, 1) if rss else None,
            "exit_code": done.returncode, "log": str(log)}


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
    if fresh or not (data / "terra_dataset.json").exists():
        stages["sim"] = timed(["sim", "--preset", preset, "--seed", "0", "--out", str(data), "--overwrite", "-q"], cache / f"{preset}-sim.log")
        ensure(stages["sim"], "terra sim")
    if fresh or not (bundle / "manifest.json").exists():
        if bundle.exists():
            shutil.rmtree(bundle)
        stages["map"] = timed(["map", str(data), "--out", str(bundle), "-q"], cache / f"{preset}-map.log")
        ensure(stages["map"], "terra map")
    for name, path in (("sim", data), ("map", bundle)):
        if name in stages:
            stages[name]["output_mb"] = size_mb(path)
    return bundle, stages


def same_graph(a: Path, b: Path) -> dict:
    """Whether two bundles hold the same places, edges and regions."""
    from terra.bundle import Bundle
    from terra.graph.storage import load_scene_graph

    ga, gb = load_scene_graph(Bundle(a)), load_scene_graph(Bundle(b))
    checks = {
        "places": np.array_equal(ga.places.position, gb.places.position) and np.array_equal(ga.places.terrain, gb.places.terrain),
        "edges": np.array_equal(ga.place_edges, gb.place_edges) and np.array_equal(ga.place_edge_weight, gb.place_edge_weight)
        and np.array_equal(ga.place_edge_kind, gb.place_edge_kind),
        "regions": len(ga.regions) == len(gb.regions)
        and all(np.array_equal(ga.place_region(k), gb.place_region(k)) for k in range(1, len(ga.regions) + 1)),
    }
    checks["counts"] = {"places": len(ga.places), "edges": int(len(ga.place_edges)), "regions": [len(r) for r in ga.regions]}
    return checks


def build_stats(bundle: Path) -> dict:
    import json

    manifest = json.loads((bundle / "manifest.json").read_text())
    return manifest["components"]["graph"]["stats"]


def run_large(cache: Path, fresh: bool) -> None:
    bundle, stages = sim_and_map("large", cache, fresh)
    work = cache / "large-builds"
    work.mkdir(exist_ok=True)
    builds = {}
    for name, tiles in (("one piece", "null"), ("tiles", None)):
        target = work / f"{name.replace(' ', '-')}.terra"
        if target.exists():
            shutil.rmtree(target)
        shutil.copytree(bundle, target)
        config = work / f"{name.replace(' ', '-')}.yaml"
        config.write_text("build: {}\n" if tiles is None else f"build:\n  tiles:\n    size: {tiles}\n")
        builds[name] = timed(["build", str(target), "--config", str(config), "-q"], work / f"{name.replace(' ', '-')}.log")
        ensure(builds[name], f"terra build ({name})")
        builds[name]["stats"] = build_stats(target)
    same = same_graph(work / "one-piece.terra", work / "tiles.terra")
    rows = [(f"{s} large preset", f"{v['wall_s']} s, {v['peak_rss_mb']} MB peak, {v['output_mb']} MB", "-") for s, v in stages.items()]
    rows += [(f"terra build large, {name}", f"{b['wall_s']} s, {b['peak_rss_mb']:.0f} MB peak", "<= 2048 MB (tiles)") for name, b in builds.items()]
    rows.append(("tiles == one piece (places, edges, regions)", f"{same['places']}, {same['edges']}, {same['regions']}", "all True"))
    rows.append(("places / edges / regions per level", f"{same['counts']['places']} / {same['counts']['edges']} / {same['counts']['regions']}", "-"))
    report(rows, {**machine(), "preset": "large", "stages": stages, "builds": builds, "same": same}, RESULTS / "scale_large.json")


def run_huge(cache: Path, fresh: bool) -> None:
    start = time.perf_counter()
    bundle, stages = sim_and_map("huge", cache, fresh)
    stages["build"] = timed(["build", str(bundle)], cache / "huge-build.log")
    ensure(stages["build"], "terra build")
    stages["build"]["output_mb"] = size_mb(bundle)
    stages["build"]["stats"] = build_stats(bundle)
    stages["find"] = timed(["find", str(bundle), "get bike from the bicycle rack", "--method", "3dsg", "--json"], cache / "huge-find.log")
    ensure(stages["find"], "terra find")
    total = time.perf_counter() - start
    rows = [(f"terra {s} (huge)", f"{v['wall_s']} s, {v['peak_rss_mb']} MB peak" + (f", {v['output_mb']} MB" if "output_mb" in v else ""), "-")
            for s, v in stages.items()]
    peak = max(v["peak_rss_mb"] for v in stages.values())
    wall = sum(v["wall_s"] for v in stages.values())
    rows.append(("end to end (stages run here)", f"{wall:.0f} s, {peak:.0f} MB peak", "< 3600 s, < 8192 MB"))
    g = stages["build"]["stats"]
    rows.append(("huge map: grid cells, places", f"{g['grid_cells'][0]} x {g['grid_cells'][1]}, {sum(g['places_per_terrain'].values())}", "-"))
    report(rows, {**machine(), "preset": "huge", "stages": stages, "end_to_end_wall_s": round(wall, 1), "this_run_wall_s": round(total, 1),
                  "peak_rss_mb": peak, "cached_stages_reused": [s for s in ("sim", "map") if s not in stages]}, RESULTS / "scale_huge.json")


def machine() -> dict:
    return {"machine": platform.node(), "python": platform.python_version(), "cpus": os.cpu_count(),
            "load_average_1min_at_start": os.getloadavg()[0], "date": time.strftime("%Y-%m-%d")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("preset", choices=["large", "huge"])
    parser.add_argument("--cache", type=Path, default=Path("/work/bench-cache/issue-18b"))
    parser.add_argument("--fresh", action="store_true", help="simulate and map again even when cached")
    args = parser.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    (run_large if args.preset == "large" else run_huge)(args.cache, args.fresh)


if __name__ == "__main__":
    main()
