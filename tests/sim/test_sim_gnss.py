"""The simulator's GNSS receiver (`sim.gnss`, `terra sim --gnss`): fixes of the true positions with the
configured noise, an anchor of each visit's own frame that puts the world where the simulator has it, and
the same anchor read back from a written terra-folder's gnss.csv."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terra.cli import run
from terra.datasets.base import GeoreferencedDataset
from terra.datasets.registry import open_dataset
from terra.datasets.terra_folder import TerraFolderDataset
from terra.mapping.sessions import relative_error
from terra.schemas import Wgs84Anchor
from terra.sim.config import GnssConfig, RevisitConfig, SimConfig
from terra.sim.dataset import simulate
from terra.sim.revisit import session_pose
from terra.wgs84 import MapToWgs84, pose_between

RECEIVER = GnssConfig(lat=47.3769, lon=8.5417, alt=408.0, noise_m=2.0)
WORLD = Wgs84Anchor(lat=RECEIVER.lat, lon=RECEIVER.lon, alt=RECEIVER.alt)  # the world frame, +x east


@pytest.fixture(scope="module")
def visits():
    first = simulate("tiny", 0, SimConfig(gnss=RECEIVER))
    second = simulate("tiny", 0, SimConfig(gnss=RECEIVER, revisit=RevisitConfig(frame=(50.0, -10.0, 90.0))))
    return first, second


def test_fixes_scatter_by_the_configured_noise_around_the_true_positions(visits):
    first, _ = visits
    fixes = first.gnss_fixes()
    assert fixes is not None and len(fixes) == len(first)
    true = np.stack([first.gt_T_map_lidar(i)[:3, 3] for i in range(len(first))])
    error = MapToWgs84(WORLD).map_points(np.column_stack([fixes.lon, fixes.lat, fixes.alt])) - true
    horizontal = error[:, :2].std(axis=0)
    assert np.all(np.abs(horizontal - 2.0) < 0.5) and np.all(np.abs(error[:, :2].mean(axis=0)) < 0.5)


def test_each_visit_is_anchored_where_the_simulator_put_its_frame(visits):
    first, second = visits
    map_anchor = Wgs84Anchor.model_validate(first.wgs84_anchor())
    session_anchor = Wgs84Anchor.model_validate(second.wgs84_anchor())
    # The first visit reports world poses: its anchor is the world's, within the fixes' noise.
    metres, degrees = relative_error(np.eye(4), pose_between(WORLD, map_anchor))
    assert metres < 1.0 and degrees < 1.0
    metres, degrees = relative_error(session_pose(second.config.revisit), pose_between(map_anchor, session_anchor))
    assert metres < 1.5 and degrees < 1.5


def test_a_written_folder_keeps_the_fixes_and_reads_the_same_anchor(tmp_path):
    out = tmp_path / "drive"
    assert run(["sim", "--preset", "tiny", "--max-frames", "12", "--gnss", "1.0", "--out", str(out), "-q"]) == 0
    assert (out / "gnss.csv").is_file()
    config = SimConfig(gnss=RECEIVER.model_copy(update={"noise_m": 1.0}))
    config = config.model_copy(update={"route": config.route.model_copy(update={"max_frames": 12})})
    expected = simulate("tiny", 0, config).wgs84_anchor()
    found = TerraFolderDataset(out).wgs84_anchor()
    assert expected is not None and found is not None
    assert math.isclose(found["lat"], expected["lat"], abs_tol=1e-7)
    assert math.isclose(found["lon"], expected["lon"], abs_tol=1e-7)
    assert math.isclose(found["yaw_deg"], expected["yaw_deg"], abs_tol=1e-3)


@pytest.mark.parametrize("format", ["rosbag1", "rosbag2"])
def test_a_bag_carries_the_fixes_as_navsatfix_and_reads_the_same_anchor(tmp_path, format):
    out = tmp_path / format
    command = ["sim", "--preset", "tiny", "--max-frames", "12", "--gnss", "1.0", "--format", format]
    assert run([*command, "--out", str(out), "-q"]) == 0
    config = SimConfig(gnss=RECEIVER.model_copy(update={"noise_m": 1.0}))
    config = config.model_copy(update={"route": config.route.model_copy(update={"max_frames": 12})})
    expected = simulate("tiny", 0, config).wgs84_anchor()
    bag = open_dataset(out)
    assert isinstance(bag, GeoreferencedDataset)
    found = bag.wgs84_anchor()
    assert expected is not None and found is not None and found["source"].endswith("(/gnss/fix)")
    for key, tolerance in (("lat", 1e-7), ("lon", 1e-7), ("alt", 1e-3), ("yaw_deg", 1e-3)):
        assert math.isclose(found[key], expected[key], abs_tol=tolerance)


def test_gnss_is_refused_for_formats_without_a_place_for_it(tmp_path):
    out = tmp_path / "kitti"
    assert run(["sim", "--preset", "tiny", "--gnss", "2", "--format", "semantickitti", "--out", str(out), "-q"]) == 2
    assert not out.exists() or not any(out.iterdir())
