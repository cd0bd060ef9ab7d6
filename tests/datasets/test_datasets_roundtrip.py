"""Writer-then-reader round trips of both dataset formats on a hand-built dataset."""

import numpy as np
import pytest

from terra.datasets import open_dataset
from terra.datasets.ground_truth import load_ground_truth, write_ground_truth
from terra.sim.writer import write_dataset
from tests.datasets.fixtures import CLASSES, STAMPS, HandDataset, calibrations


@pytest.fixture(scope="module")
def hand():
    return HandDataset()


@pytest.fixture(scope="module")
def written(hand, tmp_path_factory):
    root = tmp_path_factory.mktemp("formats")
    return {
        fmt: write_dataset(hand, root / fmt, format=fmt, progress=False) for fmt in ("terra-folder", "semantickitti")
    }


def assert_same_calibration(got, expected):
    assert (got.width, got.height) == (expected.width, expected.height)
    np.testing.assert_array_equal(got.K, expected.K)
    np.testing.assert_array_equal(got.dist, expected.dist)
    np.testing.assert_array_equal(got.T_cam_lidar, expected.T_cam_lidar)


@pytest.mark.parametrize("fmt", ["terra-folder", "semantickitti"])
def test_frames_round_trip(hand, written, fmt):
    ds = open_dataset(written[fmt])
    assert len(ds) == len(hand)
    assert [c.name for c in ds.classes] == [c.name for c in CLASSES]
    assert [c.id for c in ds.classes.terrain_classes] == [1, 3]
    for i, expected in enumerate(hand.frames):
        got = ds[i]
        assert got.stamp == expected.stamp
        np.testing.assert_array_equal(got.points, expected.points)
        assert got.intensity is not None
        assert got.points.dtype == np.float32 and got.intensity.dtype == np.float32
        np.testing.assert_array_equal(got.intensity, expected.intensity)
        np.testing.assert_array_equal(got.point_labels, expected.point_labels)
        np.testing.assert_array_equal(got.point_instances, expected.point_instances)
        # Poses go through a quaternion (terra-folder) or Tr^-1 P Tr (SemanticKITTI): exact to rounding.
        np.testing.assert_allclose(got.T_map_lidar, expected.T_map_lidar, rtol=0, atol=1e-12)
        assert len(got.cameras) == 2
        for cam, exp in zip(got.cameras, expected.cameras):
            assert cam.stamp == exp.stamp
            assert_same_calibration(cam.calibration, exp.calibration)
            np.testing.assert_array_equal(cam.semantic, exp.semantic)
            np.testing.assert_array_equal(cam.instance, exp.instance)
            if fmt == "semantickitti":  # PNG: lossless
                np.testing.assert_array_equal(cam.image, exp.image)
            else:  # the reference layout's images are JPEG: close, not equal
                err = np.abs(cam.image.astype(int) - exp.image)
                assert cam.image.shape == exp.image.shape and err.mean() < 2.0 and np.percentile(err, 99) < 12


def voxel_centroids(frames, leaf=0.4):
    """Independent reference: mean map-frame point and intensity per occupied voxel, sorted."""
    pts = np.concatenate([f.points.astype(np.float64) @ f.T_map_lidar[:3, :3].T + f.T_map_lidar[:3, 3] for f in frames])
    rows = np.c_[pts, np.concatenate([f.intensity for f in frames])]
    _, inverse = np.unique(np.floor(pts / leaf).astype(np.int64), axis=0, return_inverse=True)
    inverse = inverse.ravel()
    means = np.stack([np.bincount(inverse, rows[:, k]) for k in range(4)], 1) / np.bincount(inverse)[:, None]
    return sort_rows(means)


def sort_rows(a):
    return a[np.lexsort(a.T[::-1])]


def test_terra_folder_global_map_is_voxel_centroids(hand, written):
    """global_pc holds the mean map-frame point of every occupied 0.4 m voxel of all scans."""
    got = open_dataset(written["terra-folder"]).global_map()
    expected = voxel_centroids(hand.frames)
    assert got is not None and got.shape == (len(expected), 3)
    np.testing.assert_allclose(sort_rows(got), expected[:, :3], atol=1e-4)


