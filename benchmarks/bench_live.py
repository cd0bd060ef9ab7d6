"""Live mapping: per-frame fusion, snapshots and queries while the map grows (issue 25's targets).

The simulator drives `--preset` with a frame every `speed / hz` metres (a `--hz` LiDAR with one
camera frame per scan, labels backend). Frames are rendered first (not timed: a robot's sensors
give them), then fed to a terra.live.Session as fast as it takes them, with a snapshot (map commit,
graph rebuilt, read view loaded) after every `--update-every` seconds of drive time. After each
snapshot a find runs twice on it (cold: the view's first query; warm: the second).

Reported: fusion per frame (median, 99th percentile; the first frame, which loads the text
model, apart), sustained throughput (frames / (fusion +
snapshot time)), snapshot stages (median), warm and cold find (median, p99), peak memory.

Usage: python benchmarks/bench_live.py --preset small --frames 200 --hz 10 --update-every 2
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


def _render(preset: str, frames: int, hz: float):
    from terra.sim import simulate
    from terra.sim.config import SimConfig

    config = SimConfig()
    spacing = config.route.speed / hz
    config = config.model_copy(update={"route": config.route.model_copy(update={"frame_spacing": spacing})})
    dataset = simulate(preset, seed=0, config=config)
    count = min(frames, len(dataset))
    start = time.perf_counter()
    rendered = [dataset[i] for i in range(count)]
    return dataset, rendered, time.perf_counter() - start


def _percentiles(values: list[float]) -> tuple[float, float]:
    array = np.asarray(values, dtype=np.float64)
    return float(np.median(array)), float(np.percentile(array, 99))


def _find_seconds(snapshot, query: str) -> tuple[float, float]:
    """(cold, warm) seconds of one find on the snapshot's read view."""
    from terra.tasks.commands import find
    from terra.tasks.requests import FindRequest

    request = FindRequest(queries=[query])
    times = []
    for _ in range(2):
        start = time.perf_counter()
        find(snapshot.bundle, request)
        times.append(time.perf_counter() - start)
    return times[0], times[1]


def _first_in_view(frames, class_ids: set[int]) -> int | None:
    """Index of the first frame whose camera images show a pixel of the classes (the object is in view)."""
    for i, frame in enumerate(frames):
        for camera in frame.cameras:
            if camera.semantic is not None and np.isin(camera.semantic, list(class_ids)).any():
                return i
    return None


def _freshness(frames, dataset, snapshots: list[tuple[float, float, float | None]], query: str) -> dict:
    """When the queried object was first in view (drive time, s), the first snapshot that finds it
    within 2 m of the truth, and the freshness: the drive time from first view to that snapshot's
    last frame plus the snapshot's own time (a live run waits for both)."""
    from terra.eval.judging import gt_class_of

    gt = dataset.ground_truth()
    name = gt_class_of(query, gt)
    ids = {c.id for c in dataset.classes if c.name == name}
    first = _first_in_view(frames, ids)
    t0 = float(frames[0].stamp)
    out: dict = {"class": name, "first_in_view_s": None if first is None else float(frames[first].stamp) - t0}
    found = next(((t, took) for t, took, distance in snapshots if distance is not None and distance <= 2.0), None)
    if first is not None and found is not None:
        out["found_at_s"] = found[0] - t0
        out["freshness_s"] = found[0] - float(frames[first].stamp) + found[1]
    return out


