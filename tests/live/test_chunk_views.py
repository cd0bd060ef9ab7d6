"""The read view of a live version derived from the view before it (terra/mapping/chunk_views.py):
the same arrays as a full derivation (every chunk read, the keys sorted in full), on random drives
and on the tiny campus, whose closed session is still the batch map byte for byte."""

from __future__ import annotations

import gc
import shutil

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.errors import TerraError
from terra.live import Session
from terra.mapping import chunk_views
from terra.mapping.storage import load_map
from tests.live.test_session import map_files
from tests.mapping.fixtures import assert_same_map


@pytest.fixture
def full_derivations(monkeypatch) -> list[str]:
    """The bundle folders whose view was derived in full (every chunk read, all keys sorted)."""
    calls: list[str] = []
    full = chunk_views.full_view

    def counted(bundle, *args):
        calls.append(str(bundle.path))
        return full(bundle, *args)

    monkeypatch.setattr(chunk_views, "full_view", counted)
    monkeypatch.setattr(chunk_views, "MOST_CHANGED", float("inf"))  # from the view before, however much changed
    return calls


def _assert_full_view(view, out, tmp_path) -> None:
    """`view` is the map a process that never saw `out` before derives from its files in full."""
    copy = tmp_path / "copy.terra"
    shutil.rmtree(copy, ignore_errors=True)
    shutil.copytree(out, copy)
    assert_same_map(view, copy)


def _random_frame(rng: np.random.Generator, labels: np.ndarray, centre: np.ndarray) -> dict:
    """A scan of 400 points within 6 m of `centre` (metres, map frame = LiDAR frame), random labels."""
    points = centre + rng.uniform(-6.0, 6.0, size=(400, 3)) * [1.0, 1.0, 0.2]
    return {"points": points, "T_map_lidar": np.eye(4), "labels": rng.choice(labels, 400), "instances": None}


@pytest.mark.parametrize("seed", [0, 1])
def test_a_view_derived_from_the_one_before_equals_a_full_derivation_on_random_drives(
    tiny_campus, tmp_path, full_derivations, seed
):
    """A drive that grows the map at one end and comes back over old ground at random: after the
    first, every view is derived from the one before, and each equals the full derivation."""
    rng = np.random.default_rng(seed)
    labels = np.unique(tiny_campus[0].point_labels)
    out = tmp_path / "live.terra"
    session = Session(out, tiny_campus.classes, graph=False, name="random", chunk_rows=256)
    stamp = 0.0
    for step in range(6):
        for _ in range(int(rng.integers(1, 4))):
            ahead = np.array([8.0 * step, 0.0, 0.0])  # new ground
            back = np.array([rng.uniform(0.0, 8.0 * step + 1.0), rng.uniform(-3.0, 3.0), 0.0])  # ground seen before
            for centre in (ahead, back):
                stamp += 0.1
                frame = _random_frame(rng, labels, centre)
                session.add_frame(frame["points"], frame["T_map_lidar"], stamp, labels=frame["labels"])
        snapshot = session.snapshot()
        _assert_full_view(snapshot.bundle.msm, out, tmp_path)
    assert full_derivations.count(str(out)) == 1  # the first view only
    assert len(snapshot.bundle.msm) > 4 * 256


def test_live_views_derived_one_from_another_and_the_closed_map_equal_the_batch_map(
    tiny_campus, tiny_bundle, tmp_path, full_derivations
):
    out = tmp_path / "live.terra"
    session = Session(out, tiny_campus.classes, graph=False, name=tiny_campus.name, chunk_rows=1024)
    for i in range(len(tiny_campus)):
        session.add(tiny_campus[i])
        if (i + 1) % 4 == 0:
            _assert_full_view(session.snapshot().bundle.msm, out, tmp_path)
    assert full_derivations.count(str(out)) == 1
    last = session.snapshot()
    assert_same_map(last.bundle.msm, tiny_bundle.path)  # the live view of the whole drive is the batch map
    session.close()
    assert map_files(out) == map_files(tiny_bundle.path)  # byte for byte


def test_a_view_whose_arrays_were_freed_is_derived_in_full(tiny_campus, tmp_path, full_derivations):
    out = tmp_path / "live.terra"
    session = Session(out, tiny_campus.classes, graph=False, name=tiny_campus.name, chunk_rows=1024)
    for i in range(6):
        session.add(tiny_campus[i])
    session.snapshot()
    session._latest = None  # no reader holds the first view any more
    gc.collect()
    session.add(tiny_campus[6])
    second = session.snapshot()
    assert full_derivations.count(str(out)) == 2
    _assert_full_view(second.bundle.msm, out, tmp_path)
    with pytest.raises(ValueError):  # views are read-only: the next one takes rows from them
        second.bundle.msm.points[0, 0] = 1.0


def test_a_damaged_chunk_is_refused_when_the_view_comes_from_the_one_before(tiny_campus, tmp_path):
    out = tmp_path / "live.terra"
    session = Session(out, tiny_campus.classes, graph=False, name=tiny_campus.name, chunk_rows=1024)
    for i in range(6):
        session.add(tiny_campus[i])
    first = session.snapshot()
    damaged = out / "map/chunks/00001/points.npy"
    data = bytearray(damaged.read_bytes())
    data[-1] ^= 1
    damaged.write_bytes(bytes(data))
    with pytest.raises(TerraError, match="00001/points.npy: checksum mismatch"):
        load_map(Bundle(out))  # no chunk changed since `first`: none is read, each is checked
    assert len(first.bundle.msm) > 1024


def test_a_version_whose_changed_chunks_hold_most_rows_is_derived_in_full(tiny_campus, tmp_path, full_derivations):
    out = tmp_path / "live.terra"
    session = Session(out, tiny_campus.classes, graph=False, name=tiny_campus.name, chunk_rows=1024)
    for i in range(6):
        session.add(tiny_campus[i])
    session.snapshot()
    for i in range(6, 12):  # new ground and old: most chunks change
        session.add(tiny_campus[i])
    chunk_views.MOST_CHANGED = 0.0  # (restored by monkeypatch) any changed chunk is too many
    second = session.snapshot()
    assert full_derivations.count(str(out)) == 2
    _assert_full_view(second.bundle.msm, out, tmp_path)
