"""Two drives of the simulated tiny campus joined into one map (terra/mapping/sessions.py): the second drive
in its own frame, 50 m and 90 degrees from the map's; its transform recovered against the simulator's truth,
its returns counted apart, the joined map equal to one run over both drives' aligned frames, and every bad
join refused with the bundle untouched."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.datasets.base import ClassTable, SemanticClass
from terra.errors import TerraError
from terra.geometry import invert_pose
from terra.mapping.align import pose_from_guess
from terra.mapping.config import MappingConfig
from terra.mapping.pipeline import run_mapping
from terra.mapping.sessions import SessionFrames, plan_join, relative_error, session_list
from terra.schemas import Wgs84Anchor
from terra.wgs84 import MapToWgs84
from tests.live.test_session import FrameRange, map_files
from tests.mapping.fixtures import folder_digest

T_TRUE = pose_from_guess(50.0, -10.0, 90.0)  # map <- second drive's frame
GUESS = pose_from_guess(47.0, -7.0, 84.0)  # 4.2 m and 6 degrees off


class Concatenated:
    """Two datasets one after the other, as one drive."""

    def __init__(self, first, second):
        self.parts, self.name, self.classes = (first, second), first.name, first.classes

    def __len__(self) -> int:
        return len(self.parts[0]) + len(self.parts[1])

    def __getitem__(self, index: int):
        first = len(self.parts[0])
        return self.parts[0][index] if index < first else self.parts[1][index - first]

    def global_map(self):
        return None


@pytest.fixture(scope="module")
def joined(tiny_campus, tmp_path_factory):
    """(folder of the joined map, the alignment found, the second drive in its own frame, the first map's folder)."""
    root = tmp_path_factory.mktemp("sessions")
    first = root / "first.terra"
    run_mapping(FrameRange(tiny_campus, 0, 25), MappingConfig(), first, show_progress=False)
    out = root / "joined.terra"
    shutil.copytree(first, out)
    second = SessionFrames(FrameRange(tiny_campus, 15, 40), invert_pose(T_TRUE))  # poses in its own frame
    plan = plan_join(second, out, GUESS)
    run_mapping(plan.frames, MappingConfig(), out, show_progress=False, join=plan.alignment.to_json())
    return out, plan.alignment, second, first


def test_the_second_drive_is_found_where_the_simulator_put_it(joined):
    _, alignment, _, _ = joined
    metres, degrees = relative_error(T_TRUE, alignment.T_map_session)
    assert metres < 0.05 and degrees < 0.05
    assert alignment.how == "initial guess + GICP" and alignment.converged


def test_the_manifest_lists_both_sessions(joined, tiny_campus):
    out, alignment, _, _ = joined
    info = Bundle(out).model.components.map
    assert info is not None
    sessions = session_list(list(info.sources or []))
    assert [s["session"] for s in sessions] == [1, 2] and [s["frames"] for s in sessions] == [25, 25]
    assert sessions[0]["how"] == "defines the map frame" and sessions[0]["fitness"] is None
    stamps = tiny_campus.trajectory.stamps
    assert sessions[0]["time_span"] == [stamps[0], stamps[24]] and sessions[1]["time_span"] == [stamps[15], stamps[39]]
    np.testing.assert_allclose(sessions[1]["T_map_session"], alignment.T_map_session, atol=1e-8)
    assert sessions[1]["fitness"] == round(alignment.fitness, 4) and sessions[1]["overlap"] == round(
        alignment.overlap, 4
    )


def test_returns_are_counted_per_session_and_add_up(joined):
    out, _, _, first = joined
    bundle = Bundle(out)
    hits = np.asarray(bundle.array("map/state/session_hits"), dtype=np.int64)
    total = np.asarray(bundle.array("map/state/voxel_hits"), dtype=np.int64)
    assert hits.shape == (total.size, 2)
    np.testing.assert_array_equal(hits.sum(axis=1), total)
    # Session 1's column is the first map's voxel hits, each at its voxel in the joined map.
    keys = np.asarray(bundle.array("map/state/voxel_keys"))
    first_bundle = Bundle(first)
    first_keys, first_hits = first_bundle.array("map/state/voxel_keys"), first_bundle.array("map/state/voxel_hits")
    rows = np.searchsorted(keys, first_keys)
    np.testing.assert_array_equal(keys[rows], first_keys)
    np.testing.assert_array_equal(hits[rows, 0], first_hits)
    assert hits[:, 0].sum() == int(np.asarray(first_hits, np.int64).sum())


def test_the_joined_map_equals_one_run_over_the_aligned_frames(joined, tiny_campus, tmp_path):
    out, alignment, second, _ = joined
    both = Concatenated(FrameRange(tiny_campus, 0, 25), SessionFrames(second, alignment.T_map_session))
    single = tmp_path / "single.terra"
    run_mapping(both, MappingConfig(), single, show_progress=False)
    per_session = ("map/state/session_hits.npy", "map/state/session_votes.npy")  # a one-session map has neither
    found = {k: v for k, v in map_files(out).items() if k not in per_session}
    assert found == map_files(single)


def test_bad_joins_are_refused_and_leave_the_bundle_untouched(joined, tiny_campus):
    out, _, second, _ = joined
    before = folder_digest(out)
    with pytest.raises(TerraError, match="this session is already in the map"):
        plan_join(second, out, GUESS)
    far = SessionFrames(FrameRange(tiny_campus, 14, 40), invert_pose(T_TRUE))
    with pytest.raises(TerraError, match=r"cannot align the session to the map: fitness 0\.\d\d .*overlap"):
        plan_join(far, out, pose_from_guess(50.0, -10.0, 270.0))  # turned the wrong way round
    relabelled = FrameRange(tiny_campus, 30, 40)
    relabelled.classes = ClassTable([SemanticClass(1, "grass", terrain=True), SemanticClass(2, "car")])
    with pytest.raises(TerraError, match="class table differs from the map's"):
        plan_join(relabelled, out, GUESS)
    assert folder_digest(out) == before


def test_without_a_guess_the_search_finds_the_drive(joined, tiny_campus):
    _, _, _, first = joined
    other = SessionFrames(FrameRange(tiny_campus, 16, 40), invert_pose(T_TRUE))
    plan = plan_join(other, first, None)
    metres, degrees = relative_error(T_TRUE, plan.alignment.T_map_session)
    assert metres < 0.05 and degrees < 0.05 and plan.alignment.how == "place search + GICP"


class Anchored:
    """A dataset whose frame is anchored on the Earth, as a source with GNSS fixes is (`wgs84_anchor`)."""

    def __init__(self, dataset, anchor: Wgs84Anchor):
        self.dataset, self.anchor, self.name, self.classes = dataset, anchor, dataset.name, dataset.classes

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, index: int):
        return self.dataset[index]

    def global_map(self):
        return None

    def wgs84_anchor(self) -> dict:
        return self.anchor.model_dump(mode="json")


