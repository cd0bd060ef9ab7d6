"""`terra eval --ground-only SEQUENCE`: LiDAR ground segmentation scored against SemanticKITTI labels.

The scores are checked against counts worked by hand and against scikit-learn's metrics on the label
files read independently with numpy; the default segmentation must reach the issue's F1 of 0.95 on a
simulated sequence written in SemanticKITTI's layout (real labelled scans: test_ground_real_labels.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from terra.cli import run
from terra.eval.ground_segmentation import ground_table, score_scan
from terra.eval.results import GroundTable


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    root = tmp_path_factory.mktemp("sk") / "data"
    assert (
        run(["sim", "--preset", "tiny", "--max-frames", "3", "--format", "semantickitti", "--out", str(root), "-q"])
        == 0
    )
    return root / "sequences" / "00"


def test_scan_counts_by_hand():
    # road, sidewalk, unlabeled, outlier, car, building, terrain, lane-marking
    labels = np.array([40, 48, 0, 1, 10, 50, 72, 60])
    found = np.array([True, False, True, True, True, False, True, True])
    # scored: all but 0 and 1; ground found: 40, 72, 60 (tp 3); 48 missed (fn 1); the car found (fp 1)
    assert score_scan(found, labels) == (3, 1, 1, 6)
    # A point without a position (a NaN return) is not scored: here the road point.
    finite = np.array([False, True, True, True, True, True, True, True])
    assert score_scan(found, labels, finite) == (2, 1, 1, 5)


def test_scans_with_nan_returns_are_segmented_and_scored(sequence, tmp_path):
    """A scan whose sensor wrote NaN for missing returns (as some drivers do): those points are never
    ground and never scored; the others score as in the scan without them."""
    from terra.graph.ground import segment_ground

    points = np.fromfile(sequence / "velodyne" / "000000.bin", dtype="<f4").reshape(-1, 4)
    labels = np.fromfile(sequence / "labels" / "000000.label", dtype="<u4")
    holes = points.copy()
    holes[::50, :3] = np.nan
    seq = tmp_path / "seq"
    (seq / "velodyne").mkdir(parents=True)
    (seq / "labels").mkdir()
    holes.astype("<f4").tofile(seq / "velodyne" / "000000.bin")
    labels.astype("<u4").tofile(seq / "labels" / "000000.label")
    found = segment_ground(holes[:, :3])
    assert not found[::50].any()
    (scan,) = ground_table(seq).scans
    kept = np.isfinite(holes[:, 0])
    expected = score_scan(segment_ground(holes[kept, :3]), labels[kept] & 0xFFFF)
    assert (scan.tp, scan.fp, scan.fn, scan.scored) == expected


def test_scores_against_independent_counts(sequence):
    from sklearn.metrics import f1_score, precision_score, recall_score

    low = lambda points: points[:, 2] < -1.2  # noqa: E731 - a plain height threshold, sensor frame
    table = ground_table(sequence, segment=low, method="z < -1.2")
    assert [s.scan for s in table.scans] == ["000000.bin", "000001.bin", "000002.bin"]
    truth_all, found_all = [], []
    for name in ("000000", "000001", "000002"):
        points = np.fromfile(sequence / "velodyne" / f"{name}.bin", dtype="<f4").reshape(-1, 4)
        labels = np.fromfile(sequence / "labels" / f"{name}.label", dtype="<u4") & 0xFFFF
        keep = labels > 1
        truth_all.append(np.isin(labels[keep], [40, 44, 48, 49, 60, 72]))
        found_all.append(points[keep, 2] < -1.2)
    truth, found = np.concatenate(truth_all), np.concatenate(found_all)
    precision, recall, f1 = table.pooled()
    assert precision == pytest.approx(precision_score(truth, found))
    assert recall == pytest.approx(recall_score(truth, found))
    assert f1 == pytest.approx(f1_score(truth, found))
    assert sum(s.scored for s in table.scans) == len(truth)
    per_scan = [f1_score(t, f) for t, f in zip(truth_all, found_all)]
    assert table.mean()[2] == pytest.approx(np.mean(per_scan))


def test_default_segmentation_reaches_the_target(sequence, capsys):
    assert run(["eval", "--ground-only", str(sequence.parent.parent), "--json", "-q"]) == 0
    data = json.loads(capsys.readouterr().out)
    table = GroundTable.from_json(data)
    assert GroundTable.from_json(table.to_json()) == table
    assert len(table.scans) == 3 and table.method == "segment_ground"
    assert data["pooled"]["f1"] >= 0.95 and data["mean_per_scan"]["f1"] >= 0.95
    assert run(["eval", "--ground-only", str(sequence), "--max-images", "1", "-q"]) == 0
    text = capsys.readouterr().out
    assert "1 labelled scan," in text and "pooled:" in text


def test_bad_input_is_one_line(sequence, tmp_path, capsys):
    empty = tmp_path / "seq"
    (empty / "velodyne").mkdir(parents=True)
    (empty / "velodyne" / "000000.bin").write_bytes(np.zeros(8, "<f4").tobytes())
    assert run(["eval", "--ground-only", str(empty), "-q"]) == 2
    assert "no scan in velodyne/ has a label file" in capsys.readouterr().err
    (empty / "labels").mkdir()
    (empty / "labels" / "000000.label").write_bytes(np.zeros(3, "<u4").tobytes())
    assert run(["eval", "--ground-only", str(empty), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert "000000.label: 3 labels for 2 points" in err and len(err.splitlines()) == 1
    assert run(["eval", "--ground-only", "--terrain-only", str(sequence), "-q"]) == 2
    assert "give one of them" in capsys.readouterr().err
