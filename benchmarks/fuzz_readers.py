"""Reliability (issues 13 and 24): mutation fuzzing of every reader, value families, and kill -9
during `terra map`.

Fuzzing: the harness of the test suite (tests/reliability/fuzzing.py) on many more inputs. Jobs go round robin
over the readers (bundle manifest, every bundle array, scene graph, map metadata, the terra-folder,
SemanticKITTI and KITTI raw layouts, ROS 1 and ROS 2 bags, config, task and msmap files, the authors'
reference files) and issue 24's value families (node ids, coordinates, queries, tf quaternions,
oversized images in folders and bags, truncated ROS 1 / ROS 2 bags, KITTI raw / SemanticKITTI /
terra-folder calibration values, HTTP requests to the service: tests/reliability/families.py); each
case works on a fresh copy of its 3-frame seed and runs the command that reads it in a worker
process observed from outside, so a crash (the worker dies) or a hang (no answer within `--timeout`
s, killed) is counted rather than taking the run down. Targets: over >= 10,000 inputs, zero
tracebacks (HTTP 5xx), crashes, hangs, partial outputs, changed input bundles and files written
outside the output path.

Kills: `terra map` of the 3-frame dataset over an existing bundle, SIGKILLed from outside after a
random share of an uninterrupted run's time, then rerun: the output path must hold the old or the new
complete bundle after the kill, the rerun the new one (the same bytes as an uninterrupted run), and
no leftovers (`.NAME.*`, `NAME.partial`) may remain.

Usage (from the repository root):
  python benchmarks/fuzz_readers.py --cases 10000 --kills 50     # the issue's target (hours on 2 cores)
  python benchmarks/fuzz_readers.py --cases 600 --kills 10        # a quick check
  python benchmarks/fuzz_readers.py --cases 10000 --budget 1800   # stop starting cases after 30 min
  python benchmarks/fuzz_readers.py --families --cases 10000 --kills 0   # issue 24's value families only
Writes benchmarks/results/fuzz_readers.json (or --out) and prints a table.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import platform
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # this worktree's terra and tests, not an installed copy

from benchtable import report  # noqa: E402

from tests.reliability.fuzzing import FAILURES, build_seeds, supervise, targets  # noqa: E402


def fuzz(
    seeds,
    work: Path,
    cases: int,
    workers: int,
    timeout: float,
    budget: float | None,
    only: list[str] | None = None,
    offset: int = 0,
) -> dict:
    """Counts of outcomes per reader and the failures (at most 50, with their mutation)."""
    names = only or list(targets(seeds))
    jobs = [
        {"target": names[k % len(names)], "seed": offset + k // len(names), "seeds": seeds.to_json(), "work": str(work)}
        for k in range(cases)
    ]
    until = None if budget is None else time.monotonic() + budget
    done = [0]

    def log(result: dict) -> None:
        done[0] += 1
        if result["outcome"] in FAILURES:
            print(
                f"  {result['outcome']}: {result['target']} #{result['seed']}: {result['mutation']} "
                f"{result['detail'][:200]!r}",
                flush=True,
            )
        if done[0] % 500 == 0:
            print(f"  {done[0]} of {cases} inputs", flush=True)

    start = time.perf_counter()
    results = supervise(jobs, workers=workers, timeout=timeout, log=log, until=until)
    per_target: dict[str, collections.Counter] = {n: collections.Counter() for n in names}
    for r in results:
        per_target[r["target"]][r["outcome"]] += 1
    failures = [r for r in results if r["outcome"] in FAILURES]
    return {
        "inputs": len(results),
        "seconds": time.perf_counter() - start,
        "outcomes": dict(sum(per_target.values(), collections.Counter())),
        "per_target": {n: dict(c) for n, c in per_target.items()},
        "failures": failures[:50],
    }


def _bundle_state(path: Path) -> str:
    from tests.reliability.test_crash_safety import bundle_state

    return bundle_state(path)


def kills(seeds, work: Path, count: int, rng: random.Random) -> dict:
    """`terra map` over an existing bundle killed after a random share of a full run, then rerun."""
    from tests.reliability.test_crash_safety import leftovers

    if count == 0:
        return {"runs": 0, "full_run_seconds": None, "tally": {}, "failures": []}
    dataset = seeds.datasets["terra-folder"]
    (work / "old.yaml").write_text("mapping:\n  fusion:\n    voxel_size: 0.5\n")
    (work / "new.yaml").write_text("mapping:\n  checkpoint_every: 1\n")
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}

    def argv(out: Path, config: str) -> list[str]:
        # --overwrite: the run replaces an existing bundle (without it `terra map` refuses at once).
        return [
            *(sys.executable, "-m", "terra", "map", str(dataset), "--out", str(out), "--overwrite", "-q"),
            *("-c", str(work / config)),
        ]

    subprocess.run(argv(work / "old.terra", "old.yaml"), cwd=REPO, env=env, check=True, capture_output=True)
    t0 = time.perf_counter()
    subprocess.run(argv(work / "new.terra", "new.yaml"), cwd=REPO, env=env, check=True, capture_output=True)
    full = time.perf_counter() - t0
    old, new = _bundle_state(work / "old.terra"), _bundle_state(work / "new.terra")
    tally = collections.Counter()
    bad = []
    for k in range(count):
        folder = work / f"kill{k}"
        folder.mkdir()
        out = folder / "campus.terra"
        shutil.copytree(work / "old.terra", out)
        proc = subprocess.Popen(
            argv(out, "new.yaml"), cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        time.sleep(rng.uniform(0.0, 1.1) * full)
        proc.send_signal(signal.SIGKILL)
        killed = proc.wait() == -signal.SIGKILL
        tally["killed" if killed else "finished before the kill"] += 1
        # The two-rename fallback may leave the path missing until a command's recovery step runs.
        subprocess.run(
            [sys.executable, "-m", "terra", "info", str(out), "--no-verify"], cwd=REPO, env=env, capture_output=True
        )
        after_kill = _bundle_state(out)
        rerun = subprocess.run(argv(out, "new.yaml"), cwd=REPO, env=env, capture_output=True, text=True)
        checks = {
            "old or new after the kill": after_kill in (old, new),
            "rerun exit 0": rerun.returncode == 0,
            "new bundle after the rerun": _bundle_state(out) == new,
            "no leftovers": leftovers(folder, out.name) == [],
        }
        for what, ok in checks.items():
            tally[what if ok else f"NOT {what}"] += 1
        if not all(checks.values()):
            bad.append({"run": k, "checks": checks, "stderr": rerun.stderr[-500:]})
        shutil.rmtree(folder)
    return {"runs": count, "full_run_seconds": full, "tally": dict(tally), "failures": bad}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", type=int, default=10_000, help="mutated inputs to run")
    parser.add_argument("--kills", type=int, default=20, help="killed `terra map` runs")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds without an answer that make a hang")
    parser.add_argument("--budget", type=float, default=None, help="start no fuzz case after this many seconds")
    parser.add_argument("--targets", default=None, help="comma-separated readers (default: all)")
    parser.add_argument("--families", action="store_true", help="only issue 24's value families")
    parser.add_argument("--seed-offset", type=int, default=0, help="first case number of each reader")
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "fuzz_readers.json")
    args = parser.parse_args()
    result = {
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "load_average_1min_at_start": os.getloadavg()[0],
        "args": {k: str(v) for k, v in vars(args).items()},
    }
    with tempfile.TemporaryDirectory(prefix="terra-fuzz-") as tmp:
        work = Path(tmp)
        seeds = build_seeds(work / "seeds")
        (work / "fuzz").mkdir()
        (work / "kill").mkdir()
        only = args.targets.split(",") if args.targets else None
        if args.families:
            from tests.reliability.families import families

            only = [f.name for f in families()]
        if only and set(only) - set(targets(seeds)):
            parser.error(f"unknown readers {sorted(set(only) - set(targets(seeds)))}; known: {sorted(targets(seeds))}")
        result["fuzz"] = fuzz(
            seeds, work / "fuzz", args.cases, args.workers, args.timeout, args.budget, only, args.seed_offset
        )
        result["kill"] = kills(seeds, work / "kill", args.kills, random.Random(0))
    f, k = result["fuzz"], result["kill"]
    outcomes = f["outcomes"]
    rows = [
        ("mutated inputs", str(f["inputs"]), ">= 10000"),
        ("  exit 0, valid result", str(outcomes.get("ok", 0)), ""),
        ("  exit 2, one line", str(outcomes.get("refused", 0)), ""),
    ]
    rows += [(f"  {what}", str(outcomes.get(what, 0)), "0") for what in FAILURES]
    rows += [
        ("fuzz wall time", f"{f['seconds']:.0f} s", ""),
        ("kill -9 of terra map", str(k["runs"]), ""),
        ("  killed mid-run", str(k["tally"].get("killed", 0)), ""),
    ]
    rows += [
        (f"  {what}", str(k["tally"].get(what, 0)), str(k["runs"]))
        for what in ("old or new after the kill", "new bundle after the rerun", "no leftovers")
    ]
    report(rows, result, args.out)
    print(json.dumps({n: c for n, c in f["per_target"].items()}, sort_keys=True))


if __name__ == "__main__":
    main()
