"""The live map (terra.live.Session) and `terra map --append` against one batch run of the same frames.

The batch reference is `tiny_bundle`: simulate('tiny', 0) mapped in one `build_map` run with the
default MappingConfig. A drive fed frame by frame, or mapped in two parts, must give the same map:
a live snapshot (row chunks, terra/mapping/chunks.py) as `load_map` reads it, and a closed session or
a batch continuation the same map files byte for byte (map/meta.json too: the same source name),
fusion state included.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.errors import TerraError
from terra.graph.config import BuildConfig
from terra.live import LiveFrameError, Session
from terra.mapping.config import MappingConfig
from terra.mapping.pipeline import run_mapping
from tests.mapping.fixtures import assert_same_map, folder_digest


class FrameRange:
    """Frames [start, stop) of a dataset, as a dataset of their own (same name and classes)."""

    def __init__(self, dataset, start: int, stop: int):
        self._dataset, self._start, self._stop = dataset, start, stop
        self.name, self.classes = dataset.name, dataset.classes

    def __len__(self) -> int:
        return self._stop - self._start

    def __getitem__(self, index: int):
        if not 0 <= index < len(self):
            raise IndexError(index)
        return self._dataset[self._start + index]

    def global_map(self):
        return None


def map_files(path) -> dict[str, str]:
    return {name: digest for name, digest in folder_digest(path).items() if name.startswith("map/")}


def test_batch_map_keeps_its_fusion_state(tiny_campus, tiny_bundle):
    bundle = Bundle(tiny_bundle.path)
    assert bundle.has("map/state/meta.json") and bundle.has("map/state/voxel_sums")
    info = bundle.model.components.map
    assert info is not None and info.frames == len(tiny_campus)
    assert info.time_span == [tiny_campus[0].stamp, tiny_campus[len(tiny_campus) - 1].stamp]
    assert info.version == bundle.version == 1
    assert info.sources is not None and [s["first_frame"] for s in info.sources] == [0]


def test_live_fed_drive_equals_the_batch_map(tiny_campus, tiny_bundle, tmp_path):
    out = tmp_path / "live.terra"
    session = Session(out, tiny_campus.classes, MappingConfig(), graph=False, name=tiny_campus.name, chunk_rows=4096)
    half = len(tiny_campus) // 2
    for i in range(half):
        session.add(tiny_campus[i])
    early = session.snapshot()  # a snapshot in the middle changes nothing of what follows
    assert early.version == 1 and early.frames == half and early.map_time == pytest.approx(tiny_campus[half - 1].stamp)
    early_points = len(early.bundle.msm)
    for i in range(half, len(tiny_campus)):
        session.add(tiny_campus[i])
    final = session.snapshot()
    assert final.version == 2 and len(early.bundle.msm) == early_points < len(final.bundle.msm)
    assert Bundle(out).has("map/chunks/00009/points") and not Bundle(out).has("map/points")
    assert_same_map(out, tiny_bundle.path, any_order=True)  # rows in creation order until the close
    closing = session.close()  # the closing version in the flat layout batch runs write
    assert closing is not None and closing.version == 3
    assert map_files(out) == map_files(tiny_bundle.path)
    # Closed: the fusion state is let go of, the snapshots read on, and nothing more is fused.
    assert session.mapper.fusion.geometry.size == 0 and len(early.bundle.msm) == early_points
    from terra.mapping import chunk_views

    assert os.path.realpath(out) not in chunk_views._MEMOS  # nor what the process kept of its last view
    assert session.close() is closing and Bundle(out).version == 3
    with pytest.raises(TerraError, match=r"live\.terra: the session is closed; a new Session\(\.\.\., resume=True\)"):
        session.add(tiny_campus[0])
    with pytest.raises(TerraError, match="the session is closed"):
        session.snapshot()
    with pytest.raises(TerraError, match="fusion state was let go of when its session closed"):
        session.mapper.fusion.associate(np.zeros((1, 3)), np.eye(4))


def test_append_in_two_parts_equals_one_run(tiny_campus, tiny_bundle, tmp_path):
    out = tmp_path / "parts.terra"
    cut = len(tiny_campus) // 3
    first = run_mapping(FrameRange(tiny_campus, 0, cut), MappingConfig(), out, show_progress=False)
    assert first.bundle.version == 1
    second = run_mapping(FrameRange(tiny_campus, cut, len(tiny_campus)), MappingConfig(), out, False, append=True)
    assert second.bundle.version == 2
    assert map_files(out) == map_files(tiny_bundle.path)
    info = second.bundle.model.components.map
    assert info is not None and info.sources is not None
    assert [(s["first_frame"], s["frames"]) for s in info.sources] == [(0, cut), (cut, len(tiny_campus) - cut)]
    assert info.frames == len(tiny_campus)


def test_append_refuses_another_configuration_and_a_source_already_in(tiny_campus, tmp_path):
    out = tmp_path / "parts.terra"
    cut = 4
    run_mapping(FrameRange(tiny_campus, 0, cut), MappingConfig(), out, show_progress=False)
    before = folder_digest(out)
    other = MappingConfig.model_validate({"fusion": {"voxel_size": 0.5}})
    with pytest.raises(TerraError, match=r"mapping\.fusion\.voxel_size = 0\.4, this run has 0\.5"):
        run_mapping(FrameRange(tiny_campus, cut, 8), other, out, show_progress=False, append=True)
    with pytest.raises(TerraError, match="already in the map"):
        run_mapping(FrameRange(tiny_campus, 0, cut), MappingConfig(), out, show_progress=False, append=True)
    assert folder_digest(out) == before
    with pytest.raises(TerraError, match="no bundle to append to"):
        run_mapping(FrameRange(tiny_campus, 0, cut), MappingConfig(), tmp_path / "none.terra", False, append=True)


def test_a_resumed_session_continues_the_drive(tiny_campus, tiny_bundle, tmp_path):
    out = tmp_path / "live.terra"
    session = Session(out, tiny_campus.classes, graph=False, name=tiny_campus.name)
    cut = len(tiny_campus) // 2
    for i in range(cut):
        session.add(tiny_campus[i])
    session.snapshot()
    with pytest.raises(TerraError, match="a bundle exists"):
        Session(out, tiny_campus.classes, graph=False)
    resumed = Session(out, tiny_campus.classes, graph=False, resume=True, name=tiny_campus.name)
    assert resumed.frames == cut
    with pytest.raises(LiveFrameError, match="does not follow"):
        resumed.add(tiny_campus[cut - 1])  # a stamp already fused
    for i in range(cut, len(tiny_campus)):
        resumed.add(tiny_campus[i])
    resumed.snapshot()
    assert_same_map(out, tiny_bundle.path, any_order=True)
    resumed.close()
    assert map_files(out) == map_files(tiny_bundle.path)


def _rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    pose = np.eye(4)
    pose[:2, :2] = [[c, -s], [s, c]]
    return pose


@pytest.mark.parametrize(
    ("change", "reason", "message"),
    [
        (lambda f: {"T_map_lidar": np.full((4, 4), np.nan)}, "bad_pose", "NaN or infinity"),
        (lambda f: {"T_map_lidar": np.diag([2.0, 1.0, 1.0, 1.0])}, "bad_pose", "not rigid"),
        (lambda f: {"T_map_lidar": _rotation_z(0.3)[:3]}, "bad_pose", "4x4"),
        (lambda f: {"points": f.points[:, :2]}, "bad_points", r"\(N, 3\)"),
        (lambda f: {"points": f.points.astype(str)}, "bad_points", "expected numbers"),
        (lambda f: {"stamp": float("nan")}, "bad_stamp", "finite"),
        (lambda f: {"stamp": f.stamp - 10.0}, "stamp_back", "does not follow"),
        (lambda f: {"times": np.zeros(3)}, "bad_times", "one value per point"),
    ],
)
def test_malformed_frames_are_refused_and_counted(tiny_campus, tmp_path, change, reason, message):
    session = Session(tmp_path / "live.terra", tiny_campus.classes, graph=False)
    good = tiny_campus[0]
    assert session.add(good)
    frame = tiny_campus[1]
    fields = {"points": frame.points, "T_map_lidar": frame.T_map_lidar, "stamp": frame.stamp, **change(frame)}
    with pytest.raises(LiveFrameError, match=message):
        session.add_frame(**fields)
    assert session.refused.counts == {reason: 1}
    assert session.frames == 1 and session.mapper.stats.counts["frames_fused"] == 1  # nothing fused


FEED_SCRIPT = """
import sys
from tests.reliability.killpoint import install
install(sys.argv[1], int(sys.argv[2]))
from terra.live import Session
from terra.sim import simulate
dataset = simulate("tiny", seed=0)
session = Session(sys.argv[3], dataset.classes, graph=False, name=dataset.name, chunk_rows=4096)
for i in range(len(dataset)):
    session.add(dataset[i])
    if (i + 1) % 4 == 0:
        session.snapshot()
