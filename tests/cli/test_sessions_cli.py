"""`terra map SESSION --into MAP [--initial-guess x,y,yaw]` and `terra info` through the command line, on
two terra folders of the simulated tiny campus, the second drive written in its own frame."""

from __future__ import annotations

import json

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.cli import run
from terra.geometry import invert_pose
from terra.mapping.align import pose_from_guess
from terra.mapping.sessions import SessionFrames, relative_error, session_list
from terra.sim.writer import write_dataset
from tests.live.test_session import FrameRange
from tests.mapping.fixtures import folder_digest

T_TRUE = pose_from_guess(50.0, -10.0, 90.0)


@pytest.fixture(scope="module")
def drives(tiny_campus, tmp_path_factory):
    """(first drive's folder, second drive's folder in its own frame, config without the global map)."""
    root = tmp_path_factory.mktemp("drives")
    first = write_dataset(FrameRange(tiny_campus, 0, 20), root / "first", progress=False)
    moved = SessionFrames(FrameRange(tiny_campus, 12, 32), invert_pose(T_TRUE))
    second = write_dataset(moved, root / "second", progress=False)
    config = root / "voxels.yaml"
    config.write_text("mapping:\n  fusion:\n    use_global_map: false\n")
    return first, second, config


def test_a_second_drive_joins_the_map_and_info_lists_both(drives, tmp_path, capsys):
    first, second, config = drives
    out = tmp_path / "campus.terra"
    assert run(["map", str(first), "--out", str(out), "-c", str(config), "-q"]) == 0
    capsys.readouterr()
    assert run(["map", str(second), "--into", str(out), "--initial-guess", "47,-7,84", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    session = summary["session"]
    assert session["session"] == 2 and session["frames"] == 20 and session["how"] == "initial guess + GICP"
    metres, degrees = relative_error(T_TRUE, np.asarray(session["T_map_session"]))
    assert metres < 0.05 and degrees < 0.05
    info = Bundle(out).model.components.map
    assert info is not None and len(session_list(list(info.sources or []))) == 2

    assert run(["info", str(out), "--no-verify"]) == 0
    text = capsys.readouterr().out
    assert "  sessions: 2" in text
    assert "    session 1: " in text and "defines the map frame" in text
    line = next(line for line in text.splitlines() if line.startswith("    session 2: "))
    assert "(20 frames, " in line and "x 50.00 m, y -10.00 m" in line and "yaw 90.00 deg" in line
    assert f"fitness {session['fitness']:.2f}, overlap {session['overlap']:.2f}" in line


def test_bad_joins_exit_2_with_one_line_and_the_map_untouched(drives, tmp_path, capsys):
    first, second, config = drives
    out = tmp_path / "campus.terra"
    assert run(["map", str(first), "--out", str(out), "-c", str(config), "-q"]) == 0
    before = folder_digest(out)
    cases = [
        (["map", str(second), "--into", str(out), "--initial-guess", "50,-10,270", "-q"], "cannot align the session"),
        (["map", str(first), "--into", str(out), "-q"], "already in the map"),
        (["map", str(second), "--into", str(out), "--initial-guess", "50,-10", "-q"], "expected x,y,yaw"),
        (["map", str(second), "--into", str(out), "--out", str(tmp_path / "x"), "-q"], "leave --out out"),
        (["map", str(second), "--out", str(tmp_path / "x"), "--initial-guess", "1,2,3", "-q"], "is for --into"),
        (["map", str(second), "--into", str(tmp_path / "none.terra"), "-q"], "no bundle to append to"),
    ]
    capsys.readouterr()
    for argv, expected in cases:
        assert run(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and expected in err, (argv, err)
    other = tmp_path / "other.yaml"
    other.write_text("mapping:\n  fusion:\n    voxel_size: 0.8\n    use_global_map: false\n")
    args = ["map", str(second), "--into", str(out), "--initial-guess", "47,-7,84", "-c", str(other), "-q"]
    assert run(args) == 2
    assert "mapping.fusion.voxel_size = 0.4, this run has 0.8" in capsys.readouterr().err
    assert folder_digest(out) == before
    assert not (tmp_path / "x").exists()


def test_get_changes_answers_as_terra_changes(drives, tmp_path, capsys):
    pytest.importorskip("fastapi")
    from fastapi.testclient import TestClient

    from terra.loaded import LoadedBundle
    from terra.serve.app import create_app
    from terra.serve.config import ServeConfig

    first, second, config = drives
    out = tmp_path / "campus.terra"
    assert run(["map", str(first), "--out", str(out), "-c", str(config), "-q"]) == 0
    assert run(["map", str(second), "--into", str(out), "--initial-guess", "47,-7,84", "-q"]) == 0
    capsys.readouterr()
    assert run(["changes", str(out), "--between", "1", "2", "--json"]) == 0
    expected = json.loads(capsys.readouterr().out)
    client = TestClient(create_app(LoadedBundle(out), settings=ServeConfig()))
    answer = client.get("/changes", params={"first": 1, "second": 2})
    assert answer.status_code == 200 and answer.json() == expected
    refused = client.get("/changes", params={"first": 1, "second": 3})
    assert refused.status_code == 400 and "the map has sessions 1 to 2" in refused.json()["error"]
