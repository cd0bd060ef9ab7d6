"""build_map end to end on the hand-built box scene: semantics, LiDAR-only input, resume, bad input."""

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.datasets.fingerprint import sample_frames
from terra.errors import TerraError
from terra.mapping.config import MappingConfig
from terra.mapping.pipeline import build_map, run_mapping
from terra.mapping.storage import load_map
from tests.mapping.fixtures import BoxScene, default_boxes, folder_digest


def inside(points: np.ndarray, box, margin: float = 0.05) -> np.ndarray:
    return np.all((points >= np.asarray(box.lo) - margin) & (points <= np.asarray(box.hi) + margin), axis=1)


def class_of_points(msm, text_embedder, names):
    """Per point, the class name whose embedding is nearest its MS-Max bank entry (None if unobserved)."""
    ids = msm.ms_max_ids()
    nearest = (msm.bank @ text_embedder.embed_text(names).T).argmax(axis=1)
    return np.array([names[nearest[i]] if i >= 0 else None for i in ids], dtype=object)


@pytest.fixture(scope="module")
def box_run(tmp_path_factory, text_embedder):
    out = tmp_path_factory.mktemp("boxrun") / "map.terra"
    return run_mapping(BoxScene(), MappingConfig(), out, show_progress=False)


def test_objects_and_terrain_of_the_box_scene(box_run, text_embedder):
    msm = load_map(box_run.bundle)
    labels = class_of_points(msm, text_embedder, ["car", "bench", "building"])
    car, bench, building = default_boxes()
    for box, name in ((car, "car"), (bench, "bench"), (building, "building")):
        sel = inside(msm.points, box) & (labels != None)  # noqa: E711
        assert sel.sum() >= 10, name
        assert np.mean(labels[sel] == name) == 1.0, name
    # Observed object points are inside some box, or on the ground right at its foot, where a
    # pixel straddles ground and object (at 30 m a pixel spans 0.3 m).
    observed = labels != None  # noqa: E711
    in_any = inside(msm.points, car) | inside(msm.points, bench) | inside(msm.points, building)
    near_any = inside(msm.points, car, 1.2) | inside(msm.points, bench, 1.2) | inside(msm.points, building, 1.2)
    assert np.all(near_any[observed]) and np.mean(in_any[observed]) > 0.95
    # Terrain votes: grass where y > 0, asphalt elsewhere, for ground points away from the boundary.
    ground = (np.abs(msm.points[:, 2]) < 0.05) & (np.abs(msm.points[:, 1]) > 0.4)
    t = msm.terrain_index()
    voted = ground & (t >= 0)
    assert voted.sum() > 200
    expected = np.where(msm.points[voted, 1] > 0, 0, 1)
    assert np.mean(t[voted] == expected) == 1.0
    # Points on objects get no terrain, but for the odd one on an object's silhouette edge, whose
    # pixel centre already shows the ground beside it.
    raised = np.abs(msm.points[:, 2]) > 0.3
    assert np.mean(t[raised] == -1) > 0.98
    assert box_run.bundle.manifest["embedder"]["name"] == text_embedder.name


def test_lidar_only_source_gives_a_full_map(tmp_path, text_embedder):
    scene = BoxScene(with_cameras=False)
    msm = load_map(build_map(scene, MappingConfig(), tmp_path / "lidar.terra", progress=False))
    assert len(msm.images) == 0
    labels = class_of_points(msm, text_embedder, ["car", "bench", "building"])
    car = default_boxes()[0]
    sel = inside(msm.points, car)
    assert np.mean(labels[sel] == "car") > 0.95
    assert msm.bank.shape[0] == 3
    ground = np.abs(msm.points[:, 2]) < 0.05
    t = msm.terrain_index()
    assert np.mean(t[ground & (msm.points[:, 1] > 0.4)] == 0) > 0.95
    lists, nearest = msm.images_observing(msm.points[:3])
    assert [len(x) for x in lists] == [0, 0, 0] and nearest.tolist() == [-1, -1, -1]


class Interrupted(Exception):
    pass


class FailingAfter(BoxScene):
    """A BoxScene whose loading dies when the mapping pass reaches frame `fail_at` (a simulated
    kill). Reading it earlier, out of order, as the dataset fingerprint reads the last frame
    during setup, does not count: the kill is meant to come after the last checkpoint."""

    fail_at: int = -1

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.read: set[int] = set()

    def __getitem__(self, index):
        if index == self.fail_at and index - 1 in self.read:
            raise Interrupted(f"killed at frame {index}")
        self.read.add(index)
        return super().__getitem__(index)


