"""The read view of a live version derived from the view before it (terra/mapping/chunk_views.py):
rows in creation order, the same arrays as a process reading every chunk of the version gives, only
the chunks whose files changed read again; on random drives and on the tiny campus, whose last live
view holds the batch map's rows and whose closed session is the batch map byte for byte."""

from __future__ import annotations

import gc
import shutil

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.errors import TerraError
from terra.live import Session
from terra.mapping import chunk_views
from terra.mapping.chunks import read_rows
from terra.mapping.storage import load_map
from tests.live.test_session import map_files
from tests.mapping.fixtures import assert_same_map


@pytest.fixture
def chunks_read(monkeypatch) -> list[tuple[str, list[int]]]:
    """(bundle folder, chunks read) of every view derived."""
    calls: list[tuple[str, list[int]]] = []

    def counted(bundle, names, n, k, t, chunks=None):
        calls.append((str(bundle.path), list(chunks) if chunks is not None else []))
        return read_rows(bundle, names, n, k, t, chunks)

    monkeypatch.setattr(chunk_views, "read_rows", counted)
    return calls


@pytest.fixture
def files_read(monkeypatch) -> list[str]:
    """The bundle files (paths) read from disk while a view is derived."""
    import terra.bundle

    paths: list[str] = []
    deriving = [False]
    real_read, real_view = terra.bundle.read_npy, chunk_views.chunk_view

    def read(path, *args, **kwargs):
        if deriving[0]:
            paths.append(str(path))
        return real_read(path, *args, **kwargs)

    def view(*args, **kwargs):
        deriving[0] = True
        try:
            return real_view(*args, **kwargs)
        finally:
            deriving[0] = False

    monkeypatch.setattr(terra.bundle, "read_npy", read)
    monkeypatch.setattr(chunk_views, "chunk_view", view)
    return paths


def _changed_chunks(before: dict, after: dict) -> list[int]:
    """The chunks whose view files differ between two manifests' files (or are new)."""
    count = 1 + max((int(name.split("/")[2]) for name in after if name.startswith("map/chunks/")), default=-1)
    return [c for c in range(count) if chunk_views._digests(before, c) != chunk_views._digests(after, c)]


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
    tiny_campus, tmp_path, chunks_read, files_read, seed
):
    """A drive that grows the map at one end and comes back over old ground at random: after the
    first, every view reads only the chunks whose files changed, and of those only the files the
    version kept from the one before (those it wrote are handed over in memory), and each equals the
    full derivation."""
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
        before = dict(Bundle(out).files) if step else {}
        files_read.clear()
        snapshot = session.snapshot()
        reads = [chunks for folder, chunks in chunks_read if folder == str(out)]
        after = snapshot.bundle.bundle.files
        assert reads[-1] == _changed_chunks(before, after)
        from_disk = [path.split("/live.terra/")[1] for path in files_read if "/map/chunks/" in path]
        assert all(before.get(name) == after[name] for name in from_disk)
        written = [name for name in after if name.startswith("map/chunks/") and before.get(name) != after[name]]
        assert written and not set(written) & set(from_disk)
        _assert_full_view(snapshot.bundle.msm, out, tmp_path)
    assert len(snapshot.bundle.msm) > 4 * 256
    assert 0 < len(reads[-1]) < len(snapshot.bundle.msm) // 256  # old ground seen again: some chunks, not all


def test_live_views_derived_one_from_another_and_the_closed_map_equal_the_batch_map(
    tiny_campus, tiny_bundle, tmp_path, chunks_read
):
    out = tmp_path / "live.terra"
    session = Session(out, tiny_campus.classes, graph=False, name=tiny_campus.name, chunk_rows=1024)
    for i in range(len(tiny_campus)):
        session.add(tiny_campus[i])
        if (i + 1) % 4 == 0:
            _assert_full_view(session.snapshot().bundle.msm, out, tmp_path)
    last = session.snapshot()
    assert len(chunks_read[-1][1]) < len(last.bundle.msm) // 1024  # not every chunk read again
    # The live view of the whole drive holds the batch map's rows, in the order they were first seen.
    assert_same_map(last.bundle.msm, tiny_bundle.path, any_order=True)
    assert not np.array_equal(last.bundle.msm.points, load_map(Bundle(tiny_bundle.path)).points)
    np.testing.assert_array_equal(last.bundle.msm.points, session.mapper.fusion.geometry.points())  # the fusion's rows
    session.close()
    assert map_files(out) == map_files(tiny_bundle.path)  # byte for byte


def test_a_view_whose_arrays_were_freed_is_derived_in_full(tiny_campus, tmp_path, chunks_read):
    out = tmp_path / "live.terra"
    session = Session(out, tiny_campus.classes, graph=False, name=tiny_campus.name, chunk_rows=1024)
    for i in range(6):
        session.add(tiny_campus[i])
    session.snapshot()
    session._latest = None  # no reader holds the first view any more
    gc.collect()
    session.add(tiny_campus[6])
    second = session.snapshot()
    assert chunks_read[-1][1] == list(range(1 + (len(second.bundle.msm) - 1) // 1024))  # every chunk
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
