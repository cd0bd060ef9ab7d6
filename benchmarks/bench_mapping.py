"""Phase 1 speed and size: fusion time per frame, and `terra map` on the campus preset.

Targets (issue "Phase 1"):
- fusion, excluding model inference: median <= 50 ms per frame (default LiDAR + one camera).
  Measured on the small simulated campus: frames are rendered and perceived (labels backend)
  first, untimed; then association + per-image fusion (projection, z-buffer, votes, DBSCAN, bank,
  counts, visibility) is timed frame by frame on one growing map, as `terra map` runs it.
- the campus bundle <= 150 MB and peak memory of `terra map` on the campus preset <= 4 GB: one
  `terra map DATASET --out OUT -q` child process, its peak RSS from getrusage(RUSAGE_CHILDREN).

Usage:
  python benchmarks/bench_mapping.py                       # full: 150 small-campus frames + campus map
  python benchmarks/bench_mapping.py --quick               # check: 20 frames + map of the tiny preset
  python benchmarks/bench_mapping.py --dataset DIR --map-out DIR --frames N --skip-campus
Writes benchmarks/results/mapping.json (mapping-quick.json with --quick; --result) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from benchtable import report

ROOT = Path(__file__).resolve().parents[1]


def bench_fusion(preset: str, n_frames: int) -> dict:
    """Per-frame wall time of fusion alone (no rendering, no perception) on `preset`."""
    from terra.mapping.config import MappingConfig
    from terra.mapping.fusion import MapFusion
    from terra.perception.registry import get_perception
    from terra.sim import simulate

    dataset = simulate(preset, seed=0)
    config = MappingConfig()
    perception = get_perception(config.perception, dataset.classes)
    n = min(n_frames, len(dataset))
    inputs = []
    perceive_s = []
    for i in range(n):
        frame = dataset[i]
        t0 = time.perf_counter()
        seen = [perception.perceive(cam, np.random.default_rng([0, i, c])) for c, cam in enumerate(frame.cameras)]
        perceive_s.append(time.perf_counter() - t0)
        inputs.append((frame, seen))
    fusion = MapFusion(config, perception.terrain_classes, perception.dim, dataset.global_map())
    per_frame, cpu = [], []
    for frame, seen in inputs:
        c0, t0 = time.process_time(), time.perf_counter()
        points_map, index = fusion.associate(frame.points, frame.T_map_lidar)
        for camera, s in zip(frame.cameras, seen):
            fusion.integrate_image(
                frame.points, points_map, index, frame.T_map_lidar, camera.calibration, camera.stamp, s
            )
        per_frame.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    t0 = time.perf_counter()
    msm = fusion.finish(perception.embedder, perception.terrain_embeddings())
    finish_s = time.perf_counter() - t0
    ms = np.asarray(per_frame) * 1e3
    return {
        "preset": preset,
        "frames": n,
        "cameras_per_frame": len(inputs[0][0].cameras) if inputs else 0,
        "scan_points_median": int(np.median([len(f.points) for f, _ in inputs])) if inputs else 0,
        "median_ms": float(np.median(ms)),
        "p90_ms": float(np.percentile(ms, 90)),
        "max_ms": float(ms.max()),
        "cpu_median_ms": float(statistics.median(cpu) * 1e3),
        "finish_s": finish_s,
        "map_points": len(msm),
        "bank_entries": int(msm.bank.shape[0]),
        "labels_perception_median_ms": float(np.median(perceive_s) * 1e3),
    }


def folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def bench_map_command(source: list[str], out: Path) -> dict:
    """Run `terra map SOURCE --out OUT -q` as a child; wall time, peak RSS, bundle size."""
    shutil.rmtree(out.with_name(out.name + ".partial"), ignore_errors=True)  # never resume here
    shutil.rmtree(out, ignore_errors=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    argv = [sys.executable, "-m", "terra", "map", *source, "--out", str(out), "-q"]
    t0 = time.perf_counter()
    done = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"terra map failed ({done.returncode}): {done.stderr.strip()}")
    peak_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss  # KiB on Linux
    manifest = json.loads((out / "manifest.json").read_text())
    info = manifest["components"]["map"]
    return {
        "command": " ".join(["terra", "map", *source, "--out", str(out), "-q"]),
        "wall_s": wall,
        "peak_rss_mb": peak_kb / 1024,
        "bundle_mb": folder_bytes(out) / 1e6,
        "bytes_per_component": {k: int(v) for k, v in sorted(_component_bytes(out).items())},
        "points": info["points"],
        "bank_entries": info["bank"],
        "images": info["images"],
        "observations": info["observations"],
        "frames_fused": info["stats"].get("frames_fused"),
    }


def _component_bytes(path: Path) -> dict[str, int]:
    from terra.bundle import Bundle

    return Bundle(path).component_bytes()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="20 frames and the tiny preset instead of the campus")
    parser.add_argument("--preset", default="small", help="simulated preset of the fusion timing")
    parser.add_argument("--frames", type=int, default=150, help="frames of the fusion timing")
    parser.add_argument(
        "--dataset", type=Path, default=Path("/work/bench-cache/campus-sim"), help="campus dataset folder"
    )
    parser.add_argument(
        "--map-out", type=Path, default=Path("/work/bench-cache/campus-map"), help="campus bundle to write"
    )
    parser.add_argument("--skip-campus", action="store_true", help="only the fusion timing")
    parser.add_argument(
        "--result",
        type=Path,
        default=None,
        help="JSON to write (default results/mapping.json, mapping-quick.json with --quick)",
    )
    args = parser.parse_args()

    frames = 20 if args.quick else args.frames
    args.result = args.result or ROOT / "benchmarks" / "results" / (
        "mapping-quick.json" if args.quick else "mapping.json"
    )
    result: dict = {
        "machine": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "load_average_1min_at_start": os.getloadavg()[0],
        "quick": args.quick,
    }
    result["fusion"] = f = bench_fusion(args.preset, frames)
    rows = [
        (
            f"fusion per frame ({f['preset']}, {f['frames']} frames, {f['cameras_per_frame']} camera, "
            f"~{f['scan_points_median']:,} pts/scan)",
            f"{f['median_ms']:.1f} ms median "
            f"(p90 {f['p90_ms']:.1f}, max {f['max_ms']:.1f}, cpu {f['cpu_median_ms']:.1f})",
            "<= 50 ms",
        ),
        ("  labels perception per frame (not fusion)", f"{f['labels_perception_median_ms']:.1f} ms median", "-"),
    ]
    if not args.skip_campus:
        if args.quick:
            tmp = Path(tempfile.mkdtemp(prefix="bench-mapping-"))
            source, out, label = ["--sim", "tiny"], tmp / "tiny.terra", "tiny preset"
        else:
            if not (args.dataset / "manifest.json").exists() and not args.dataset.is_dir():
                raise SystemExit(
                    f"{args.dataset}: no such dataset folder (generate it with `terra sim campus --out ...`)"
                )
            source, out, label = [str(args.dataset)], args.map_out, "campus preset"
        result["map"] = m = bench_map_command(source, out)
        result["map"]["label"] = label
        rows += [
            (
                f"terra map, {label} ({m['frames_fused']} frames, {m['points']:,} points)",
                f"{m['wall_s']:.1f} s wall",
                "-",
            ),
            (f"bundle size, {label}", f"{m['bundle_mb']:.1f} MB", "<= 150 MB"),
            (f"peak memory of terra map, {label}", f"{m['peak_rss_mb']:.0f} MB", "<= 4096 MB"),
        ]
        if args.quick:
            shutil.rmtree(out.parent, ignore_errors=True)
    report(rows, result, args.result)


if __name__ == "__main__":
    main()