def test_global_map_accumulator_flushing_in_pieces_changes_nothing(hand):
    """The writer reduces as it goes (memory follows the map): flushing every 100 points gives
    the same centroids and intensities as the reference computed at once."""
    from terra.datasets.terra_folder import GlobalMapAccumulator

    acc = GlobalMapAccumulator(flush_every=100)
    for f in hand.frames:
        acc.add(f.points.astype(np.float64) @ f.T_map_lidar[:3, :3].T + f.T_map_lidar[:3, 3], f.intensity)
    np.testing.assert_allclose(sort_rows(acc.result()), voxel_centroids(hand.frames), atol=1e-4)


@pytest.mark.parametrize("fmt", ["terra-folder", "semantickitti"])
def test_ground_truth_round_trip(hand, written, fmt, tmp_path):
    gt, got = hand.gt, load_ground_truth(written[fmt])
    for a, b in zip(got.objects, gt.objects):
        assert (a.instance_id, a.class_id, a.class_name) == (b.instance_id, b.class_id, b.class_name)
        np.testing.assert_allclose(np.r_[a.center, a.size, a.yaw], np.r_[b.center, b.size, b.yaw], atol=5e-7)
    assert len(got.objects) == len(gt.objects)
    assert got.terrain is not None and gt.terrain is not None
    np.testing.assert_array_equal(got.terrain.classes, gt.terrain.classes)
    np.testing.assert_array_equal(got.terrain.ground_height, gt.terrain.ground_height)
    np.testing.assert_array_equal(got.terrain.origin, gt.terrain.origin)
    assert got.terrain.resolution == gt.terrain.resolution and got.terrain.legend == gt.terrain.legend
    assert [(r.name, r.description) for r in got.regions] == [(r.name, r.description) for r in gt.regions]
    np.testing.assert_allclose(got.regions[0].polygon, gt.regions[0].polygon, atol=5e-7)
    # Reading and writing again reproduces the files byte for byte.
    write_ground_truth(tmp_path, got)
    for name in ("objects.json", "objects.csv", "terrain.npy", "ground_height.npy", "terrain.json", "regions.json"):
        assert (tmp_path / "ground_truth" / name).read_bytes() == (written[fmt] / "ground_truth" / name).read_bytes()


def test_semantickitti_without_terra_extras_reads_like_real_kitti(hand, written, tmp_path):
    """Only the files the real dataset has: classes from SemanticKITTI's table, cameras from P2/P3."""
    import shutil

    root = tmp_path / "kitti"
    seq = root / "sequences" / "00"
    shutil.copytree(
        written["semantickitti"] / "sequences" / "00",
        seq,
        ignore=shutil.ignore_patterns("*_semantic", "*_instance", "terra_cameras.json"),
    )
    ds = open_dataset(root, format="semantickitti")
    assert ds.classes.by_id(10).name == "car" and ds.classes.by_id(48).terrain
    frame = ds[1]
    expected = hand.frames[1]
    sk = {c.id: c.semantickitti_id for c in CLASSES}
    assert frame.point_labels is not None and expected.point_labels is not None
    known = np.isin(expected.point_labels, [i for i, k in sk.items() if k is not None])
    np.testing.assert_array_equal(frame.point_labels[known], [sk[i] for i in expected.point_labels[known]])
    np.testing.assert_allclose(frame.T_map_lidar, expected.T_map_lidar, atol=1e-12)
    # KITTI's P matrices carry intrinsics and extrinsics but no distortion.
    for cam, cal in zip(frame.cameras, calibrations()):
        np.testing.assert_allclose(cam.calibration.K, cal.K, atol=1e-9)
        np.testing.assert_allclose(cam.calibration.T_cam_lidar, cal.T_cam_lidar, atol=1e-9)
        assert not np.any(cam.calibration.dist)
    assert [c.name for c in frame.cameras] == ["sequences/00/image_2/000001.png", "sequences/00/image_3/000001.png"]


def test_stamps_are_written_with_six_decimals(written):
    names = sorted(p.name for p in (written["terra-folder"] / "lidar_pc").iterdir())
    assert names == [f"lidar_pc_{t:.6f}.npy" for t in STAMPS]
