"""Issue 27 on real labels: `terra eval --ground-only` on real SemanticKITTI scans and their human
labels (tests/data/semantickitti: sequence 00 frames 0 and 2, sequence 07 frame 964, each cut to its
forward 60-degree wedge; sources in tests/data/README.md).

The sample is checked to be real (sizes, classes and instance ids of SemanticKITTI's labels, the
same points as the Patchwork++ sample of the same KITTI scan), and the scorer's precision, recall
and F1 are checked against scikit-learn's on the label files read here with numpy, and held to the
issue's target, F1 0.95 for each sequence of the sample (whole scans: 0.962 pooled,
benchmarks/RESULTS.md)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from terra.cli import run
from terra.eval.ground_segmentation import ground_table
from terra.eval.results import GroundTable
from terra.graph.ground import segment_ground

DATA = Path(__file__).resolve().parents[1] / "data"
SEQUENCES = DATA / "semantickitti" / "sequences"
SCANS = {"00": {"000000": 19_797, "000002": 19_417}, "07": {"000964": 18_265}}
"""Points kept of each scan."""
SHA256 = {
    "00/velodyne/000000.bin": "1a2831d5",
    "00/labels/000000.label": "2396f552",
    "00/velodyne/000002.bin": "94bf4637",
    "00/labels/000002.label": "16fd25ad",
    "07/velodyne/000964.bin": "7d410316",
    "07/labels/000964.label": "adc0b1c6",
}
"""First 8 hex digits of each kept file's sha256."""
GROUND = [40, 44, 48, 49, 60, 72]  # road, parking, sidewalk, other-ground, lane-marking, terrain
SEMANTIC_KITTI_IDS = {
    0,
    1,
    10,
    11,
    13,
    15,
    16,
    18,
    20,
    30,
    31,
    32,
    40,
    44,
    48,
    49,
    50,
    51,
    52,
    60,
    70,
    71,
    72,
    80,
    81,
    99,
}
SEMANTIC_KITTI_IDS |= set(range(252, 260))  # moving-car ... moving-other-vehicle


def read(seq: str, frame: str) -> tuple[np.ndarray, np.ndarray]:
    points = np.fromfile(SEQUENCES / seq / "velodyne" / f"{frame}.bin", dtype="<f4").reshape(-1, 4)
    labels = np.fromfile(SEQUENCES / seq / "labels" / f"{frame}.label", dtype="<u4")
    return points, labels


def test_the_sample_is_the_real_labelled_scans():
    for name, digest in SHA256.items():
        assert hashlib.sha256((SEQUENCES / name).read_bytes()).hexdigest()[:8] == digest, name
    for seq, frames in SCANS.items():
        assert sorted(p.stem for p in (SEQUENCES / seq / "velodyne").glob("*.bin")) == sorted(frames)
        for frame, n in frames.items():
            assert (SEQUENCES / seq / "velodyne" / f"{frame}.bin").stat().st_size == 16 * n
            assert (SEQUENCES / seq / "labels" / f"{frame}.label").stat().st_size == 4 * n
            points, labels = read(seq, frame)
            semantic, instance = labels & 0xFFFF, labels >> 16
            assert set(np.unique(semantic).tolist()) <= SEMANTIC_KITTI_IDS
            # a street scene: road, sidewalk, cars, buildings, vegetation, each with many points
            for cls in (40, 48, 10, 50, 70):
                assert np.count_nonzero(semantic == cls) > 300, (seq, frame, cls)
            # instance ids on things (cars), none on stuff (road)
            assert np.unique(instance[semantic == 10]).size >= 2
            assert not instance[semantic == 40].any()
            # an HDL-64E scan's forward wedge: ranges to beyond 50 m, remission in [0, 1]
            azimuth = np.degrees(np.arctan2(points[:, 1], points[:, 0]))
            assert np.abs(azimuth).max() <= 30.0
            assert np.hypot(points[:, 0], points[:, 1]).max() > 50.0
            assert points[:, 3].min() >= 0.0 and points[:, 3].max() <= 1.0
    # sequence 00 frame 0 is the scan patchwork-plusplus ships (tests/data/kitti holds every 12th
    # point of it): every one of those points inside the wedge is in the sample
    every12th = np.fromfile(DATA / "kitti" / "000000_every12th.bin", dtype="<f4").reshape(-1, 4)
    inside = every12th[np.abs(np.degrees(np.arctan2(every12th[:, 1], every12th[:, 0]))) <= 30.0]
    points, _ = read("00", "000000")
    rows = np.ascontiguousarray(points).view(np.dtype((np.void, 16))).ravel()
    wanted = np.ascontiguousarray(inside).view(np.dtype((np.void, 16))).ravel()
    assert len(inside) > 1000 and np.isin(wanted, rows).all()


@pytest.mark.parametrize("seq", sorted(SCANS))
def test_scores_on_real_labels_match_independent_counts(seq, capsys):
    from sklearn.metrics import f1_score, precision_score, recall_score

    truth_all, found_all = [], []
    for frame in sorted(SCANS[seq]):
        points, labels = read(seq, frame)
        semantic = labels & 0xFFFF
        keep = semantic > 1  # unlabeled (0) and outlier (1) are not scored
        truth_all.append(np.isin(semantic[keep], GROUND))
        found_all.append(segment_ground(points[:, :3])[keep])
    truth, found = np.concatenate(truth_all), np.concatenate(found_all)

    table = ground_table(SEQUENCES / seq)
    assert [s.scan for s in table.scans] == [f"{f}.bin" for f in sorted(SCANS[seq])]
    assert sum(s.scored for s in table.scans) == len(truth)
    precision, recall, f1 = table.pooled()
    assert precision == pytest.approx(precision_score(truth, found))
    assert recall == pytest.approx(recall_score(truth, found))
    assert f1 == pytest.approx(f1_score(truth, found))
    assert table.mean()[2] == pytest.approx(np.mean([f1_score(t, f) for t, f in zip(truth_all, found_all)]))
    assert f1 >= 0.95  # the target (00: 0.954, 07: 0.959 on these wedges)

    assert run(["eval", "--ground-only", str(SEQUENCES / seq), "--json", "-q"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert GroundTable.from_json(data).pooled() == pytest.approx(table.pooled())
