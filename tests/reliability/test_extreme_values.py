"""Finite but extreme values in a dataset's geometry that reached numeric code as infinity and
escaped as tracebacks: each is now one line, exit 2, nothing written.

- a /tf rotation of components 1e200: finite, but its length overflows to infinity (scipy then
  found a "zero norm" and raised ValueError);
- a KITTI raw `calib_imu_to_velo.txt` translation of 1e308 metres (finite, so the finiteness check
  passed; the points reached DBSCAN as infinity), and the same in `calib_velo_to_cam.txt` and in
  SemanticKITTI's `Tr`.
"""

from __future__ import annotations

import re
import shutil

import pytest

from tests.reliability.fuzzing import cli


def test_a_quaternion_whose_length_overflows_is_one_line(tmp_path):
    import numpy as np

    from tests.datasets.fixtures_ros import factory_for, scan, write_test_bag

    f = factory_for()
    message = f.tf([(0, "map", "velodyne", np.eye(4))])
    q = message.transforms[0].transform.rotation
    q.x, q.y, q.z, q.w = 1e200, 1e200, 0.0, 1e200
    bag = write_test_bag(
        tmp_path / "bag",
        [
            ("/tf", "tf2_msgs/msg/TFMessage", 0, message),
            ("/points", "sensor_msgs/msg/PointCloud2", 0, f.pointcloud2(0, "velodyne", scan())),
        ],
    )
    config = tmp_path / "c.yaml"
    config.write_text("dataset:\n  poses: tf\n  map_frame: map\n")
    for argv in (["inspect", bag], ["map", bag, "--out", tmp_path / "m.terra", "-q", "--config", config]):
        code, _, err = cli(argv)
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and "rotation quaternion has length inf" in lines[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "c.yaml"]


@pytest.mark.parametrize(
    "dataset,name,key",
    [
        ("kitti-raw", "calib_imu_to_velo.txt", "T"),
        ("kitti-raw", "calib_velo_to_cam.txt", "T"),
        ("semantickitti", "calib.txt", "Tr"),
    ],
)
def test_a_calibration_translation_of_1e308_metres_is_one_line(reliability_seeds, tmp_path, dataset, name, key):
    data = shutil.copytree(reliability_seeds.datasets[dataset], tmp_path / "data")
    calib = next(data.rglob(name))
    lines = calib.read_text().splitlines()
    row = next(k for k, line in enumerate(lines) if line.startswith(f"{key}:"))
    numbers = lines[row].split()[1:]
    numbers[3 if key == "Tr" else 0] = "1e308"  # Tr is [R | t] row-major: t_x is its 4th number
    lines[row] = f"{key}: " + " ".join(numbers)
    calib.write_text("\n".join(lines) + "\n")
    code, _, err = cli(["map", data, "--out", tmp_path / "m.terra", "-q"])
    out = err.strip().splitlines()
    assert code == 2 and len(out) == 1, err[-2000:]
    assert re.search(rf"{re.escape(name)}.*{key}('s translation)? must be within .* got 1e\+308 m", out[0]), out[0]
    assert not (tmp_path / "m.terra").exists()
