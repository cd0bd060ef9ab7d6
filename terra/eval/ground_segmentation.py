"""LiDAR ground segmentation scored against human labels: `terra eval --ground-only SEQUENCE`.

Each labelled scan of a SemanticKITTI sequence (velodyne/NNNNNN.bin, labels/NNNNNN.label) is
segmented on its own, in its sensor frame, by `terra.graph.ground.segment_ground` (the same filter
`terra build` runs on a fused map), and every point is judged ground or not against its label.

Ground is what a ground robot drives or walks on, in SemanticKITTI's ids: road (40), parking (44),
sidewalk (48), other-ground (49), terrain (72), and lane-marking (60, paint on the road), the
classes Patchwork++'s authors score as ground. Points labelled unlabeled (0) or outlier (1), and
points without a finite position, are left out of the scores (they are neither); everything else is
non-ground. Precision, recall and F1 are given pooled over every scored point and as the mean over
scans (Patchwork++ reports the mean of scans). A folder written by `terra sim --format
semantickitti` uses the same ids for its terrain.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from terra.datasets.folder_io import read_point_labels, read_velodyne_scan
from terra.datasets.semantickitti import sequence_dir
from terra.errors import TerraError
from terra.eval.results import GroundScan, GroundTable
from terra.progress import progress

GROUND_LABELS: dict[int, str] = {
    40: "road",
    44: "parking",
    48: "sidewalk",
    49: "other-ground",
    60: "lane-marking",
    72: "terrain",
}
"""SemanticKITTI ids scored as ground."""
UNSCORED_LABELS: dict[int, str] = {0: "unlabeled", 1: "outlier"}
"""SemanticKITTI ids left out of the scores."""

Segmenter = Callable[[np.ndarray], np.ndarray]
"""points (N, 3) metres -> (N,) bool, True for ground."""


def labelled_scans(path: Path) -> tuple[Path, list[tuple[Path, Path]]]:
    """The sequence folder under `path` (itself, or the one `sequences/NN/` of a dataset root) and its
    (scan, label file) pairs in scan order; TerraError naming the folder when there are none."""
    sequence = sequence_dir(path)
    pairs = [
        (scan, sequence / "labels" / f"{scan.stem}.label") for scan in sorted((sequence / "velodyne").glob("*.bin"))
    ]
    pairs = [(scan, label) for scan, label in pairs if label.is_file()]
    if not pairs:
        raise TerraError(
            f"{sequence}: no scan in velodyne/ has a label file in labels/ (NNNNNN.bin with NNNNNN.label); "
            "ground segmentation is scored against labels"
        )
    return sequence, pairs


def read_labelled_scan(scan: Path, label: Path) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) float32 (sensor frame, metres) and SemanticKITTI class ids (N,) of one scan."""
    points = read_velodyne_scan(scan)[:, :3]
    return points, (read_point_labels(label, len(points)) & 0xFFFF).astype(np.int64)


def score_scan(found: np.ndarray, labels: np.ndarray, finite: np.ndarray | None = None) -> tuple[int, int, int, int]:
    """(true positives, false positives, false negatives, points scored) of ground mask `found`
    (N,) against SemanticKITTI ids `labels` (N,), unscored ids and the points not `finite` (N,) left out."""
    scored = ~np.isin(labels, list(UNSCORED_LABELS))
    if finite is not None:
        scored &= np.asarray(finite, dtype=bool)
    truth = np.isin(labels, list(GROUND_LABELS))
    found = np.asarray(found, dtype=bool)
    tp = int(np.count_nonzero(found & truth & scored))
    fp = int(np.count_nonzero(found & ~truth & scored))
    fn = int(np.count_nonzero(~found & truth & scored))
    return tp, fp, fn, int(np.count_nonzero(scored))


def ground_table(
    path: Path,
    segment: Segmenter | None = None,
    method: str = "segment_ground",
    max_scans: int | None = None,
    show_progress: bool = False,
) -> GroundTable:
    """Score `segment` (default: terra.graph.ground.segment_ground with its defaults) on the labelled
    scans of the SemanticKITTI sequence at `path` (the first `max_scans` of them, all by default)."""
    if segment is None:
        from terra.graph.ground import segment_ground as segment
    sequence, pairs = labelled_scans(path)
    rows = []
    for scan, label in progress(
        pairs[:max_scans], desc="scoring scans", total=len(pairs[:max_scans]), enabled=show_progress
    ):
        points, labels = read_labelled_scan(scan, label)
        start = time.perf_counter()
        found = np.asarray(segment(points), dtype=bool)
        seconds = time.perf_counter() - start
        if found.shape != labels.shape:
            raise TerraError(f"{method} returned {found.shape[0]} flags for {len(labels)} points of {scan}")
        tp, fp, fn, scored = score_scan(found, labels, np.asarray(np.isfinite(points).all(axis=1)))
        rows.append(GroundScan(scan.name, len(points), scored, tp, fp, fn, seconds))
    return GroundTable(str(sequence), method, sorted(GROUND_LABELS), rows)