def test_resume_after_interruption_is_byte_identical(tmp_path, box_run, text_embedder):
    config = MappingConfig(checkpoint_every=2)
    reference = run_mapping(BoxScene(), config, tmp_path / "ref.terra", show_progress=False).bundle
    out = tmp_path / "map.terra"
    scene = FailingAfter()
    scene.fail_at = 5
    with pytest.raises(Interrupted):
        run_mapping(scene, config, out, show_progress=False)
    assert not out.exists() and (tmp_path / "map.terra.partial").is_dir()
    loaded = []

    class Counting(BoxScene):
        def __getitem__(self, index):
            loaded.append(index)
            return super().__getitem__(index)

    run = run_mapping(Counting(), config, out, show_progress=False)
    # The dataset fingerprint reads its sample frames first; then frames 0-3 are not redone.
    fingerprint_reads = sample_frames(len(BoxScene()))
    assert run.resumed_from == 4 and loaded == fingerprint_reads + [4, 5]
    assert not (tmp_path / "map.terra.partial").exists()
    assert folder_digest(out) == folder_digest(reference.path)
    # The default config (no checkpoint before the end) gives the same map too.
    assert folder_digest(box_run.bundle.path)["map/counts_indices.npy"] == folder_digest(out)["map/counts_indices.npy"]


class Faulty(BoxScene):
    """Frame 1: NaN points; 2: empty scan; 3: unreadable; 4: image stamp 1 s off; 6: non-finite
    pose; 7: label image of another size than its calibration; 8: scan of (n, 2) points."""

    def __init__(self):
        super().__init__(n_frames=9)

    def __getitem__(self, index):
        frame = super().__getitem__(index)
        if index == 1:
            frame.points[:7] = np.nan
        elif index == 2:
            frame.points = np.zeros((0, 3), np.float32)
            assert frame.point_labels is not None
            frame.point_labels = frame.point_labels[:0]
        elif index == 3:
            raise TerraError(f"frame{index}.npy: unreadable scan")
        elif index == 4:
            frame.cameras[0].stamp += 1.0
        elif index == 6:
            frame.T_map_lidar = np.full((4, 4), np.nan)
        elif index == 7:
            semantic = frame.cameras[0].semantic
            assert semantic is not None
            frame.cameras[0].semantic = semantic[:-1]
        elif index == 8:
            frame.points = frame.points[:, :2]
        return frame


def test_per_frame_faults_are_skipped_and_counted(tmp_path, text_embedder):
    run = run_mapping(Faulty(), MappingConfig(), tmp_path / "m.terra", show_progress=False)
    stats = run.stats
    assert stats["points_dropped_nonfinite"] == 7
    assert stats["frames_skipped_empty"] == 1
    assert stats["frames_skipped_unreadable"] == 1
    assert stats["images_skipped_unmatched_stamp"] == 1
    assert stats["frames_skipped_bad_pose"] == 1
    assert stats["images_skipped_bad_size"] == 1
    assert stats["frames_skipped_bad_points"] == 1
    assert stats["frames_fused"] == 5 and stats["images_fused"] == 3
    assert run.notes["frames_skipped_unreadable"] == "frame3.npy: unreadable scan"
    assert run.notes["frames_skipped_bad_pose"].startswith(
        "frame 6 (t = 6.000 s): T_map_lidar must be a finite 4x4 pose"
    )
    n8 = len(BoxScene(n_frames=9)[8].points)
    assert (
        run.notes["frames_skipped_bad_points"]
        == f"frame 8 (t = 8.000 s): points must be (N, 3) metres, got shape ({n8}, 2)"
    )
    assert (
        run.notes["images_skipped_unmatched_stamp"]
        == "front: image stamp 5.000 s is 1.000 s from its scan's 4.000 s (tolerance 0.1 s)"
    )
    assert (
        run.notes["images_skipped_bad_size"]
        == "front: semantic labels of (119, 160) pixels, calibration says (height, width) (120, 160)"
    )
    assert run.bundle.manifest["components"]["map"]["stats"] == stats
    assert len(load_map(run.bundle).images) == 3


class Broken(BoxScene):
    def __getitem__(self, index):
        raise TerraError(f"scan_{index}.bin: truncated file")


def test_structural_faults_stop_and_keep_the_old_bundle(tmp_path, box_run):
    out = tmp_path / "m.terra"
    run_mapping(BoxScene(n_frames=2), MappingConfig(), out, show_progress=False)
    before = folder_digest(out)
    with pytest.raises(TerraError, match="none of its 6 frames could be used.*scan_0.bin: truncated file"):
        run_mapping(Broken(), MappingConfig(), out, show_progress=False)
    assert folder_digest(out) == before
    Bundle(out).verify()
    user_folder = tmp_path / "photos"
    user_folder.mkdir()
    (user_folder / "a.jpg").write_bytes(b"x")
    with pytest.raises(TerraError, match="not a Terra bundle"):
        run_mapping(BoxScene(n_frames=1), MappingConfig(), user_folder, show_progress=False)
    assert (user_folder / "a.jpg").read_bytes() == b"x"
