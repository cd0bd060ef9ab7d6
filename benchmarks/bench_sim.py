"""Simulator speed: one default frame (LiDAR scan + camera image), whole presets with `terra sim`.

Targets (issue 2, on a 2-core machine): one default LiDAR scan (32 x 1024) plus one default camera
frame (640 x 480) rendered in <= 0.5 s; the small preset generated in <= 2 min; the campus preset
in <= 15 min.

- frame: median over `--frames` frames spread along the small preset's route (after one warm-up
  frame, which compiles the kernels), LiDAR and camera timed separately.
- presets: `terra sim --preset P --seed 0` in a fresh process per preset (so import and kernel
  compilation count), wall time, CPU time and peak memory of that process, output size, and the
  time to read every frame back with the format's reader.

Usage:
  python benchmarks/bench_sim.py --presets small,campus          # full size (the lead's run)
  python benchmarks/bench_sim.py --quick                         # a minute: frame + tiny preset
Writes benchmarks/results/sim.json (or --out) and prints a table.
"""

from __future__ import annotations

import argparse
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

from benchtable import report

TARGETS = {"frame": 0.5, "small": 120.0, "campus": 900.0}


def bench_frame(frames: int) -> dict:
    """Median seconds to render one default frame, LiDAR and camera separately."""
    import numpy as np

    from terra.geometry import invert_pose
    from terra.sim import simulate

    ds = simulate("small", seed=0)
    picks = np.linspace(0, len(ds) - 1, frames + 1).round().astype(int)
    lidar, camera = [], []
    points = []
    for k, i in enumerate(picks):
        T = ds.gt_T_map_lidar(int(i))
        t0 = time.perf_counter()
        scan = ds.lidar.render(ds.world, T, np.random.default_rng(0))
        t1 = time.perf_counter()
        for cam in ds.cameras:
            cam.render(ds.world, T @ invert_pose(cam.calibration.T_cam_lidar))
        t2 = time.perf_counter()
        if k == 0:
            continue  # warm-up: kernel compilation
        lidar.append(t1 - t0)
        camera.append(t2 - t1)
        points.append(len(scan["points"]))
    total = [a + b for a, b in zip(lidar, camera)]
    cfg = ds.config
    return {
        "frames_timed": len(total),
        "lidar_s_median": statistics.median(lidar),
        "camera_s_median": statistics.median(camera),
        "frame_s_median": statistics.median(total),
        "frame_s_max": max(total),
        "points_per_scan_median": statistics.median(points),
        "lidar": f"{cfg.lidar.beams} x {cfg.lidar.columns}",
        "cameras": [f"{c.width} x {c.height}" for c in cfg.cameras],
    }


def bench_preset(preset: str, fmt: str, work: Path, max_frames: int | None) -> dict:
    """`terra sim` in a fresh process: wall, CPU, peak RSS, bytes written, read-back time."""
    out = work / f"{preset}-{fmt}"
    argv = ["sim", "--preset", preset, "--seed", "0", "--format", fmt, "--out", str(out), "--quiet", "--overwrite"]
    if max_frames:
        argv += ["--max-frames", str(max_frames)]
    code = (
        "import resource, sys; from terra.cli import run; rc = run(sys.argv[1:]); "
        "print('PEAK_RSS_KB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr); sys.exit(rc)"
    )
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"terra sim failed ({proc.returncode}): {proc.stderr.strip().splitlines()[-1:]}")
    rss_kb = next(int(line.split()[1]) for line in proc.stderr.splitlines() if line.startswith("PEAK_RSS_KB"))
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())

    from terra.datasets import open_dataset

    t1 = time.perf_counter()
    ds = open_dataset(out)
    for i in range(len(ds)):
        ds[i]
    read = time.perf_counter() - t1
    return {
        "preset": preset,
        "format": fmt,
        "frames": len(ds),
        "wall_s": wall,
        "cpu_s": (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime),
        "peak_rss_mb": rss_kb / 1024,
        "output_mb": size / 2**20,
        "read_back_s": read,
        "summary": proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else "",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--presets",
        default="small",
        help="comma-separated presets to generate (tiny, small, campus, large; '' for none)",
    )
    parser.add_argument("--format", default="terra-folder", choices=["terra-folder", "semantickitti"])
    parser.add_argument("--frames", type=int, default=9, help="frames timed for the per-frame figure")
    parser.add_argument("--max-frames", type=int, default=None, help="cap the generated presets (for a check run)")
    parser.add_argument(
        "--work", type=Path, default=None, help="where generated datasets go (default: a temp folder, removed)"
    )
    parser.add_argument("--quick", action="store_true", help="3 frames, tiny preset with 10 frames")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "sim.json")
    args = parser.parse_args()
    if args.quick:
        args.frames, args.presets, args.max_frames = 3, "tiny", 10
    presets = [p for p in args.presets.split(",") if p]

    result = {
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "load_average_1min_at_start": os.getloadavg()[0],
        "quick": args.quick,
    }
    result["frame"] = bench_frame(args.frames)
    work = args.work or Path(tempfile.mkdtemp(prefix="bench-sim-"))
    try:
        result["presets"] = [bench_preset(p, args.format, work, args.max_frames) for p in presets]
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)

    f = result["frame"]
    rows = [
        ("frame: LiDAR " + f["lidar"] + " (median)", f"{f['lidar_s_median']:.3f} s", ""),
        ("frame: camera " + ", ".join(f["cameras"]) + " (median)", f"{f['camera_s_median']:.3f} s", ""),
        (
            "frame: LiDAR + camera (median / max)",
            f"{f['frame_s_median']:.3f} / {f['frame_s_max']:.3f} s",
            f"<= {TARGETS['frame']} s",
        ),
    ]
    for p in result["presets"]:
        target = TARGETS.get(p["preset"]) if not args.max_frames else None
        rows.append(
            (
                f"terra sim --preset {p['preset']} ({p['frames']} frames, {p['format']})",
                f"{p['wall_s']:.1f} s wall, {p['cpu_s']:.0f} s CPU, "
                f"{p['peak_rss_mb']:.0f} MB, {p['output_mb']:.0f} MB out",
                f"<= {target:.0f} s" if target else "",
            )
        )
        rows.append(
            (
                f"  read back all frames ({p['format']} reader)",
                f"{p['read_back_s']:.1f} s ({p['frames'] / max(p['read_back_s'], 1e-9):.0f} frames/s)",
                "",
            )
        )
    report(rows, result, args.out)


if __name__ == "__main__":
    main()
