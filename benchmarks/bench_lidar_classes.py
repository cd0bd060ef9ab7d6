"""Can a LiDAR-only map tell its ground apart by class (issue 27)? Per-cell LiDAR intensity,
roughness and range against the human labels of real SemanticKITTI scans.

Each scan of `SEQ` (SemanticKITTI's layout: `velodyne/NAME.bin` x y z intensity float32,
`labels/NAME.label` uint32, the class in the low 16 bits) is cut to its labelled ground points
(road 40, parking 44, sidewalk 48, lane-marking 60, terrain 72; other-ground 49 left out: too few)
and put on 0.4 m cells (Terra's terrain grid) in the sensor frame; a cell with at least 3 such
points gets its features (mean intensity, the standard deviation of its heights, the log of its
mean range, metres) and its majority label. Two questions, each a balanced logistic regression
(scikit-learn) trained on every scan but one and scored on the one left out:
- paved (road, parking, sidewalk, lane-marking) against terrain (vegetation ground: grass, soil):
  "never on the grass";
- road (road, parking, lane-marking) against sidewalk: "on the sidewalk".
Scores: balanced accuracy (0.5 is chance) and F1 of the smaller class, per held-out scan.

Usage:
  python benchmarks/bench_lidar_classes.py SEQ [--out benchmarks/results/lidar_classes.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

CELL = 0.4  # metres: the terrain grid's cell
MIN_POINTS = 3
ROAD, PARKING, SIDEWALK, LANE_MARKING, TERRAIN = 40, 44, 48, 60, 72
FEATURES = {
    "intensity": [0],
    "roughness": [1],
    "intensity + roughness": [0, 1],
    "intensity + roughness + range": [0, 1, 2],
}
QUESTIONS = {
    "paved_vs_terrain": ([ROAD, PARKING, SIDEWALK, LANE_MARKING], [TERRAIN]),
    "road_vs_sidewalk": ([ROAD, PARKING, LANE_MARKING], [SIDEWALK]),
}


def scan_cells(scan: Path, first: list[int], second: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Features (C, 3) (mean intensity, height standard deviation metres, log(1 + mean range
    metres)) and whether the majority of the cell's points are of `second` (C,), for the cells of
    the scan's points labelled `first` or `second`."""
    points = np.fromfile(scan, dtype=np.float32).reshape(-1, 4).astype(np.float64)
    labels = np.fromfile(scan.parent.parent / "labels" / (scan.stem + ".label"), dtype=np.uint32) & 0xFFFF
    keep = np.isin(labels, first + second)
    points, labels = points[keep], labels[keep]
    ij = np.floor(points[:, :2] / CELL).astype(np.int64)
    _, cell, count = np.unique(ij, axis=0, return_inverse=True, return_counts=True)
    cell = cell.ravel()

    def mean(values: np.ndarray) -> np.ndarray:
        return np.bincount(cell, weights=values) / count

    z = mean(points[:, 2])
    rough = np.sqrt(np.maximum(mean(points[:, 2] ** 2) - z * z, 0.0))
    features = np.column_stack([mean(points[:, 3]), rough, np.log1p(mean(np.hypot(points[:, 0], points[:, 1])))])
    is_second = mean(np.isin(labels, second).astype(np.float64)) > 0.5
    enough = count >= MIN_POINTS
    return features[enough], is_second[enough]


def held_out_scores(data: dict[str, tuple[np.ndarray, np.ndarray]], columns: list[int]) -> dict[str, Any]:
    """Balanced accuracy and the second class's F1 on each scan, trained on the others."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.metrics import balanced_accuracy_score, f1_score

    out = {}
    for held, (x, y) in data.items():
        train_x = np.vstack([f[:, columns] for name, (f, _) in data.items() if name != held])
        train_y = np.concatenate([t for name, (_, t) in data.items() if name != held])
        if y.all() or not y.any() or train_y.all() or not train_y.any():
            out[held] = None  # one class only: nothing to score
            continue
        model = LogisticRegression(class_weight="balanced", max_iter=1000).fit(train_x, train_y)
        found = model.predict(x[:, columns])
        out[held] = {
            "balanced_accuracy": round(float(balanced_accuracy_score(y, found)), 3),
            "f1": round(float(f1_score(y, found)), 3),
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results" / "lidar_classes.json")
    args = parser.parse_args()
    scans = sorted((args.sequence / "velodyne").glob("*.bin"))
    if len(scans) < 2:
        sys.exit(f"{args.sequence}: expected at least two scans in velodyne/ with their labels/")
    result: dict[str, Any] = {
        "machine": f"{platform.node()} {platform.machine()} {platform.python_version()}",
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "argv": sys.argv[1:],
    }
    for question, (first, second) in QUESTIONS.items():
        data = {scan.stem: scan_cells(scan, first, second) for scan in scans}
        summary = {
            name: {
                "cells": len(y),
                "second_class_cells": int(y.sum()),
                "median_intensity_first_second": [round(float(np.median(x[~y, 0])), 3) if (~y).any() else None,
                                                  round(float(np.median(x[y, 0])), 3) if y.any() else None],
                "median_roughness_m_first_second": [round(float(np.median(x[~y, 1])), 4) if (~y).any() else None,
                                                    round(float(np.median(x[y, 1])), 4) if y.any() else None],
            }
            for name, (x, y) in data.items()
        }  # fmt: skip
        scores = {features: held_out_scores(data, columns) for features, columns in FEATURES.items()}
        result[question] = {"scans": summary, "held_out": scores}
        print(f"\n{question}")
        print("| features | " + " | ".join(data) + " |")
        print("|---" * (len(data) + 1) + "|")
        for features, per_scan in scores.items():
            cells = [f"{s['balanced_accuracy']:.3f} / {s['f1']:.3f}" if s else "-" for s in per_scan.values()]
            print(f"| {features} | " + " | ".join(cells) + " |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
