"""Live versions in row chunks (terra/mapping/chunks.py): a snapshot writes again only the chunks in
which a point changed and shares the others with the version before (hard links); the map read
from them is the map the flat layout stores; both layouts continue one another."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.errors import TerraError
from terra.live import Session
from terra.mapping.config import MappingConfig
from terra.mapping.pipeline import run_mapping
from terra.mapping.storage import load_map
from terra.mapping.summary import map_summary
from tests.live.test_session import FrameRange, map_files
from tests.mapping.fixtures import assert_same_map

ROWS = 1024


def _chunk_inodes(out) -> dict[str, int]:
    return {name: os.stat(out / name).st_ino for name in Bundle(out).files if name.startswith("map/chunks/")}


def _add_near_part(session: Session, frame, radius: float) -> None:
    """Fuse the points of `frame` within `radius` metres of the sensor, without its images: a frame
    that changes a small part of the map."""
    near = np.linalg.norm(frame.points, axis=1) < radius
    session.add_frame(
        frame.points[near],
        frame.T_map_lidar,
        frame.stamp,
        labels=frame.point_labels[near],
        instances=frame.point_instances[near],
    )


def test_a_snapshot_rewrites_only_the_chunks_that_changed(tiny_campus, tmp_path):
    out = tmp_path / "live.terra"
    session = Session(out, tiny_campus.classes, graph=False, name=tiny_campus.name, chunk_rows=ROWS)
    for i in range(20):
        session.add(tiny_campus[i])
    first = session.snapshot()
    before = _chunk_inodes(out)
    chunks = {name.split("/")[2] for name in before}
    _add_near_part(session, tiny_campus[20], 4.0)
    fusion = session.mapper.fusion
    changed = {f"{c:05d}" for c in np.unique(fusion.touched_rows() // ROWS)}
    second = session.snapshot()
    after = _chunk_inodes(out)
    rewritten = {name.split("/")[2] for name, inode in after.items() if before.get(name) != inode}
    assert rewritten == changed and 0 < len(changed) < len(chunks) / 2
    shared = [name for name in after if name.split("/")[2] not in changed]
    assert shared and all(after[name] == before[name] for name in shared)  # the same files, hard-linked
    full = len(first.bundle.msm) // ROWS  # chunks whose points were all there before
    kept = [f"map/chunks/{c}/keys.npy" for c in changed if int(c) < full]
    assert kept and all(after[name] == before[name] for name in kept)  # in a changed chunk, unchanged keys
    Bundle(out).verify()
    # The read view of the shared chunks is the map the flat layout stores for the same fusion.
    chunked = tmp_path / "chunked.terra"
    shutil.copytree(out, chunked)
    assert Bundle(chunked).version == second.version == first.version + 1
    assert_same_map(second.bundle.msm, chunked)  # the session's view is the version as stored
    session.close()
    assert not Bundle(out).has("map/chunks/00000/points") and Bundle(out).has("map/points")
    assert_same_map(chunked, out, any_order=True)  # creation order, then voxel-key order
    summaries = [map_summary(Bundle(path))["map"] for path in (chunked, out)]  # `terra info`
    assert summaries[0]["terrain_points"] == summaries[1]["terrain_points"]
    assert summaries[0]["points"] == summaries[1]["points"] > 0
    assert_same_map(second.bundle.msm, load_map(Bundle(out)), any_order=True)


def test_a_damaged_chunk_is_refused(tiny_campus, tmp_path):
    out = tmp_path / "live.terra"
    session = Session(out, tiny_campus.classes, graph=False, name=tiny_campus.name, chunk_rows=ROWS)
    for i in range(6):
        session.add(tiny_campus[i])
    session.snapshot()
    damaged = out / "map/chunks/00002/votes.npy"
    data = bytearray(damaged.read_bytes())
    data[-1] ^= 1
    damaged.write_bytes(bytes(data))
    with pytest.raises(TerraError, match="00002/votes.npy: checksum mismatch"):
        load_map(Bundle(out))
    with pytest.raises(TerraError, match="checksum mismatch"):
        Session(out, tiny_campus.classes, graph=False, resume=True, name=tiny_campus.name)


def test_append_continues_a_live_version_and_a_session_continues_a_batch_map(tiny_campus, tiny_bundle, tmp_path):
    """`terra map --append` resumes from a live version's chunks (a session that never closed);
    a live session resumes from a batch map (flat) and writes all its chunks once."""
    cut = len(tiny_campus) // 3
    live = tmp_path / "live.terra"
    session = Session(live, tiny_campus.classes, graph=False, name=tiny_campus.name, chunk_rows=ROWS)
    for i in range(cut):
        session.add(tiny_campus[i])
    session.snapshot()
    del session  # never closed: the bundle keeps its last live version
    run_mapping(FrameRange(tiny_campus, cut, len(tiny_campus)), MappingConfig(), live, False, append=True)
    assert map_files(live) == map_files(tiny_bundle.path)

    batch = tmp_path / "batch.terra"
    run_mapping(FrameRange(tiny_campus, 0, cut), MappingConfig(), batch, show_progress=False)
    resumed = Session(batch, tiny_campus.classes, graph=False, resume=True, name=tiny_campus.name, chunk_rows=ROWS)
    for i in range(cut, len(tiny_campus)):
        resumed.add(tiny_campus[i])
    resumed.snapshot()
    assert Bundle(batch).has("map/chunks/00000/keys")
    assert_same_map(batch, tiny_bundle.path, any_order=True)


def _patched_chunks(out) -> dict[str, np.ndarray]:
    """Chunk folder -> its patched rows (chunk-local), for the chunks of `out` with a row patch."""
    bundle = Bundle(out)
    names = [name for name in bundle.files if name.endswith("/patch_rows.npy")]
    return {name.split("/")[2]: bundle.array(name[: -len(".npy")]) for name in names}


def test_a_chunk_in_which_few_rows_changed_keeps_its_files_and_gets_a_row_patch(tiny_campus, tmp_path):
    """Old chunks with a few rows seen again keep their files (the same inodes) and store those rows
    in a patch, cumulative over versions; the map read is the flat map of the same fusion, and a
    session resumed from a patched version continues it exactly."""
    out = tmp_path / "live.terra"
    session = Session(out, tiny_campus.classes, graph=False, name=tiny_campus.name, chunk_rows=ROWS)
    for i in range(20):
        session.add(tiny_campus[i])
    first = session.snapshot()
    before = _chunk_inodes(out)
    full = len(first.bundle.msm) // ROWS
    versions = []
    for frame in (20, 21):
        _add_near_part(session, tiny_campus[frame], 4.0)
        touched = session.mapper.fusion.touched_rows()
        session.snapshot()
        versions.append((touched, _patched_chunks(out)))
    (touched, patches), (touched2, patches2) = versions
    assert patches and all(int(c) < full for c in patches)  # only chunks that were full are patched
    for c, rows in patches.items():
        local = touched[touched // ROWS == int(c)] % ROWS
        np.testing.assert_array_equal(rows, local)  # the rows seen again, and only those
        assert 0 < rows.size <= 0.25 * ROWS
        assert _chunk_inodes(out)[f"map/chunks/{c}/points.npy"] == before[f"map/chunks/{c}/points.npy"]
    for c, rows in patches2.items():  # cumulative: the rows of the patch before are still there
        earlier = patches.get(c, np.zeros(0, np.int32))
        local = touched2[touched2 // ROWS == int(c)] % ROWS
        np.testing.assert_array_equal(rows, np.union1d(earlier, local))
    Bundle(out).verify()
    chunked = tmp_path / "chunked.terra"
    shutil.copytree(out, chunked)
    assert_same_map(session.snapshot().bundle.msm, chunked)  # the session's view is the version as read
    resumed = Session(chunked, tiny_campus.classes, graph=False, resume=True, name=tiny_campus.name, chunk_rows=ROWS)
    for live in (session, resumed):
        live.add(tiny_campus[22])
        live.close()
    assert map_files(chunked) == map_files(out)  # the patched version restored the fusion exactly


def test_a_damaged_row_patch_is_refused(tiny_campus, tmp_path):
    out = tmp_path / "live.terra"
    session = Session(out, tiny_campus.classes, graph=False, name=tiny_campus.name, chunk_rows=ROWS)
    for i in range(20):
        session.add(tiny_campus[i])
    session.snapshot()
    _add_near_part(session, tiny_campus[20], 4.0)
    session.snapshot()
    chunk = sorted(_patched_chunks(out))[0]
    damaged = out / f"map/chunks/{chunk}/patch_votes.npy"
    data = bytearray(damaged.read_bytes())
    data[-1] ^= 1
    damaged.write_bytes(bytes(data))
    with pytest.raises(TerraError, match=f"{chunk}/patch_votes.npy: checksum mismatch"):
        load_map(Bundle(out))
