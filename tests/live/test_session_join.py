"""A live Session joining a second drive to a map (Session(..., join=...)) gives the map `terra map --into`
gives for the same frames and alignment, byte for byte, with the drive's own clock and frame."""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.datasets.base import Frame
from terra.errors import TerraError
from terra.geometry import invert_pose
from terra.live import Session
from terra.mapping.align import pose_from_guess
from terra.mapping.changes import detect_changes
from terra.mapping.config import MappingConfig
from terra.mapping.pipeline import run_mapping
from terra.mapping.sessions import SessionFrames, map_points, plan_join, session_list
from tests.live.test_session import FrameRange, map_files
from tests.mapping.fixtures import assert_same_map

T_TRUE = pose_from_guess(50.0, -10.0, 90.0)


class EarlierClock:
    """A drive whose clock reads `shift` seconds less (its images' too), frames copied, not changed."""

    def __init__(self, dataset, shift: float):
        self.dataset, self.shift, self.name, self.classes = dataset, shift, dataset.name, dataset.classes

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, index: int) -> Frame:
        frame = self.dataset[index]
        cameras = [replace(camera, stamp=camera.stamp - self.shift) for camera in frame.cameras]
        return replace(frame, stamp=frame.stamp - self.shift, cameras=cameras)

    def global_map(self):
        return None


def test_a_live_join_equals_the_batch_join(tiny_campus, tmp_path):
    first = tmp_path / "first.terra"
    run_mapping(FrameRange(tiny_campus, 0, 20), MappingConfig(), first, show_progress=False)
    batch, live = tmp_path / "batch.terra", tmp_path / "live.terra"
    shutil.copytree(first, batch)
    shutil.copytree(first, live)
    # In its own frame, on its own clock: earlier than the map's last frame.
    second = EarlierClock(SessionFrames(FrameRange(tiny_campus, 12, 30), invert_pose(T_TRUE)), 1000.0)
    plan = plan_join(second, batch, pose_from_guess(47.0, -7.0, 84.0))
    run_mapping(plan.frames, MappingConfig(), batch, show_progress=False, join=plan.alignment.to_json())

    session = Session(live, tiny_campus.classes, graph=False, join=plan.alignment, name="visit2")
    for i in range(len(second)):
        assert session.add(second[i])
    session.snapshot()
    assert_same_map(live, batch, any_order=True)  # a live version (row chunks, creation order) as load_map reads it
    np.testing.assert_array_equal(map_points(Bundle(live)), map_points(Bundle(batch)))
    changed, expected = detect_changes(live, 1, 2), detect_changes(batch, 1, 2)  # `terra changes` on both layouts
    assert changed.observed_area_m2 == expected.observed_area_m2 > 0
    assert [o.to_json() for o in changed.objects] == [o.to_json() for o in expected.objects]
    assert changed.terrain_pairs == expected.terrain_pairs
    np.testing.assert_array_equal(changed.terrain_cells, expected.terrain_cells)
    session.close()
    # map/meta.json names the live session's source (as a resumed live map does); the map itself is the same.
    assert {k: v for k, v in map_files(live).items() if k != "map/meta.json"} == {
        k: v for k, v in map_files(batch).items() if k != "map/meta.json"
    }
    info = Bundle(live).model.components.map
    assert info is not None
    joined = session_list(list(info.sources or []))[-1]
    assert joined["session"] == 2 and joined["name"] == "visit2" and joined["how"] == "initial guess + GICP"
    np.testing.assert_allclose(joined["T_map_session"], plan.alignment.T_map_session, atol=1e-8)


def test_a_join_needs_a_map_and_a_rigid_transform(tiny_campus, tmp_path):
    with pytest.raises(TerraError, match="no bundle to append to"):
        Session(tmp_path / "none.terra", tiny_campus.classes, graph=False, join=np.eye(4))
    first = tmp_path / "first.terra"
    run_mapping(FrameRange(tiny_campus, 0, 3), MappingConfig(), first, show_progress=False)
    with pytest.raises(TerraError, match="join: expected T_map_session as a 4x4 rigid pose"):
        Session(first, tiny_campus.classes, graph=False, join=np.eye(3))
