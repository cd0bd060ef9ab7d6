"""Memory and snapshot cost of a long live drive (issue 25: "live mapping of the large preset within 2 GB
peak", "memory flat over the drive").

The frames of a written dataset (`--dataset`, e.g. `terra sim --preset large`) are fed one by one to a
`terra.live.Session` (labels backend, graph on: each snapshot commits the map and its fusion state and
updates the scene graph), with a snapshot after every `--snapshot-every` frames and `close()` (the
closing full build) at the end. Per snapshot: the map's points, the commit's stages (map, graph, load)
and the process's resident memory now and at its peak so far (the whole process: Python, the text
model, the dataset reader, the session).

Usage: python benchmarks/bench_live_memory.py --dataset large-sim --snapshot-every 50 [--frames N]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.benchtable import report  # noqa: E402


def _rss_mib() -> tuple[float, float]:
    """(resident now, peak so far) of this process, MiB."""
    with open("/proc/self/statm") as f:
        now = int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    return now, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run(args: argparse.Namespace) -> dict:
    from terra.datasets.registry import open_dataset
    from terra.live import Session

    dataset = open_dataset(args.dataset)
    count = min(args.frames or len(dataset), len(dataset))
    rows: list[dict] = []
    started = time.perf_counter()
    if args.work is not None:
        args.work.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=args.work) as tmp:
        session = Session(Path(tmp) / "live.terra", dataset.classes, name="bench")
        for i in range(count):
            session.add(dataset[i])
            if (i + 1) % args.snapshot_every and i + 1 < count:
                continue
            start = time.perf_counter()
            snap = session.snapshot() if i + 1 < count else session.close()
            assert snap is not None
            now, peak = _rss_mib()
            graph = snap.bundle.graph if not snap.graph_note else None
            row = {
                "frame": i + 1,
                "map_points": len(snap.bundle.msm.points),
                "places": len(graph.places) if graph is not None else 0,
                "seconds": time.perf_counter() - start,
                "stages": dict(snap.seconds),
                "graph": snap.graph_update.get("kind", snap.graph_note),
                "rss_mib": now,
                "peak_rss_mib": peak,
            }
            rows.append(row)
            print({k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
    return {"dataset": str(args.dataset), "frames": count, "rows": rows, "wall_s": time.perf_counter() - started}


def _summary(result: dict) -> list[tuple[str, str, str]]:
    rows = result["rows"]
    last = rows[-1]
    commits = [r["stages"].get("map", 0.0) for r in rows[:-1]] or [0.0]
    per_point = [r["rss_mib"] / max(r["map_points"], 1) * 1e6 for r in rows if r["map_points"] > 100_000]
    return [
        ("frames / snapshots", f"{result['frames']} / {len(rows)}", ""),
        ("map points at the end / places", f"{last['map_points']:,} / {last['places']:,}", ""),
        ("peak resident memory", f"{max(r['peak_rss_mib'] for r in rows):,.0f} MiB", "<= 2,048 MiB"),
        ("resident memory per million map points, first / last", _first_last(per_point, "MiB"), "flat"),
        ("map commit, median / last", f"{np.median(commits):.2f} / {commits[-1]:.2f} s", ""),
        ("closing snapshot (full build)", f"{last['seconds']:.1f} s", ""),
        ("whole drive", f"{result['wall_s'] / 60:.1f} min", ""),
    ]


def _first_last(values: list[float], unit: str) -> str:
    return f"{values[0]:,.0f} / {values[-1]:,.0f} {unit}" if values else "-"


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--dataset", type=Path, required=True, help="a terra-folder from `terra sim`")
    parser.add_argument("--frames", type=int, default=None, help="frames fed (default: all)")
    parser.add_argument("--snapshot-every", type=int, default=50)
    parser.add_argument("--work", type=Path, default=None, help="where the live bundle is written (a temporary folder)")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "live_memory.json")
    args = parser.parse_args()
    load = os.getloadavg()[0]
    result = run(args)
    result["load_average_1min_at_start"] = load
    result["cpus"] = os.cpu_count()
    report(_summary(result), result, args.out)


if __name__ == "__main__":
    main()
