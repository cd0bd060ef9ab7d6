"""Sources without poses of their own (a KITTI odometry sequence without poses.txt, a KITTI raw
drive without OXTS): `terra map --poses odometry` maps them, where the source's own pose check
stopped it before; `terra inspect` describes them and says how to map them."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from terra.cli import run
from terra.sim.writer import write_dataset
from tests.datasets.fixtures import STAMPS, HandDataset
from tests.datasets.test_datasets_kitti_raw import write_drive


@pytest.fixture
def sequence(tmp_path):
    """A KITTI odometry sequence written from the hand-built dataset, poses.txt removed."""
    root = write_dataset(HandDataset(), tmp_path / "kitti", format="semantickitti", progress=False)
    seq = root / "sequences" / "00"
    (seq / "poses.txt").unlink()
    return seq


@pytest.fixture
def drive(tmp_path):
    """A KITTI raw drive (three scans, image_02) without its oxts/ folder."""
    drive = write_drive(tmp_path / "raw")
    shutil.rmtree(drive / "oxts")
    return drive


@pytest.mark.parametrize(("source", "refusal"), [("sequence", "no poses.txt"), ("drive", "no OXTS packet")])
def test_map_with_poses_odometry_maps_a_source_without_poses(request, tmp_path, capsys, source, refusal):
    path = request.getfixturevalue(source)
    out = tmp_path / "out.terra"
    assert run(["map", str(path), "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert (
        len(err.splitlines()) == 1
        and refusal in err
        and err.endswith("map with --poses odometry (or dataset.poses: odometry) to compute poses from the scans")
    )
    assert not out.exists()
    assert run(["map", str(path), "--out", str(out), "--poses", "odometry", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    frames = len(STAMPS) if source == "sequence" else 3
    assert summary["pose_source"] == "odometry (KISS-ICP)" and summary["odometry"]["scans"] == frames
    assert summary["odometry"]["errors"] is None  # no reference poses to measure against
    assert (out / "manifest.json").is_file()
    poses = np.loadtxt(tmp_path / "out_poses_kitti.txt").reshape(-1, 3, 4)
    assert len(poses) == frames and np.isfinite(poses).all()
    np.testing.assert_allclose(poses[0], np.eye(4)[:3], atol=1e-12)  # the first scan's frame is the map's


@pytest.mark.parametrize("source", ["sequence", "drive"])
def test_inspect_says_there_are_no_poses_and_how_to_map(request, capsys, source):
    path = request.getfixturevalue(source)
    assert run(["inspect", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"] == (len(STAMPS) if source == "sequence" else 3)
    assert info["pose_source"].startswith("no poses: map with --poses odometry (")
    assert run(["inspect", str(path), "--poses", "odometry"]) == 0
    assert "  poses: odometry (KISS-ICP)" in capsys.readouterr().out


def test_kitti_raw_odometry_keeps_oxts_as_the_reference(tmp_path, capsys):
    """With OXTS present, `--poses odometry` maps every scan and measures its error against OXTS."""
    drive = write_drive(tmp_path / "raw")
    out = tmp_path / "odo.terra"
    assert run(["map", str(drive), "--out", str(out), "--poses", "odometry", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["odometry"]["scans"] == 3 and summary["odometry"]["errors"] is not None
