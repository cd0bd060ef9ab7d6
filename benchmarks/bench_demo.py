"""`terra demo` wall time, from an empty folder (cold) and again on its caches (warm).

Target (issue "Evaluation suite and the end-to-end demo"): `terra demo --preset small` in at most
5 minutes on this machine, cold. Each run is a fresh `terra` process, as a user would start it
(imports and the text embedder's loading included).

Usage: python benchmarks/bench_demo.py [--preset small] [--out DIR] [--quick]
  --quick   the tiny preset (a check of the script, seconds instead of minutes)
  --out     where the demo writes (must not exist; default a temporary folder, removed after)
Writes benchmarks/results/demo.json (demo_tiny.json with --quick) and prints a table.
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
from pathlib import Path

TARGET_S = 300.0
STAGE_ORDER = [
    "test: simulate",
    "test: map",
    "test: graph",
    "validation: simulate",
    "validation: map",
    "validation: graph",
    "validation: tune",
    "test: tasks",
    "eval:",
]


def stage_rank(name: str) -> int:
    return next((i for i, prefix in enumerate(STAGE_ORDER) if name.startswith(prefix)), len(STAGE_ORDER))


def run_demo(out: Path, preset: str, seed: int) -> tuple[float, dict]:
    """Wall seconds of one `terra demo` process and its --json output."""
    cmd = [sys.executable, "-m", "terra", "demo", "--out", str(out), "--preset", preset, "--seed", str(seed), "--json"]
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if proc.returncode != 0:
        sys.exit(f"terra demo failed (exit {proc.returncode}):\n{proc.stderr[-2000:]}")
    return seconds, json.loads(proc.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--preset", default="small")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--quick", action="store_true", help="tiny preset")
    args = parser.parse_args()
    preset = "tiny" if args.quick else args.preset
    if args.out is not None and args.out.exists():
        sys.exit(f"{args.out}: exists; the cold run needs an empty folder")
    if args.out is not None:
        tmp, out = None, Path(args.out)
    else:
        tmp = Path(tempfile.mkdtemp(prefix="terra-bench-demo-"))
        out = tmp / "demo"
    try:
        cold_s, cold = run_demo(out, preset, args.seed)
        warm_s, warm = run_demo(out, preset, args.seed)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    assert all(v == "cached" for v in warm["steps"].values()), warm["steps"]
    ev = cold["evaluation"]
    result = {
        "preset": preset,
        "seed": args.seed,
        "cold_s": round(cold_s, 2),
        "warm_s": round(warm_s, 2),
        "target_s": TARGET_S,
        "meets_target": cold_s <= TARGET_S,
        "stages_s": {k: round(cold["timing"][k], 2) for k in sorted(cold["timing"], key=stage_rank)},
        "frames": {"test": cold["test_scene"].get("frames"), "validation": cold["validation_scene"].get("frames")},
        "figures": {
            "retrieval_f1": {m: round(v["f1"], 3) for m, v in ev["retrieval"]["methods"].items()},
            "regions_f1": {m: round(v["f1"], 3) for m, v in ev["regions"]["methods"].items()},
            "memory_bytes": ev["memory"]["total_bytes"],
        },
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "platform": platform.platform()},
    }
    print(f"terra demo --preset {preset} --seed {args.seed}")
    print(f"  {'run':<28} {'seconds':>9}")
    verdict = "met" if result["meets_target"] else "MISSED"
    print(f"  {'cold (empty --out)':<28} {cold_s:>9.1f}   target <= {TARGET_S:.0f} s: {verdict}")
    print(f"  {'warm (every step cached)':<28} {warm_s:>9.1f}")
    print("  cold run by stage:")
    for name, sec in result["stages_s"].items():
        print(f"    {name:<36} {sec:>8.1f}")
    results = Path(__file__).resolve().parent / "results"
    results.mkdir(exist_ok=True)
    path = results / ("demo_tiny.json" if preset == "tiny" else "demo.json")
    path.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