def run(args: argparse.Namespace) -> dict:
    from terra.live import Session
    from terra.live.replay import ask

    dataset, frames, render_s = _render(args.preset, args.frames, args.hz)
    every = max(1, int(round(args.update_every * args.hz)))
    fuse: list[float] = []
    stages: dict[str, list[float]] = {"map": [], "graph": [], "load": []}
    snapshot_total: list[float] = []
    cold: list[float] = []
    warm: list[float] = []
    notes: list[str] = []
    judged: list[tuple[float, float, float | None]] = []  # (map time, snapshot seconds, metres to truth)
    kinds: list[str] = []
    gt = dataset.ground_truth()
    with tempfile.TemporaryDirectory() as tmp:
        session = Session(Path(tmp) / "live.terra", dataset.classes, graph=not args.no_graph, name=dataset.name)
        for i, frame in enumerate(frames):
            start = time.perf_counter()
            session.add(frame)
            fuse.append(time.perf_counter() - start)
            if (i + 1) % every == 0 or i + 1 == len(frames):
                start = time.perf_counter()
                snapshot = session.snapshot()
                snapshot_total.append(time.perf_counter() - start)
                for name, seconds in snapshot.seconds.items():
                    stages[name].append(seconds)
                if snapshot.graph_note:
                    notes.append(snapshot.graph_note)
                c, w = _find_seconds(snapshot, args.query)
                cold.append(c)
                warm.append(w)
                took = snapshot_total[-1]
                judged.append(
                    (float(snapshot.map_time or 0.0), took, ask(snapshot, 0.0, gt, args.query, None).distance_m)
                )
                kinds.append(snapshot.graph_update.get("kind", "none"))
        points = len(session.latest.bundle.msm) if session.latest is not None else 0
    fused_s = float(np.sum(fuse))
    return {
        "preset": args.preset,
        "hz": args.hz,
        "frames": len(frames),
        "update_every_frames": every,
        "render_seconds": render_s,
        "map_points": points,
        # The first frame loads the text model and embeds the class names once: reported apart.
        "first_frame_s": fuse[0],
        "fusion_per_frame_s": dict(zip(("median", "p99"), _percentiles(fuse[1:] or fuse))),
        "snapshots": len(snapshot_total),
        "snapshot_s": dict(zip(("median", "p99"), _percentiles(snapshot_total))),
        "snapshot_stage_median_s": {k: float(np.median(v)) for k, v in stages.items() if v},
        "throughput_fps": len(frames) / (fused_s + float(np.sum(snapshot_total))),
        "throughput_fusion_only_fps": len(frames) / fused_s,
        "find_cold_s": dict(zip(("median", "p99"), _percentiles(cold))),
        "find_warm_s": dict(zip(("median", "p99"), _percentiles(warm))),
        "graph_notes": sorted(set(notes))[:3],
        "graph_updates": {kind: kinds.count(kind) for kind in sorted(set(kinds))},
        "freshness": _freshness(frames, dataset, judged, args.query),
        "update_every_s": args.update_every,
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "load_average_1min_at_start": args.load,
        "cpus": os.cpu_count(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--preset", default="small")
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--hz", type=float, default=10.0)
    parser.add_argument("--update-every", type=float, default=2.0, help="seconds of drive between snapshots")
    parser.add_argument("--query", default="bicycle rack")
    parser.add_argument("--no-graph", action="store_true", help="snapshots commit the map only")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "live.json")
    args = parser.parse_args()
    args.load = os.getloadavg()[0]
    result = run(args)
    ms = 1000.0
    rows = [
        (
            "frames fed (Hz, snapshot every)",
            f"{result['frames']} ({args.hz:g} Hz, {result['update_every_frames']})",
            "",
        ),
        ("map points at the end", f"{result['map_points']}", ""),
        ("first frame (text model loaded)", f"{result['first_frame_s']:.1f} s", ""),
        ("fusion per frame median", f"{result['fusion_per_frame_s']['median'] * ms:.1f} ms", ""),
        ("fusion per frame p99", f"{result['fusion_per_frame_s']['p99'] * ms:.1f} ms", "<= 50 ms"),
        ("throughput with snapshots", f"{result['throughput_fps']:.1f} frames/s", ">= 10"),
        ("throughput, fusion only", f"{result['throughput_fusion_only_fps']:.1f} frames/s", ""),
        ("snapshot median", f"{result['snapshot_s']['median'] * ms:.0f} ms", "<= 200 ms (map)"),
        *(
            (f"  stage {name} median", f"{seconds * ms:.0f} ms", "")
            for name, seconds in result["snapshot_stage_median_s"].items()
        ),
        ("find warm median", f"{result['find_warm_s']['median'] * ms:.1f} ms", "<= 50 ms"),
        ("find warm p99", f"{result['find_warm_s']['p99'] * ms:.1f} ms", "<= 150 ms"),
        ("find cold median", f"{result['find_cold_s']['median'] * ms:.0f} ms", ""),
        ("graph updates (kind: count)", ", ".join(f"{k}: {v}" for k, v in result["graph_updates"].items()), ""),
        (
            f"freshness of {result['freshness']['class']!r} (first in view at "
            f"{result['freshness']['first_in_view_s']} s)",
            f"{result['freshness'].get('freshness_s', float('nan')):.1f} s",
            f"<= {args.update_every + 1:g} s",
        ),
        ("peak memory", f"{result['peak_rss_mib']:.0f} MiB", "<= 2048"),
    ]
    report(rows, result, args.out)


if __name__ == "__main__":
    main()
