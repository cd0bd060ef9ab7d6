"""Snapshot cost of a live drive, this code against another (issue 25: "Snapshot: at most 200 ms on
the campus preset, memory flat over the drive (no full copy of the map per version)").

The frames of a written dataset (`--dataset`, e.g. `terra sim --preset campus --seed 0`) are fed
one by one to a `terra.live.Session(..., graph=False)`, with a snapshot after every `--every`
frames (the map and its fusion state committed as a new version, its read view loaded). Per
snapshot: the map's points, the snapshot's stages (map commit, read view load), the first MS-Avg /
MS-Max query work on the new view (computed on first use where the version does not store it),
the bytes and files the version wrote (files whose inode the version before did not have) and
the process's resident memory. The closing `close()` is not timed.

Each code runs in a child process of its own (`--before PATH` names a tree of the other code, e.g.
`git archive <commit> | tar -x -C PATH`), alternately `--rounds` times, on the same frames and
machine, so both see the same load.

Usage: python benchmarks/bench_live_snapshot.py --dataset campus-sim --every 100 --before /tmp/before
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parents[1]  # this code; a child imports the code its PYTHONPATH names


def _inodes(path: Path) -> dict[int, int]:
    """inode -> size of every file of folder `path`."""
    out = {}
    for root, _, files in os.walk(path):
        for name in files:
            info = os.stat(Path(root) / name)
            out[info.st_ino] = info.st_size
    return out


def drive(dataset_path: Path, every: int, frames: int | None, work: Path | None, chunk_rows: int | None) -> dict:
    """Feed the drive to a live session in this process (the code on sys.path); one row per snapshot."""
    from terra.datasets.registry import open_dataset
    from terra.live import Session

    dataset = open_dataset(dataset_path)
    count = min(frames or len(dataset), len(dataset))
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(dir=work) as tmp:
        out = Path(tmp) / "live.terra"
        options: dict[str, Any] = {"chunk_rows": chunk_rows} if chunk_rows else {}  # the code before has none
        session = Session(out, dataset.classes, name="bench", graph=False, **options)
        seen: dict[int, int] = {}
        for i in range(count):
            session.add(dataset[i])
            if (i + 1) % every and i + 1 < count:
                continue
            start = time.perf_counter()
            snap = session.snapshot()
            seconds = time.perf_counter() - start
            msm = snap.bundle.msm
            query = time.perf_counter()
            msm.ms_avg_norms()
            msm.ms_max_ids()
            query = time.perf_counter() - query
            files = _inodes(out)
            new = {ino: size for ino, size in files.items() if ino not in seen}
            seen = files
            with open("/proc/self/statm") as f:
                rss = int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
            rows.append(
                {
                    "frame": i + 1,
                    "map_points": len(msm),
                    "seconds": seconds,
                    "map_s": snap.seconds["map"],
                    "load_s": snap.seconds["load"],
                    "first_query_s": query,
                    "bytes_written": sum(new.values()),
                    "files_written": len(new),
                    "bundle_bytes": sum(files.values()),
                    "rss_mib": rss,
                }
            )
            print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
        session.close()
    return {"rows": rows, "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _child(code: Path, args: argparse.Namespace) -> dict:
    """`drive` in a child process running the code in folder `code`."""
    command = [sys.executable, str(Path(__file__).resolve()), "--child", "--dataset", str(args.dataset)]
    command += ["--every", str(args.every)] + (["--frames", str(args.frames)] if args.frames else [])
    command += ["--work", str(args.work)] if args.work else []
    command += ["--chunk-rows", str(args.chunk_rows)] if args.chunk_rows and code == HERE else []
    env = {**os.environ, "PYTHONPATH": str(code)}
    done = subprocess.run(command, env=env, stdout=subprocess.PIPE, text=True, check=True)
    return json.loads(done.stdout)


def _table(result: dict) -> list[tuple[str, str, str]]:
    rows: list[tuple[str, str, str]] = []
    names = [name for name in ("before", "after") if name in result["runs"]]
    for i, snap in enumerate(result["runs"][names[-1]][0]["rows"]):

        def cell(name: str, key: str, i: int = i) -> str:
            values = [run["rows"][i][key] for run in result["runs"][name]]
            return " / ".join(f"{v * 1000:.0f}" for v in values)

        value = "; ".join(
            f"{n} {cell(n, 'seconds')} ms (map {cell(n, 'map_s')}, load {cell(n, 'load_s')})" for n in names
        )
        rows.append((f"snapshot at {snap['map_points']:,} points", value, "<= 200 ms"))
    for name in names:
        runs = result["runs"][name]
        last = [run["rows"][-1] for run in runs]
        written = np.mean([r["bytes_written"] for r in last]) / 2**20
        rows.append(
            (f"{name}: written by the last snapshot", f"{written:.1f} MiB in {last[0]['files_written']} files", "")
        )
        rows.append((f"{name}: first query work on the last view", f"{last[0]['first_query_s'] * 1000:.0f} ms", ""))
        rows.append(
            (f"{name}: peak resident memory", " / ".join(f"{r['peak_rss_mib']:.0f}" for r in runs) + " MiB", "")
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--dataset", type=Path, required=True, help="a terra-folder from `terra sim`")
    parser.add_argument("--every", type=int, default=100, help="frames between snapshots")
    parser.add_argument("--frames", type=int, default=None, help="frames fed (default: all)")
    parser.add_argument("--before", type=Path, default=None, help="a tree of the code to compare with")
    parser.add_argument("--rounds", type=int, default=2, help="runs of each code, alternately")
    parser.add_argument("--work", type=Path, default=None, help="where the live bundles are written")
    parser.add_argument("--chunk-rows", type=int, default=None, help="rows per chunk of this code's versions")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "live_snapshot.json")
    args = parser.parse_args()
    if args.child:
        print(json.dumps(drive(args.dataset, args.every, args.frames, args.work, args.chunk_rows)))
        return
    sys.path.insert(0, str(HERE))
    from benchmarks.benchtable import report

    load = os.getloadavg()[0]
    codes = ([("before", args.before)] if args.before else []) + [("after", HERE)]
    runs: dict[str, list[dict]] = {name: [] for name, _ in codes}
    for _ in range(args.rounds):
        for name, code in codes:
            runs[name].append(_child(code, args))
    result = {"dataset": str(args.dataset), "every": args.every, "runs": runs, "before": str(args.before)}
    result["chunk_rows"] = args.chunk_rows
    result.update(load_average_1min_at_start=load, cpus=os.cpu_count(), load_average_1min_at_end=os.getloadavg()[0])
    report(_table(result), result, args.out)


if __name__ == "__main__":
    main()
