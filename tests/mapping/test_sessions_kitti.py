"""Two KITTI raw drives of one place join on their OXTS: the first visit of the simulated tiny campus and
its revisit, each written as a KITTI raw drive (`terra sim --format kitti-raw`, OXTS from the world's poses
with the world's origin at one place on the Earth). Each map frame starts at its drive's first IMU position,
x east, y north; the join takes the pose between the two drives' anchors as its prior, and the transform it
finds is the one between the two first positions."""

from __future__ import annotations

import json

import numpy as np

from terra.bundle import Bundle
from terra.cli import run
from terra.datasets.kitti_raw_writer import kitti_rig
from terra.mapping.sessions import relative_error, session_list
from terra.sim import simulate
from terra.sim.config import RevisitConfig, SimConfig

FRAMES = 30


def test_two_kitti_drives_join_from_their_oxts(tmp_path, capsys):
    for name, extra in (("first", []), ("second", ["--revisit"])):
        command = ["sim", "--preset", "tiny", "--max-frames", str(FRAMES), "--format", "kitti-raw", *extra]
        assert run([*command, "--out", str(tmp_path / name), "-q"]) == 0
    voxels = tmp_path / "voxels.yaml"
    voxels.write_text("mapping:\n  fusion:\n    use_global_map: false\n")
    out = tmp_path / "campus.terra"
    assert run(["map", str(tmp_path / "first"), "--out", str(out), "-c", str(voxels), "-q"]) == 0
    assert run(["map", str(tmp_path / "second"), "--into", str(out), "-q"]) == 0
    session = session_list(Bundle(out).model.components.map.sources or [])[1]  # pyright: ignore[reportOptionalMemberAccess]
    assert session["how"] == "GNSS prior + GICP"
    # Both map frames are the world's axes moved to each drive's first IMU position.
    first = simulate("tiny", 0, _frames(SimConfig()))
    second = simulate("tiny", 0, _frames(SimConfig(revisit=RevisitConfig())))
    T_velo_imu = kitti_rig()[1]
    shift = (second.gt_T_map_lidar(0) @ T_velo_imu)[:3, 3] - (first.gt_T_map_lidar(0) @ T_velo_imu)[:3, 3]
    truth = np.eye(4)
    truth[:3, 3] = shift
    metres, degrees = relative_error(truth, np.asarray(session["T_map_session"]))
    assert metres < 0.05 and degrees < 0.05
    capsys.readouterr()
    assert run(["info", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["map"]["wgs84_anchor"]["source"].startswith("kitti-raw OXTS")


def _frames(config: SimConfig) -> SimConfig:
    return config.model_copy(update={"route": config.route.model_copy(update={"max_frames": FRAMES})})