@pytest.fixture(scope="module")
def anchored_map(tiny_campus, tmp_path_factory):
    """The first 25 frames mapped by a source anchored on the Earth; (its folder, the anchor)."""
    on_earth = Wgs84Anchor(lat=47.3769, lon=8.5417, alt=408.0, yaw_deg=20.0)
    first = tmp_path_factory.mktemp("anchored") / "anchored.terra"
    run_mapping(Anchored(FrameRange(tiny_campus, 0, 25), on_earth), MappingConfig(), first, show_progress=False)
    return first, on_earth


def session_anchor(on_earth: Wgs84Anchor, offset: np.ndarray, turn_deg: float) -> Wgs84Anchor:
    """Where T_TRUE puts the second drive's frame on the Earth, moved by `offset` metres and turned."""
    lon, lat, alt = MapToWgs84(on_earth).lon_lat_height((T_TRUE[:3, 3] + offset)[None])[0]
    return Wgs84Anchor(lat=lat, lon=lon, alt=alt, yaw_deg=on_earth.yaw_deg + 90.0 + turn_deg)


def test_with_gnss_on_both_drives_the_join_starts_from_it(tiny_campus, anchored_map):
    """Map anchored at a known place; the second drive's anchor 2 m and 1.5 degrees off where T_TRUE puts
    it (a receiver's error): the join starts from GNSS, not from the search, and GICP removes the error."""
    first, on_earth = anchored_map
    info = Bundle(first).model.components.map
    assert info is not None and info.wgs84_anchor == on_earth
    anchor = session_anchor(on_earth, np.array([1.6, -1.2, 0.0]), 1.5)
    second = Anchored(SessionFrames(FrameRange(tiny_campus, 15, 40), invert_pose(T_TRUE)), anchor)
    plan = plan_join(second, first, None)
    metres, degrees = relative_error(T_TRUE, plan.alignment.T_map_session)
    assert plan.alignment.how == "GNSS prior + GICP"
    assert metres < 0.05 and degrees < 0.05


def test_a_drive_of_another_site_by_gnss_is_refused_without_a_search(tiny_campus, anchored_map):
    first, on_earth = anchored_map
    before = folder_digest(first)
    far = session_anchor(on_earth, np.array([5000.0, 0.0, 0.0]), 0.0)
    second = Anchored(SessionFrames(FrameRange(tiny_campus, 15, 40), invert_pose(T_TRUE)), far)
    with pytest.raises(TerraError, match=r"by GNSS the session lies 4\.9 km from the map: a drive of another site"):
        plan_join(second, first, None)
    assert folder_digest(first) == before
