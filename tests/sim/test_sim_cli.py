"""`terra sim`: same preset and seed give the same bytes; bad input gives one line, exit code 2 and
leaves nothing behind."""

import hashlib

import numpy as np
import pytest

from terra.cli import run
from terra.datasets import open_dataset

FORMATS = ("terra-folder", "semantickitti")


def sim(out, *extra):
    return run(["sim", "--preset", "tiny", "--seed", "0", "--max-frames", "3", "--out", str(out), "--quiet", *extra])


def file_hashes(root):
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def first_runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("sim-cli")
    for fmt in FORMATS:
        assert sim(root / fmt, "--format", fmt) == 0
    return root


@pytest.mark.parametrize("fmt", FORMATS)
def test_same_seed_same_bytes(first_runs, tmp_path, fmt):
    assert sim(tmp_path / "again", "--format", fmt) == 0
    first, again = file_hashes(first_runs / fmt), file_hashes(tmp_path / "again")
    assert len(first) > 20 and "world.png" in first and "ground_truth/objects.json" in first
    assert first == again


def test_written_dataset_reads_back_as_simulated(first_runs, tiny_campus):
    """Both formats hold the simulator's frames: the same points, labels and pose."""
    expected = tiny_campus[2]
    for fmt in FORMATS:
        got = open_dataset(first_runs / fmt)[2]
        np.testing.assert_array_equal(got.points, expected.points)
        np.testing.assert_array_equal(got.point_labels, expected.point_labels)
        np.testing.assert_array_equal(got.point_instances, expected.point_instances)
        np.testing.assert_allclose(got.T_map_lidar, expected.T_map_lidar, atol=1e-12)
        np.testing.assert_array_equal(got.cameras[0].semantic, expected.cameras[0].semantic)


def leftovers(folder):
    return sorted(p.name for p in folder.iterdir())


def error_line(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("terra: error: "), err
    return err[0]


@pytest.mark.parametrize(
    "args, message",
    [
        (["--preset", "gigantic"], "unknown preset 'gigantic'; expected one of: tiny, small, campus, large, huge"),
        (
            ["--format", "kitti360"],
            "unknown format 'kitti360'; expected one of: terra-folder, semantickitti, kitti-raw",
        ),
    ],
)
def test_unknown_preset_or_format(tmp_path, capsys, args, message):
    code = run(["sim", "--out", str(tmp_path / "out"), "--quiet", *args])
    assert code == 2 and message in error_line(capsys)
    assert leftovers(tmp_path) == []


def test_a_foreign_folder_is_kept_and_a_dataset_needs_overwrite(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    for extra in ((), ("--overwrite",)):  # a folder Terra did not write is never replaced
        assert sim(out, *extra) == 2
        line = error_line(capsys)
        assert "is not a dataset Terra wrote" in line and "notes.txt" in line and "--overwrite" not in line
        assert leftovers(out) == ["notes.txt"] and leftovers(tmp_path) == ["out"]
    data = tmp_path / "data"
    assert sim(data) == 0
    (data / "stale.txt").write_text("from an earlier run")
    assert sim(data) == 2
    assert "folder exists and is not empty (pass --overwrite to replace it)" in error_line(capsys)
    assert sim(data, "--overwrite") == 0
    assert "stale.txt" not in leftovers(data) and "world.png" in leftovers(data)
    assert sorted(leftovers(tmp_path)) == ["data", "out"]


@pytest.mark.parametrize(
    "yaml_text, field",
    [
        ("sim:\n  lidar:\n    beams: 0\n", "lidar.beams"),
        ("sim:\n  lidar:\n    vertical_fov_deg: [10, -10]\n", "vertical_fov_deg must satisfy"),
        ("sim:\n  lidar:\n    min_range: 50\n    max_range: 20\n", "max_range must exceed min_range"),
        ("sim:\n  cameras:\n    - dist: [0.1, 0.2, 0.3]\n", "supported lengths: 0, 4, 5, 8, 12, 14"),
        ("sim:\n  cameras:\n    - dist: [-0.5, 0, 0, 0, 0]\n", "cannot be inverted over the 640x480 image"),
        ("sim:\n  cameras:\n    - cx: 700\n", "principal point (700.0, 239.5) must lie inside"),
        ("sim:\n  cameras:\n    - name: a\n    - name: a\n", "camera names must be unique"),
        ("sim:\n  cameras:\n    - fx: -3\n", "cameras.0.fx"),
        ("sim:\n  lidar:\n    colums: 512\n", "colums"),
        ("sim:\n  lidar: [1, 2\n", "not valid YAML"),
    ],
)
def test_invalid_sensor_configuration(tmp_path, capsys, yaml_text, field):
    config = tmp_path / "sensors.yaml"
    config.write_text(yaml_text)
    assert sim(tmp_path / "out", "--config", str(config)) == 2
    line = error_line(capsys)
    assert str(config) in line and field in line
    assert leftovers(tmp_path) == ["sensors.yaml"]


def test_failure_while_writing_leaves_nothing(tmp_path, capsys, monkeypatch):
    """A crash in the middle of writing frames removes the partial folder."""
    import terra.datasets.terra_folder as terra_folder

    calls = []
    real = terra_folder.write_rgb

    def failing(path, image, *args, **kwargs):
        calls.append(path)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        return real(path, image, *args, **kwargs)

    monkeypatch.setattr(terra_folder, "write_rgb", failing)
    assert sim(tmp_path / "out") == 2
    assert "out: cannot write the dataset (No space left on device); the disk is full" in error_line(capsys)
    assert len(calls) == 2 and leftovers(tmp_path) == []


def test_world_picture(first_runs):
    from PIL import Image

    from terra.viz.world import scale_bar_length

    with Image.open(first_runs / "terra-folder" / "world.png") as im:
        assert im.format == "PNG" and im.width > im.height > 600 and not im.info.get("Software")
    # Round scale bars near a fifth of the width: tiny 60 m, small 150 m, campus 500 m, large 2 km.
    assert [scale_bar_length(e) for e in (60.0, 150.0, 500.0, 2000.0)] == [10.0, 20.0, 100.0, 200.0]