"""


@pytest.mark.parametrize("nth_write", [60, 200])
def test_kill_during_a_snapshot_keeps_the_last_version_and_resumes(tiny_campus, tiny_bundle, tmp_path, nth_write):
    """SIGKILL the feeding process in the middle of writing a snapshot (the Nth file written); the bundle
    still opens at its last committed version, and a resumed session re-fed from its next frame ends
    with the batch map."""
    import signal
    import subprocess
    import sys
    from pathlib import Path

    out = tmp_path / "live.terra"
    child = subprocess.run(
        [sys.executable, "-c", FEED_SCRIPT, "write", str(nth_write), str(out)],
        cwd=Path(__file__).parents[2],
        capture_output=True,
        timeout=600,
    )
    assert child.returncode == -signal.SIGKILL, child.stderr.decode()[-2000:]
    bundle = Bundle(out)  # the last committed version, complete
    bundle.verify()
    info = bundle.model.components.map
    assert info is not None and info.frames is not None and info.frames % 4 == 0 and bundle.version >= 1
    resumed = Session(out, tiny_campus.classes, graph=False, resume=True, name=tiny_campus.name, chunk_rows=4096)
    assert resumed.frames == info.frames
    for i in range(resumed.frames, len(tiny_campus)):
        resumed.add(tiny_campus[i])
    resumed.snapshot()
    assert_same_map(out, tiny_bundle.path, any_order=True)
    resumed.close()
    assert map_files(out) == map_files(tiny_bundle.path)
    leftovers = [p.name for p in tmp_path.iterdir() if p.name != "live.terra"]
    assert leftovers == []


def test_a_write_on_an_older_version_is_refused(tiny_graph_bundle, tmp_path):
    """A reader that saves (find --save) after another writer committed a newer version must not undo it."""
    import shutil

    from terra.graph.pipeline import run_build
    from terra.loaded import LoadedBundle

    copy = tmp_path / "copy.terra"
    shutil.copytree(tiny_graph_bundle.path, copy)
    reader = LoadedBundle(copy)
    _ = reader.graph
    run_build(copy, regions="spectral", show_progress=False)  # another writer: a newer, different version
    newer = folder_digest(copy)
    with pytest.raises(TerraError, match=r"the bundle changed while this bundle was written \(version 2 became 3\)"):
        reader.update_graph(lambda graph: graph)
    assert folder_digest(copy) == newer
    assert [p.name for p in tmp_path.iterdir()] == ["copy.terra"]


def test_live_graph_updates_are_incremental_and_the_closing_graph_is_the_batch_graph(
    tiny_campus, tiny_graph_bundle, tmp_path, monkeypatch
):
    """Snapshots after the first update the graph around the new frames only, each reading of the
    map only the rows the fusion changed since the snapshot before (the digest of the whole map is
    computed at full builds alone); `close()` builds it whole on the same map as `terra build`, so
    it is the batch graph (ids aside: the live ones are carried from the updates, the batch ones are
    a first build's)."""
    from terra.graph import update
    from terra.graph.storage import load_scene_graph

    whole_digests = []
    real_digest = update.map_digest

    def counted(points, *args, **kwargs):
        whole_digests.append(len(points))
        return real_digest(points, *args, **kwargs)

    monkeypatch.setattr(update, "map_digest", counted)

    # The tiny map is small enough that most updates would cover it: incremental ones are asked for
    # anyway (full_fraction 1), to check them against the batch graph.
    build = BuildConfig.model_validate({"update": {"full_fraction": 1.0}})
    session = Session(tmp_path / "live.terra", tiny_campus.classes, MappingConfig(), build=build, name=tiny_campus.name)
    kinds, whole_reads = [], 0
    for i in range(len(tiny_campus)):
        session.add(tiny_campus[i])
        if i >= 2 and i % 3 == 2:
            snapshot = session.snapshot()
            if not snapshot.graph_note:
                kinds.append(snapshot.graph_update["kind"])
                assert snapshot.bundle.graph is not None
                # A full build for its own reason (the first) reads the map whole; one because the
                # change covers the map compared the map's changed rows first.
                whole_reads += snapshot.graph_update["reason"] == "first build of this session"
    assert kinds[0] == "full" and kinds.count("incremental") >= 2
    assert len(whole_digests) == whole_reads == 1
    closing = session.close()
    assert closing is not None and closing.graph_update["kind"] == "full"
    live, batch = load_scene_graph(Bundle(tmp_path / "live.terra")), load_scene_graph(Bundle(tiny_graph_bundle.path))
    np.testing.assert_array_equal(live.places.position, batch.places.position)
    np.testing.assert_array_equal(live.places.terrain, batch.places.terrain)
    np.testing.assert_array_equal(live.places.embedding, batch.places.embedding)
    np.testing.assert_array_equal(live.place_edges, batch.place_edges)
    np.testing.assert_array_equal(live.place_edge_weight, batch.place_edge_weight)
    assert len(live.regions) == len(batch.regions)
    for level in range(1, len(batch.regions) + 1):
        np.testing.assert_array_equal(live.place_region(level), batch.place_region(level))
    info = Bundle(tmp_path / "live.terra").model.components.graph
    assert info is not None and info.model_dump()["update"]["kind"] == "full"


GRAPH_FEED_SCRIPT = """
import sys
from tests.reliability.killpoint import install
install("write", int(sys.argv[1]))
from terra.graph.config import BuildConfig
from terra.live import Session
from terra.sim import simulate
dataset = simulate("tiny", seed=0)
build = BuildConfig.model_validate({"update": {"full_fraction": 1.0}})
session = Session(sys.argv[2], dataset.classes, build=build, name=dataset.name)
for i in range(len(dataset)):
    session.add(dataset[i])
    if (i + 1) % 4 == 0:
        session.snapshot()
"""


def test_kill_during_an_incremental_graph_update_keeps_the_last_version(tiny_campus, tiny_bundle, tmp_path):
    """SIGKILL in the middle of writing the graph of an incremental update (the files counted by a
    first run in this process): the last version opens whole, with a graph that matches its map
    version, and a resumed session ends with the batch map and a full graph."""
    import signal
    import subprocess
    import sys
    from pathlib import Path

    import terra.bundle as bundle_module
    from terra.graph.storage import load_scene_graph

    # Count the files written up to the first incremental graph commit, and its own.
    written = {"n": 0}
    real_write = bundle_module._write_new_file

    def counting(path, data, mode=0o666, **options):
        written["n"] += 1
        return real_write(path, data, mode, **options)

    marks = []
    bundle_module._write_new_file = counting
    try:
        build = BuildConfig.model_validate({"update": {"full_fraction": 1.0}})
        session = Session(tmp_path / "dry.terra", tiny_campus.classes, build=build, name=tiny_campus.name)
        for i in range(len(tiny_campus)):
            session.add(tiny_campus[i])
            if (i + 1) % 4 == 0:
                before = written["n"]
                snapshot = session.snapshot()
                if snapshot.graph_update.get("kind") == "incremental":
                    marks.append((before, written["n"]))
                    break
    finally:
        bundle_module._write_new_file = real_write
    assert marks, "no incremental update in the tiny drive"
    start, end = marks[0]
    kill_at = end - 3  # a graph file of the incremental update, after its map commit
    assert kill_at > start
    out = tmp_path / "live.terra"
    child = subprocess.run(
        [sys.executable, "-c", GRAPH_FEED_SCRIPT, str(kill_at), str(out)],
        cwd=Path(__file__).parents[2],
        capture_output=True,
        timeout=600,
    )
    assert child.returncode == -signal.SIGKILL, child.stderr.decode()[-2000:]
    bundle = Bundle(out)
    bundle.verify()
    graph_info, map_info = bundle.model.components.graph, bundle.model.components.map
    assert map_info is not None and graph_info is not None
    assert graph_info.map_version is not None and graph_info.map_version <= bundle.version
    assert len(load_scene_graph(bundle).places) > 0
    resumed = Session(out, tiny_campus.classes, build=build, resume=True, name=tiny_campus.name)
    for i in range(resumed.frames, len(tiny_campus)):
        resumed.add(tiny_campus[i])
    closing = resumed.close()
    assert closing is not None and closing.graph_update["kind"] == "full"
    assert map_files(out) == map_files(tiny_bundle.path)
    assert [p.name for p in tmp_path.iterdir() if p.name not in ("live.terra", "dry.terra")] == []
