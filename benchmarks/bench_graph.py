"""Phase 2 speed and memory: `terra build` on the campus preset, one terrain GVD on a large grid,
agglomerative regions for 20,000 places, and a scaling table of synthetic place sets.

Targets (issue 4): `terra build` on the campus preset <= 30 s; one terrain GVD on a 2500 x 2500
grid <= 3 s; agglomerative regions for 20,000 places <= 20 s and <= 2 GB.

Memory is measured in a child process per case (peak RSS from resource.getrusage, minus the RSS
after imports, and the tracemalloc peak of the call, which NumPy reports into), so cases do not
inherit each other's high-water marks.

Usage:
  python benchmarks/bench_graph.py [--bundle /work/bench-cache/campus-map] [--grid 2500]
      [--places 20000] [--scaling 1000 5000 20000 50000] [--quick] [--skip-build]
Writes benchmarks/results/graph.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results" / "graph.json"
DEFAULT_BUNDLE = Path("/work/bench-cache/campus-map")


# ------------------------------------------------------------------------------ synthetic data


def synthetic_mask(size: int, seed: int = 0) -> np.ndarray:
    """A (size, size) free mask like one terrain of a campus at 0.4 m cells: open ground cut by
    rectangular buildings (4-40 m) and round trees (1-3 m), about 30 % blocked."""
    rng = np.random.default_rng(seed)
    free = np.ones((size, size), dtype=bool)
    n_buildings = size * size // 6000
    r, c = rng.integers(0, size, (2, n_buildings))
    h, w = rng.integers(10, 100, (2, n_buildings))
    for i in range(n_buildings):  # O(buildings) rectangles, not per cell
        free[r[i] : r[i] + h[i], c[i] : c[i] + w[i]] = False
    yy, xx = np.mgrid[-8:9, -8:9]
    for radius in (3, 5, 8):
        disk = (yy**2 + xx**2) <= radius**2
        centres = np.zeros((size, size), dtype=bool)
        centres[rng.integers(0, size, size * size // 20000), rng.integers(0, size, size * size // 20000)] = True
        from scipy import ndimage

        free &= ~np.asarray(ndimage.binary_dilation(centres, structure=disk), dtype=bool)
    return free


def synthetic_places(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """n places at a campus density (one per ~50 m^2, as on the simulated campus) with terrain and
    embedding families in 80 m zones, and the edges of their 4-nearest-neighbour graph.
    Returns (position (n, 3) m, embedding (n, 384), terrain (n,), edges (e, 2))."""
    from scipy.spatial import KDTree

    rng = np.random.default_rng(seed)
    side = np.sqrt(n * 50.0)
    xy = rng.uniform(0, side, (n, 2))
    pos = np.column_stack([xy, rng.normal(0, 0.5, n)])
    zone = (np.floor(xy[:, 0] / 80) * 7 + np.floor(xy[:, 1] / 80)).astype(np.int64) % 12
    family = rng.standard_normal((12, 384)).astype(np.float32)
    emb = family[zone] + 0.6 * rng.standard_normal((n, 384)).astype(np.float32)
    emb /= np.linalg.norm(emb, axis=1, keepdims=True)
    nn = np.asarray(KDTree(xy).query(xy, k=5)[1])
    edges = np.unique(np.sort(np.column_stack([np.repeat(np.arange(n), 4), nn[:, 1:].ravel()]), axis=1), axis=0)
    return pos, emb, zone % 5, edges


# ------------------------------------------------------------------------------ child processes


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kilobytes


def child(case: str, n: int) -> dict:
    """Run one case in this process and return seconds and memory."""
    import tracemalloc

    from terra.graph.agglomerative import agglomerative_assignments
    from terra.graph.spectral import SpectralStop, spectral_assignments

    if case == "gvd":
        from terra.graph.gvd import gvd
        from terra.graph.places import extract_places

        free = synthetic_mask(n)
        base = _rss_mb()
        tracemalloc.start()
        t0 = time.perf_counter()
        skeleton, _ = gvd(free, min_clearance=1.0, min_gap=1.5)
        t_gvd = time.perf_counter() - t0
        t0 = time.perf_counter()
        places = extract_places(
            free,
            min_clearance=1.0,
            min_gap=1.5,
            prune_ratio=1.5,
            prune_length=2.5,
            junction_merge=1.0,
            max_deviation=9.375,
            max_distance=25.0,
        )
        t_places = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        return {
            "case": f"GVD {n} x {n}",
            "seconds": t_gvd,
            "places_seconds": t_places,
            "free_share": float(free.mean()),
            "gvd_cells": int(skeleton.sum()),
            "places": int(len(places.cells)),
            "tracemalloc_peak_mb": peak,
            "rss_increase_mb": _rss_mb() - base,
        }
    pos, emb, terrain, edges = synthetic_places(n)
    base = _rss_mb()
    tracemalloc.start()
    t0 = time.perf_counter()
    if case == "agglomerative":
        labels = agglomerative_assignments(pos, emb, terrain)
    else:
        # The paper's rule stops at once on these places (a balanced mix of zones has a small
        # semantic difference), so time the reference's rule, which splits down to 10,000 m^2.
        labels = spectral_assignments(pos, emb, edges, stop=SpectralStop(0.45, 10000.0, "both"))
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    name = case if case == "agglomerative" else "spectral (stop_rule both)"
    return {
        "case": f"{name} {n} places",
        "seconds": seconds,
        "regions": [int(len(np.unique(x))) for x in labels],
        "tracemalloc_peak_mb": peak,
        "rss_increase_mb": _rss_mb() - base,
        "rss_peak_mb": _rss_mb(),
    }


def in_child(case: str, n: int, timeout: float) -> dict:
    cmd = [sys.executable, __file__, "--child", case, str(n)]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=True)
    except subprocess.TimeoutExpired:
        return {"case": f"{case} {n}", "seconds": None, "note": f"over {timeout:g} s"}
    except subprocess.CalledProcessError as exc:
        return {"case": f"{case} {n}", "seconds": None, "note": exc.stderr.strip().splitlines()[-1][:200]}
    return json.loads(out.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------------------ terra build


def bench_build(bundle: Path, repeat: int) -> list[dict]:
    from terra.bundle import Bundle
    from terra.graph.pipeline import run_build

    rows = []
    if not (bundle / "manifest.json").is_file():
        return [
            {
                "case": f"terra build {bundle}",
                "seconds": None,
                "note": "bundle not found (run terra sim + terra map first)",
            }
        ]
    manifest = Bundle(bundle).manifest
    with tempfile.TemporaryDirectory(prefix="bench-graph-") as tmp:
        work = Path(tmp) / bundle.name
        shutil.copytree(bundle, work)
        for method in ("agglomerative", "spectral"):
            times, result = [], None
            for _ in range(repeat):
                t0 = time.perf_counter()
                result = run_build(work, regions=method, show_progress=False)
                times.append(time.perf_counter() - t0)
            assert result is not None  # repeat >= 1
            g = result.graph
            rows.append(
                {
                    "case": f"terra build ({method})",
                    "seconds": min(times),
                    "runs": times,
                    "map_points": manifest.get("counts", {}).get("points"),
                    "places": len(g.places),
                    "place_edges": int(len(g.place_edges)),
                    "regions": [len(level) for level in g.regions],
                    "stages": result.timer.to_json(),
                }
            )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--bundle", type=Path, default=DEFAULT_BUNDLE, help="campus map bundle (terra map output)")
    parser.add_argument("--grid", type=int, default=2500, help="GVD grid side, cells")
    parser.add_argument("--places", type=int, default=20000, help="places for the agglomerative target")
    parser.add_argument("--scaling", type=int, nargs="*", default=[1000, 5000, 20000, 50000])
    parser.add_argument("--repeat", type=int, default=2, help="terra build runs per method (best is reported)")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per child case")
    parser.add_argument("--quick", action="store_true", help="small sizes, to check the script")
    parser.add_argument("--skip-build", action="store_true")
    parser.add_argument("--child", nargs=2, metavar=("CASE", "N"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child[0], int(args.child[1]))))
        return
    if args.quick:
        args.grid, args.places, args.scaling, args.repeat = 500, 2000, [500, 2000], 1

    rows: list[dict] = []
    if not args.skip_build:
        rows += bench_build(args.bundle, args.repeat)
    rows.append(in_child("gvd", args.grid, args.timeout))
    rows.append(in_child("agglomerative", args.places, args.timeout))
    scaling = []
    for n in args.scaling:
        for case in ("agglomerative", "spectral"):
            scaling.append(in_child(case, n, args.timeout))
            print(f"  {scaling[-1]['case']}: {scaling[-1].get('seconds')}", file=sys.stderr)

    targets = {
        "terra build (agglomerative)": 30.0,
        "terra build (spectral)": 30.0,
        f"GVD {args.grid} x {args.grid}": 3.0,
        f"agglomerative {args.places} places": 20.0,
    }
    memory_target_mb = {f"agglomerative {args.places} places": 2048.0}
    print(f"{'case':34s} {'seconds':>9s} {'target':>8s} {'RSS+ MB':>8s} {'traced MB':>9s}  detail")
    for row in rows + scaling:
        sec = "-" if row.get("seconds") is None else f"{row['seconds']:.2f}"
        tgt = targets.get(row["case"])
        rss, traced = row.get("rss_increase_mb"), row.get("tracemalloc_peak_mb")
        detail = row.get("note") or ", ".join(
            f"{k} {row[k]:.2f}" if isinstance(row[k], float) else f"{k} {row[k]}"
            for k in ("places", "regions", "places_seconds", "gvd_cells")
            if k in row
        )
        target = f"<= {tgt:g}" if tgt else ""
        rss_text = "" if rss is None else f"{rss:8.0f}"
        traced_text = "" if traced is None else f"{traced:9.0f}"
        print(f"{row['case']:34s} {sec:>9s} {target:>8s} {rss_text:>8s} {traced_text:>9s}  {detail}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(
        json.dumps(
            {
                "machine": {
                    "python": platform.python_version(),
                    "processor": platform.processor() or platform.machine(),
                },
                "quick": args.quick,
                "targets_seconds": targets,
                "targets_memory_mb": memory_target_mb,
                "rows": rows,
                "scaling": scaling,
            },
            indent=1,
            sort_keys=True,
        )
        + "\n"
    )
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
