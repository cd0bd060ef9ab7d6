"""The written files follow the reference folder layout (reference-notes.md section 1) and the
real SemanticKITTI conventions, checked by reading them with plain numpy / yaml / PIL / scipy the
way the authors' scripts and the SemanticKITTI tools do, not with Terra's readers."""

import json

import numpy as np
import pytest
import yaml
from PIL import Image
from scipy.spatial.transform import Rotation

from terra.sim.writer import write_dataset
from tests.datasets.fixtures import CLASSES, HEIGHT, STAMPS, WIDTH, HandDataset, calibrations


@pytest.fixture(scope="module")
def hand():
    return HandDataset()


@pytest.fixture(scope="module")
def folders(hand, tmp_path_factory):
    root = tmp_path_factory.mktemp("layout")
    return {
        fmt: write_dataset(hand, root / fmt, format=fmt, progress=False) for fmt in ("terra-folder", "semantickitti")
    }


def pose_from_file(values: np.ndarray) -> np.ndarray:
    """(7,) [tx ty tz qx qy qz qw] -> 4x4, as the reference does it (scipy from_quat)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(values[3:]).as_matrix()
    T[:3, 3] = values[:3]
    return T


def test_reference_folder_as_the_authors_scripts_read_it(hand, folders):
    root = folders["terra-folder"]
    cfg = yaml.safe_load((root / "msmap_camera_config.yaml").read_text())
    assert (cfg["IMG_W"], cfg["IMG_H"]) == (WIDTH, HEIGHT)
    assert cfg["cam_axis"] == ["+x", "+y"]  # forward camera, then the one looking left
    assert cfg["num_cams"] == 2  # cameras are numbered from 1, as in the authors' configs
    for n, cal in enumerate(calibrations(), start=1):
        assert cfg[f"cam{n}_K"] == cal.K.ravel().tolist()  # 9 floats, row-major
        assert cfg[f"cam{n}_dist"] == cal.dist.tolist()
    # The scan list is the pose folder sorted by the number after the last '_'; every other file's
    # name is rebuilt from that number with exactly six decimals.
    pose_files = sorted(
        (root / "transformations_lidar2global").iterdir(), key=lambda p: float(p.stem.rsplit("_", 1)[-1])
    )
    stamps = [float(p.stem.rsplit("_", 1)[-1]) for p in pose_files]
    assert stamps == list(STAMPS)
    for t, pose_file, frame in zip(stamps, pose_files, hand.frames):
        assert pose_file.name == f"transform_lidar_to_map_{t:.6f}.npy"
        pose = np.load(pose_file)
        assert pose.shape == (7,)
        np.testing.assert_allclose(pose_from_file(pose), frame.T_map_lidar, atol=1e-12)
        scan = np.load(root / "lidar_pc" / f"lidar_pc_{t:.6f}.npy")
        assert scan.shape == (len(frame.points), 4) and scan.dtype == np.float32  # x, y, z, intensity; LiDAR frame
        np.testing.assert_array_equal(scan[:, :3], frame.points)
        np.testing.assert_array_equal(scan[:, 3], frame.intensity)
        labels = np.load(root / "lidar_labels" / f"lidar_labels_{t:.6f}.npy")
        np.testing.assert_array_equal(labels, np.stack([frame.point_labels, frame.point_instances], 1))
        for n, cam in enumerate(frame.cameras, start=1):
            with Image.open(root / f"camera{n}_images" / f"cam{n}_img_{t:.6f}.jpg") as im:
                assert im.format == "JPEG" and im.size == (cfg["IMG_W"], cfg["IMG_H"])
            tf = np.load(root / f"transformations_lidar2cam{n}" / f"transform_lidar_to_cam{n}_{t:.6f}.npy")
            # lidar -> cam is T_cam<-lidar: p_c = R p_L + t.
            p_lidar = np.array([3.0, -1.0, 0.5])
            np.testing.assert_allclose(
                Rotation.from_quat(tf[3:]).apply(p_lidar) + tf[:3],
                cam.calibration.T_cam_lidar[:3, :3] @ p_lidar + cam.calibration.T_cam_lidar[:3, 3],
                atol=1e-12,
            )
            with Image.open(root / f"camera{n}_semantic" / f"cam{n}_sem_{t:.6f}.png") as im:
                np.testing.assert_array_equal(np.asarray(im), cam.semantic)
    # Only the global map with the largest stamp is used, and only its [:, :3], in the map frame.
    global_files = sorted((root / "global_pc").glob("global_pc_*.npy"), key=lambda p: float(p.stem.rsplit("_", 1)[-1]))
    assert global_files[-1].name == f"global_pc_{max(STAMPS):.6f}.npy"
    cloud = np.load(global_files[-1])
    assert cloud.ndim == 2 and cloud.shape[1] == 4
    first = hand.frames[0]
    in_map = first.points.astype(np.float64) @ first.T_map_lidar[:3, :3].T + first.T_map_lidar[:3, 3]
    nearest = np.min(np.linalg.norm(in_map[:50, None, :] - cloud[None, :, :3], axis=2), axis=1)
    assert nearest.max() < 0.4 * np.sqrt(3)  # every scan point lies within its voxel's centroid cell
    meta = json.loads((root / "terra_dataset.json").read_text())
    assert meta["frames"] == len(STAMPS)


def read_calib(path):
    out = {}
    for line in path.read_text().splitlines():
        key, values = line.split(":", 1)
        out[key] = np.array(values.split(), float)
    return out


def test_semantickitti_conventions(hand, folders):
    root = folders["semantickitti"]
    seq = root / "sequences" / "00"
    calib = read_calib(seq / "calib.txt")
    assert set(calib) == {"P0", "P1", "P2", "P3", "Tr"} and all(v.size == 12 for v in calib.values())
    Tr = np.vstack([calib["Tr"].reshape(3, 4), [0, 0, 0, 1]])
    front, left = calibrations()
    np.testing.assert_array_equal(Tr, front.T_cam_lidar)  # camera 0 is the first camera
    np.testing.assert_allclose(calib["P2"].reshape(3, 4), np.hstack([front.K, np.zeros((3, 1))]), atol=1e-12)
    # P3 projects camera-0 coordinates into the second camera.
    p_lidar = np.array([2.0, 7.0, 0.3])
    p_cam0 = Tr[:3, :3] @ p_lidar + Tr[:3, 3]
    uvw = calib["P3"].reshape(3, 4) @ np.r_[p_cam0, 1.0]
    expected = left.K @ (left.T_cam_lidar[:3, :3] @ p_lidar + left.T_cam_lidar[:3, 3])
    np.testing.assert_allclose(uvw[:2] / uvw[2], expected[:2] / expected[2], atol=1e-9)
    poses = np.loadtxt(seq / "poses.txt")
    assert poses.shape == (len(STAMPS), 12)
    np.testing.assert_array_equal(np.loadtxt(seq / "times.txt"), STAMPS)
    legend = yaml.safe_load((root / "semantic-kitti.yaml").read_text())["labels"]
    sk = {
        c.id: (
            c.semantickitti_id if c.semantickitti_id is not None else next(k for k, v in legend.items() if v == c.name)
        )
        for c in CLASSES
    }
    assert sk[23] >= 100 and legend[10] == "car" and legend[40] == "asphalt"
    for i, frame in enumerate(hand.frames):
        scan = np.fromfile(seq / "velodyne" / f"{i:06d}.bin", dtype=np.float32).reshape(-1, 4)
        np.testing.assert_array_equal(scan, np.c_[frame.points, frame.intensity])
        value = np.fromfile(seq / "labels" / f"{i:06d}.label", dtype=np.uint32)
        np.testing.assert_array_equal(value & 0xFFFF, [sk[c] for c in frame.point_labels])
        np.testing.assert_array_equal(value >> 16, frame.point_instances)
        P = np.vstack([poses[i].reshape(3, 4), [0, 0, 0, 1]])  # camera-0 pose
        np.testing.assert_allclose(np.linalg.inv(Tr) @ P @ Tr, frame.T_map_lidar, atol=1e-12)
        for k, cam in zip((2, 3), frame.cameras):
            with Image.open(seq / f"image_{k}" / f"{i:06d}.png") as im:
                np.testing.assert_array_equal(np.asarray(im.convert("RGB")), cam.image)
            with Image.open(seq / f"image_{k}_semantic" / f"{i:06d}.png") as im:
                np.testing.assert_array_equal(np.asarray(im), np.vectorize(sk.get)(cam.semantic))
