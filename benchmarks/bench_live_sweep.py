"""Graph updates of a live drive with updates far apart, long rebuilt parts cut into squares
(`build.update.max_crop_side`) or read as one bounding box (issue 25: "a sweep's long part read as
one bounding box").

The first `--frames` frames of a written dataset (e.g. `terra sim --preset large --seed 0`) are fed
to a `terra.live.Session` (graph on) with a snapshot every `--every` frames, once per value of
`--sides` (metres; 1e6 reads every part as one box), one after the other in this process. Per
snapshot: the graph update's kind and reason, whether it was a sweep, its changed points, the
rebuilt area and the crops read (m^2), its seconds and the graph's places.

Usage: python benchmarks/bench_live_sweep.py --dataset large-sim --frames 1300 --every 100 --sides 96 1e6
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


def drive(dataset_path: Path, frames: int, every: int, side: float, work: Path | None) -> list[dict]:
    """One live drive with `build.update.max_crop_side` = side; one row per snapshot."""
    from terra.datasets.registry import open_dataset
    from terra.graph.config import BuildConfig
    from terra.live import Session

    dataset = open_dataset(dataset_path)
    build = BuildConfig.model_validate({"update": {"max_crop_side": side}})
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(dir=work) as tmp:
        session = Session(Path(tmp) / "live.terra", dataset.classes, name="sweep", build=build)
        for i in range(min(frames, len(dataset))):
            session.add(dataset[i])
            if (i + 1) % every:
                continue
            snap = session.snapshot()
            update = snap.graph_update
            graph = snap.bundle.graph
            rows.append(
                {
                    "frame": i + 1,
                    "graph_s": round(snap.seconds["graph"], 3),
                    "kind": update.get("kind"),
                    "reason": update.get("reason"),
                    "sweep": update.get("sweep"),
                    "changed_points": update.get("changed_points"),
                    "zone_m2": update.get("zone_area_m2"),
                    "crop_m2": update.get("crop_area_m2"),
                    "places": len(graph.places) if graph is not None else 0,
                }
            )
            print(side, json.dumps(rows[-1]), file=sys.stderr, flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--dataset", type=Path, required=True, help="a terra-folder from `terra sim`")
    parser.add_argument("--frames", type=int, default=1300)
    parser.add_argument("--every", type=int, default=100, help="frames between snapshots")
    parser.add_argument("--sides", type=float, nargs="+", default=[96.0, 1e6], help="max_crop_side values, metres")
    parser.add_argument("--work", type=Path, default=None, help="where the live bundles are written")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "live_sweep.json")
    args = parser.parse_args()
    sys.path.insert(0, str(HERE))
    from benchmarks.benchtable import report

    load = os.getloadavg()[0]
    runs = {str(side): drive(args.dataset, args.frames, args.every, side, args.work) for side in args.sides}
    table = []
    for i, row in enumerate(next(iter(runs.values()))):
        cells = "; ".join(
            f"side {side}: {r[i]['kind']}{' sweep' if r[i]['sweep'] else ''} {r[i]['graph_s']:.1f} s, "
            f"crops {r[i]['crop_m2'] or 0:,.0f} m^2"
            for side, r in runs.items()
        )
        table.append((f"update at frame {row['frame']}", cells, ""))
    result = {"dataset": str(args.dataset), "frames": args.frames, "every": args.every, "runs": runs}
    result.update(load_average_1min_at_start=load, cpus=os.cpu_count(), load_average_1min_at_end=os.getloadavg()[0])
    report(table, result, args.out)


if __name__ == "__main__":
    main()
