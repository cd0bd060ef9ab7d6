"""Incremental graph updates against full builds of the same map, version by version (issue 25).

A simulated drive (`--dataset`: a terra-folder written by `terra sim`) is fused frame by frame with
no prior map, as a robot maps live; after every `--update-every` seconds of drive (frame stamps)
the map so far is given to a `GraphUpdater` (terra.graph.update) and, side by side on the same
map, to a full `build_scene_graph`. Reported per update: both times, the rebuilt area, and how
the incremental graph differs from the full one:
- places: the share of the full build's places with an incremental place of the same terrain
  within one grid cell (and within 2 m), and the reverse;
- regions: on the places matched both ways, the Rand index of the level-1 assignments (the share
  of place pairs that both graphs put together or both apart), and of the top level.
The last row is the session's closing full build, which equals the batch graph by construction.

Usage: python benchmarks/bench_live_graph.py --dataset campus-sim --update-every 2 --frames 300
       [--update tile=4 --update context_margin=4 ...]  (build.update settings to try)
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.benchtable import report  # noqa: E402


def _setting(text: str) -> tuple[str, float]:
    """KEY=VALUE of `--update` (a field of build.update, a number)."""
    key, _, value = text.partition("=")
    return key, float(value)


def _matched(a, b, cell: float) -> np.ndarray:
    """(len(a),) index of b's place of the same terrain within `cell` metres (2-D) of each of a's, -1 if none."""
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

    out = np.full(len(a.places), -1, dtype=np.int64)
    for t in np.unique(a.places.terrain):
        ia, ib = np.flatnonzero(a.places.terrain == t), np.flatnonzero(b.places.terrain == t)
        if len(ib) == 0:
            continue
        d, j = cKDTree(b.places.position[ib, :2]).query(a.places.position[ia, :2])
        ok = d <= cell
        out[ia[ok]] = ib[j[ok]]
    return out


def _rand_index(x: np.ndarray, y: np.ndarray) -> float:
    from sklearn.metrics import rand_score

    return float(rand_score(x, y)) if len(x) > 1 else 1.0


def compare(full, inc, cell: float) -> dict:
    """How the incremental graph `inc` differs from the full build `full` of the same map."""
    f2i = _matched(full, inc, cell)
    i2f = _matched(inc, full, cell)
    both = np.flatnonzero((f2i >= 0) & (i2f[np.maximum(f2i, 0)] == np.arange(len(f2i))))
    result = {
        "places_full": len(full.places),
        "places_incremental": len(inc.places),
        "full_matched": float((f2i >= 0).mean()) if len(f2i) else 1.0,
        "incremental_matched": float((i2f >= 0).mean()) if len(i2f) else 1.0,
        "full_matched_2m": float((_matched(full, inc, 2.0) >= 0).mean()) if len(f2i) else 1.0,
    }
    for name, level in (("level1", 1), ("top", min(len(full.regions), len(inc.regions)))):
        if level < 1:
            continue
        result[f"rand_{name}"] = _rand_index(full.place_region(level)[both], inc.place_region(level)[f2i[both]])
    return result


def run(args: argparse.Namespace) -> dict:
    from terra.datasets.registry import open_dataset
    from terra.graph.config import BuildConfig
    from terra.graph.pipeline import build_scene_graph
    from terra.graph.update import GraphUpdater
    from terra.live import Session

    dataset = open_dataset(args.dataset)
    count = min(args.frames, len(dataset))
    config = BuildConfig.model_validate({"update": dict(_setting(text) for text in args.update)})
    updater = GraphUpdater(config)
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        session = Session(Path(tmp) / "live.terra", dataset.classes, graph=False, name="bench")
        last_update = None
        updates = 0
        for i in range(count):
            frame = dataset[i]
            session.add(frame)
            stamp = frame.stamp
            last_update = stamp if last_update is None else last_update
            if stamp - last_update < args.update_every and i + 1 < count:
                continue
            last_update = stamp
            msm = session.mapper.finish()
            try:
                start = time.perf_counter()
                update = updater.update(msm)
                inc_s = time.perf_counter() - start
            except Exception as exc:  # a map too young for places: note it and go on
                rows.append({"frame": i + 1, "note": str(exc)[:120]})
                updater = GraphUpdater(config)
                continue
            updates += 1
            if updates % args.compare_every and i + 1 < count:
                rows.append(
                    {
                        "frame": i + 1,
                        "map_points": len(msm),
                        "incremental_s": inc_s,
                        "kind": update.update.kind,
                        "zone_m2": update.update.zone_area,
                        "stages": dict(update.timer.seconds),
                    }
                )
                continue
            start = time.perf_counter()
            full = build_scene_graph(msm, config).graph
            full_s = time.perf_counter() - start
            row = {
                "frame": i + 1,
                "map_points": len(msm),
                "incremental_s": inc_s,
                "full_s": full_s,
                "kind": update.update.kind,
                "zone_m2": update.update.zone_area,
                "regions_reclustered": update.update.regions_reclustered,
                "stages": dict(update.timer.seconds),
            }
            row.update(compare(full, update.graph, config.grid.cell_size))
            rows.append(row)
            print(json.dumps({k: v for k, v in row.items() if k != "stages"}), flush=True)
        closing = updater.update(msm, full=True).graph
        final = compare(build_scene_graph(msm, config).graph, closing, config.grid.cell_size)
    return {"dataset": str(args.dataset), "frames": count, "rows": rows, "closing": final}


def _percentiles(seconds: list[float]) -> str:
    """Median / 90th percentile of durations (s) in ms, and how many."""
    if not seconds:
        return "none"
    return f"{np.median(seconds) * 1e3:.0f} / {np.percentile(seconds, 90) * 1e3:.0f} ms ({len(seconds)})"


def _summary(result: dict) -> list[tuple[str, str, str]]:
    every = [r for r in result["rows"] if r.get("kind") == "incremental"]
    inc = [r for r in every if "full_s" in r]
    if not inc:
        return [("incremental updates", "0", "")]
    med = lambda key: float(np.median([r[key] for r in inc]))  # noqa: E731
    last = result["rows"][-1]
    return [
        ("incremental updates (compared with a full build)", f"{len(every)} ({len(inc)})", ""),
        ("map points at the end", f"{last.get('map_points', 0):,}", ""),
        (
            "incremental update, median / p90 (count)",
            _percentiles([r["incremental_s"] for r in every]),
            "<= 150 ms median",
        ),
        (
            "of which rebuilt an area: median / p90 (count)",
            _percentiles([r["incremental_s"] for r in every if r.get("zone_m2")]),
            "",
        ),
        ("full build of the same map, median", f"{med('full_s') * 1e3:.0f} ms", ""),
        ("incremental / full, median", f"{np.median([r['incremental_s'] / r['full_s'] for r in inc]):.1%}", "<= 10 %"),
        (
            f"incremental / full at the largest map compared ({inc[-1]['map_points']:,} points)",
            f"{inc[-1]['incremental_s'] / inc[-1]['full_s']:.1%} ({inc[-1]['incremental_s'] * 1e3:.0f} / "
            f"{inc[-1]['full_s'] * 1e3:.0f} ms)",
            "<= 10 % on 1 M points",
        ),
        ("rebuilt area, median over every update", f"{np.median([r['zone_m2'] for r in every]):,.0f} m^2", ""),
        ("full places matched (worst)", f"{min(r['full_matched'] for r in inc):.3f}", ""),
        ("full places with one within 2 m (worst)", f"{min(r['full_matched_2m'] for r in inc):.3f}", ""),
        ("incremental places matched (worst)", f"{min(r['incremental_matched'] for r in inc):.3f}", ""),
        (
            "region Rand index level 1, median / worst",
            f"{med('rand_level1'):.3f} / {min(r['rand_level1'] for r in inc):.3f}",
            ">= 0.95",
        ),
        (
            "closing full build vs batch: places matched, Rand",
            f"{result['closing']['full_matched']:.3f}, {result['closing'].get('rand_level1', 1.0):.3f}",
            "1.000",
        ),
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--dataset", type=Path, required=True, help="a terra-folder from `terra sim`")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--update-every", type=float, default=2.0, help="seconds of drive between updates")
    parser.add_argument("--compare-every", type=int, default=10, help="a full build beside every Nth update")
    parser.add_argument(
        "--update", action="append", default=[], metavar="KEY=VALUE", help="a build.update setting, e.g. tile=4"
    )
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "live_graph.json")
    args = parser.parse_args()
    load = os.getloadavg()[0]
    result = run(args)
    result["load_average_1min_at_start"] = load
    result["update_settings"] = args.update
    result["cpus"] = os.cpu_count()
    result["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    args.out.parent.mkdir(parents=True, exist_ok=True)
    report(_summary(result), result, args.out)


if __name__ == "__main__":
    main()
