"""Boxes on real KITTI cars (issue 27): the 3D IoU of the box fitted to each labelled car's points
against its human label, for every frame of the KITTI object folders given.

Each labelled Car with at least `--min-points` scan points inside its label box gets the points of
its box grown by `--margin` metres (a mask that bleeds, onto the ground too), the ground height
from Terra's ground filter near it (terra.eval.kitti_boxes), and four boxes:
- seen: fit_object_boxes on those points, nothing more (the box spans what was seen);
- seen, no ground: the same without the points the ground filter calls ground (a segmentation
  that knows the ground);
- completed: with a size prior (`--prior`, length width height; default KITTI's mean car size,
  3.9 x 1.6 x 1.56 m, the anchor size detectors use, not measured on these frames) and the sensor
  at the origin of the scan's frame as the viewpoint (terra.tasks.boxes.complete_extent);
- completed, no ground.
Means are given over the cars with at least 100 points (the issue's target) and over all kept.

Usage:
  python benchmarks/bench_kitti_boxes.py FOLDER [FOLDER ...] [--min-points 30] [--margin 0.2]
      [--prior 3.9 1.6 1.56] [--out benchmarks/results/kitti_boxes.json]
A FOLDER holds velodyne/, label_2/ and calib/ (tests/data/kitti_object is one).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchtable import report  # noqa: E402

from terra.datasets.kitti_object import object_frames, read_object_frame  # noqa: E402
from terra.eval.kitti_boxes import car_cases, fitted_iou  # noqa: E402

VARIANTS = ("seen", "seen_no_ground", "completed", "completed_no_ground")
TARGET = 0.7


def measure(folders: list[Path], min_points: int, margin: float, prior: np.ndarray) -> list[dict]:
    """One row per kept car: where it is, how many points, its ground, and the IoU of each variant."""
    rows = []
    for folder in folders:
        for name in object_frames(folder):
            for case in car_cases(read_object_frame(folder, name), margin=margin, min_points=min_points):
                row = {
                    "folder": str(folder),
                    "frame": name,
                    "car": case.index,
                    "points_in_label": case.inside,
                    "range_m": round(float(np.hypot(*case.label.center[0, :2])), 2),
                    "ground_z_m": round(case.ground_z, 3),
                    "label_bottom_m": round(float(case.label.center[0, 2] - case.label.size[0, 2] / 2), 3),
                }
                for variant in VARIANTS:
                    options = {"min_extent": prior, "viewpoint": np.zeros(3)} if variant.startswith("completed") else {}
                    iou, box = fitted_iou(case, drop_ground=variant.endswith("no_ground"), **options)
                    row[f"iou_{variant}"] = round(iou, 4)
                    if variant == "completed" and len(box):
                        row["yaw_error_deg"] = round(_yaw_error(float(box.yaw[0]), float(case.label.yaw[0])), 2)
                rows.append(row)
    return rows


def _yaw_error(a: float, b: float) -> float:
    """Degrees between two box headings modulo 180 (a box is the same turned half a turn)."""
    return float(np.degrees(abs((a - b + np.pi / 2) % np.pi - np.pi / 2)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folders", nargs="+", type=Path)
    parser.add_argument("--min-points", type=int, default=30)
    parser.add_argument("--margin", type=float, default=0.2)
    parser.add_argument("--prior", type=float, nargs=3, default=[3.9, 1.6, 1.56])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results" / "kitti_boxes.json")
    args = parser.parse_args()
    load = os.getloadavg()[0]
    start = time.perf_counter()
    rows = measure(args.folders, args.min_points, args.margin, np.array(args.prior))
    seconds = time.perf_counter() - start
    print(f"{'frame':>8} {'car':>3} {'points':>6} {'range':>6} " + " ".join(f"{v:>19}" for v in VARIANTS))
    for r in rows:
        ious = " ".join(f"{r[f'iou_{v}']:19.3f}" for v in VARIANTS)
        print(f"{r['frame']:>8} {r['car']:3d} {r['points_in_label']:6d} {r['range_m']:6.1f} {ious}")
    big = [r for r in rows if r["points_in_label"] >= 100]
    means = {
        f"{v}_{k}": round(float(np.mean([r[f"iou_{v}"] for r in sel])), 4) if sel else None
        for v in VARIANTS
        for k, sel in (("100", big), ("all", rows))
    }
    table = [
        (f"cars kept (>= {args.min_points} points) / with >= 100 points", f"{len(rows)} / {len(big)}", ""),
        *[
            (f"mean 3D IoU {v}, >= 100 points / all kept", f"{means[f'{v}_100']} / {means[f'{v}_all']}", "")
            for v in VARIANTS
        ],
        ("target: completed, >= 100 points", f"{means['completed_100']}", f">= {TARGET}"),
        ("time", f"{seconds:.2f} s", ""),
    ]
    result = {
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
        "load_average_1min_at_start": load,
        "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
        "folders": [str(f) for f in args.folders],
        "min_points": args.min_points,
        "margin_m": args.margin,
        "prior_lwh_m": list(args.prior),
        "means": means,
        "cars": rows,
        "seconds": round(seconds, 3),
    }
    report(table, result, args.out)


if __name__ == "__main__":
    main()
