"""Issue 27 on real data: boxes fitted to human-labelled KITTI cars (tests/data/kitti_object,
provenance in tests/data/README.md), scored by exact 3D IoU against the labels."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from terra.datasets.kitti_object import object_frames, read_object_frame
from terra.eval.kitti_boxes import CarCase, car_cases, fitted_iou

FOLDER = Path(__file__).resolve().parents[1] / "data" / "kitti_object"
CAR = np.array([3.9, 1.6, 1.56])  # KITTI's mean car size (length, width, height), a prior from outside these frames


@pytest.fixture(scope="module")
def cases() -> list[tuple[str, CarCase]]:
    out = []
    for name in object_frames(FOLDER):
        out += [(name, case) for case in car_cases(read_object_frame(FOLDER, name), min_points=30)]
    return out


def test_the_labels_land_on_the_points_in_the_lidar_frame(cases):
    """The calibration brings the labels onto their cars: the frames hold 14 cars with 30 or more
    points in their label box (6 with 100 or more), and the ground under each lies within 0.25 m
    of its label's bottom face."""
    assert len(cases) == 14
    assert sum(c.inside >= 100 for _, c in cases) == 6
    bottoms = np.array([c.label.center[0, 2] - c.label.size[0, 2] / 2 for _, c in cases])
    ground = np.array([c.ground_z for _, c in cases])
    assert np.all(np.abs(ground - bottoms) < 0.25)


def test_a_size_prior_and_the_viewpoint_complete_real_partial_cars(cases):
    """Boxes of what is seen cover about half of the labelled cars of the frames the fitting was
    chosen on (mean 3D IoU 0.56 for their 3 cars with 100 or more points, 0.54 over their 8);
    completed to KITTI's mean car size away from the sensor (at the origin of the scan's frame),
    they reach 0.74 and 0.75. On frame 000114, which took no part in any choice, the 3 cars with
    100 or more points reach 0.78 (0.76 seen). A short car seen whole is grown past its length
    (000114's first, 3.4 m long: 0.75 seen, 0.64 completed), the prior's known cost. The bottoms
    sit on the ground: within 0.25 m of the labels' bottom faces."""
    held_out = np.array([name == "000114" for name, _ in cases])
    big = np.array([c.inside >= 100 for _, c in cases])
    seen = np.array([fitted_iou(c)[0] for _, c in cases])
    done, boxes = zip(*(fitted_iou(c, min_extent=CAR, viewpoint=np.zeros(3)) for _, c in cases))
    done = np.array(done)
    chosen_on = ~held_out
    assert seen[big & chosen_on].mean() == pytest.approx(0.563, abs=0.01)
    assert done[big & chosen_on].mean() > 0.72 and done[chosen_on].mean() > 0.74
    assert np.all(done[chosen_on] >= seen[chosen_on] - 0.02)  # no car of these frames gets worse
    assert done[big & held_out].mean() > 0.75 and done[big].mean() > 0.74
    assert done[held_out][0] == pytest.approx(0.640, abs=0.01) and seen[held_out][0] == pytest.approx(0.747, abs=0.01)
    bottoms = np.array([b.center[0, 2] - b.size[0, 2] / 2 for b in boxes])
    labels = np.array([c.label.center[0, 2] - c.label.size[0, 2] / 2 for _, c in cases])
    assert np.all(np.abs(bottoms - labels) < 0.25)


def test_kitti_object_folders_fail_with_one_clear_line(tmp_path):
    from terra.errors import TerraError

    with pytest.raises(TerraError, match="no KITTI object frame"):
        object_frames(tmp_path)
    for sub in ("velodyne", "label_2", "calib"):
        (tmp_path / sub).mkdir()
    (tmp_path / "velodyne" / "000000.bin").write_bytes(np.zeros(6, np.float32).tobytes())  # 1.5 points
    (tmp_path / "label_2" / "000000.txt").write_text((FOLDER / "label_2" / "000002.txt").read_text())
    (tmp_path / "calib" / "000000.txt").write_text("R0_rect: 1 0 0 0 1 0 0 0 1\n")
    assert object_frames(tmp_path) == ["000000"]
    with pytest.raises(TerraError, match="not x y z reflectance quadruples"):
        read_object_frame(tmp_path, "000000")
    (tmp_path / "velodyne" / "000000.bin").write_bytes(np.zeros(8, np.float32).tobytes())
    with pytest.raises(TerraError, match="no Tr_velo_to_cam line"):
        read_object_frame(tmp_path, "000000")
