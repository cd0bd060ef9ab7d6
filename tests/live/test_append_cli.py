"""`terra map --append` through the command line: two folders of one drive give the map of the whole
drive, the graph built before is kept and reported stale, and wrong continuations are refused."""

from __future__ import annotations

from terra.bundle import Bundle
from terra.cli import run
from terra.sim.writer import write_dataset
from tests.live.test_session import FrameRange, map_files
from tests.mapping.fixtures import BoxScene, folder_digest


def test_append_two_folders_equals_the_whole_drive(tmp_path, capsys):
    scene = BoxScene()  # 6 frames, stamps 0..5 s
    whole = write_dataset(scene, tmp_path / "whole", format="terra-folder", progress=False)
    first = write_dataset(FrameRange(scene, 0, 3), tmp_path / "first", format="terra-folder", progress=False)
    second = write_dataset(FrameRange(scene, 3, 6), tmp_path / "second", format="terra-folder", progress=False)
    # Each folder ships the cloud of its own frames as a global map: accumulate from the scans instead,
    # as one map of the whole drive must (an append keeps the first map's geometry otherwise).
    voxels = tmp_path / "voxels.yaml"
    voxels.write_text("mapping:\n  fusion:\n    use_global_map: false\n")
    assert run(["map", str(whole), "--out", str(tmp_path / "whole.terra"), "-c", str(voxels), "-q"]) == 0
    out = tmp_path / "parts.terra"
    assert run(["map", str(first), "--out", str(out), "-c", str(voxels), "-q"]) == 0
    assert run(["map", str(second), "--out", str(out), "--append", "-q"]) == 0  # the bundle's own config
    assert map_files(out) == map_files(tmp_path / "whole.terra")
    bundle = Bundle(out)
    assert bundle.version == 2
    capsys.readouterr()
    assert run(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "version 2" in text and "sources: box-scene (frames 0.., 3); box-scene (frames 3.., 3)" in text

    before = folder_digest(out)
    assert run(["map", str(second), "--out", str(out), "--append", "-q"]) == 2
    assert "already in the map" in capsys.readouterr().err
    config = tmp_path / "other.yaml"
    config.write_text("mapping:\n  fusion:\n    voxel_size: 0.8\n    use_global_map: false\n")
    assert run(["map", str(whole), "--out", str(out), "--append", "--config", str(config), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "mapping.fusion.voxel_size = 0.4, this run has 0.8" in err
    assert run(["map", str(first), "--out", str(tmp_path / "none.terra"), "--append", "-q"]) == 2
    assert "no bundle to append to" in capsys.readouterr().err
    assert folder_digest(out) == before
