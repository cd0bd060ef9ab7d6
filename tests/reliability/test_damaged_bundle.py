"""Every file a command reads from a bundle is checked against the manifest's SHA-256 (once per file
and process): one flipped byte makes a query fail with one line naming the file, not answer from
damaged data."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.graph.fixtures import copy_bundle
from tests.reliability.fuzzing import cli


def flip_last_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[-1] ^= 0x01  # same size: only the checksum can tell
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("damaged", ["map/points.npy", "graph/place_embedding.npy", "graph/scene_graph.json"])
def test_a_query_on_a_damaged_file_fails_with_one_line(tiny_graph_bundle, tmp_path, damaged):
    bundle = copy_bundle(tiny_graph_bundle, tmp_path / "copy.terra")
    assert cli(["find", bundle, "find the bench", "--json"])[0] == 0
    path = bundle / damaged
    flip_last_byte(path)
    code, out, err = cli(["find", bundle, "find the bench", "--method", "3dsg", "--json"])
    assert code == 2 and out == "", (code, out, err)
    assert err.strip().splitlines() == [
        f"terra: error: {path}: checksum mismatch: the file is damaged (corrupt bundle; rebuild it)"
    ], err


def test_a_file_is_hashed_once_per_process(tiny_graph_bundle, tmp_path, monkeypatch):
    import terra.bundle as bundle_module
    from terra.bundle import Bundle

    bundle = Bundle(copy_bundle(tiny_graph_bundle, tmp_path / "copy.terra"))
    calls = []
    real = bundle_module._sha256
    monkeypatch.setattr(bundle_module, "_sha256", lambda path: calls.append(path) or real(path))
    first = bundle.array("map/points")
    again = Bundle(bundle.path).array("map/points")
    assert (first == again).all() and len(calls) == 1
    flip_last_byte(bundle.path / "map/points.npy")  # a rewritten file has a new identity: checked again
    with pytest.raises(Exception, match="checksum mismatch"):
        Bundle(bundle.path).array("map/points")
    assert len(calls) == 2
