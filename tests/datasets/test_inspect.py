"""`terra inspect` on the folder formats: what it prints is what the files state (the hand-built
dataset's exact calibrations with distortion, two cameras) and what would be skipped."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from terra.cli import run
from terra.sim.writer import write_dataset
from tests.datasets.fixtures import STAMPS, HandDataset, calibrations


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    root = tmp_path_factory.mktemp("inspect")
    return {
        fmt: write_dataset(HandDataset(), root / fmt, format=fmt, progress=False)
        for fmt in ("terra-folder", "semantickitti")
    }


@pytest.mark.parametrize("fmt", ["terra-folder", "semantickitti"])
def test_inspect_json_states_the_calibrations_as_written(capsys, written, fmt):
    assert run(["inspect", str(written[fmt]), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == fmt and info["frames"] == len(STAMPS)
    assert info["time_span"] == pytest.approx([STAMPS[0], STAMPS[-1]])
    for cam, truth in zip(info["cameras"], calibrations()):
        assert (cam["name"], cam["width"], cam["height"], cam["model"]) == (
            truth.name,
            truth.width,
            truth.height,
            truth.model,
        )
        np.testing.assert_array_equal(cam["K"], truth.K)
        np.testing.assert_array_equal(cam["dist"], truth.dist)
        np.testing.assert_array_equal(cam["T_cam_lidar"], truth.T_cam_lidar)
    assert run(["inspect", str(written[fmt])]) == 0
    text = capsys.readouterr().out
    assert f"({fmt}): {len(STAMPS)} frames" in text and "T_cam_lidar" in text


def test_inspect_counts_pose_files_that_will_be_skipped(capsys, written, tmp_path):
    folder = shutil.copytree(written["terra-folder"], tmp_path / "f")
    next((folder / "lidar_pc").glob("*.npy")).unlink()  # the first scan's LiDAR file is gone
    assert run(["inspect", str(folder), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"] == len(STAMPS) - 1 and info["skipped"] == {"scans_unaligned": 1}
    assert "nearest LiDAR scan is" in info["skipped_notes"]["scans_unaligned"]
