"""The loader registry detects both formats; corrupt or missing files give one line naming the file."""

import json
import shutil

import numpy as np
import pytest

from terra.datasets import loader_names, open_dataset
from terra.datasets.semantickitti import SemanticKittiDataset, decompose_projection
from terra.datasets.terra_folder import TerraFolderDataset
from terra.errors import TerraError
from terra.geometry import make_pose
from terra.sim.writer import write_dataset
from tests.datasets.fixtures import HandDataset


@pytest.fixture(scope="module")
def originals(tmp_path_factory):
    root = tmp_path_factory.mktemp("readers")
    hand = HandDataset()
    return {
        fmt: write_dataset(hand, root / fmt, format=fmt, progress=False) for fmt in ("terra-folder", "semantickitti")
    }


@pytest.fixture
def copy(originals, tmp_path):
    """A fresh copy of a written folder that a test may damage."""

    def make(fmt):
        return shutil.copytree(originals[fmt], tmp_path / fmt)

    return make


def test_registry_detects_both_formats(originals):
    assert {"terra-folder", "semantickitti"} <= set(loader_names())
    assert isinstance(open_dataset(originals["terra-folder"]), TerraFolderDataset)
    assert isinstance(open_dataset(originals["semantickitti"], format="auto"), SemanticKittiDataset)
    # A sequence folder itself opens too, as do the explicit names.
    assert len(open_dataset(originals["semantickitti"] / "sequences" / "00")) == 3
    assert isinstance(open_dataset(originals["terra-folder"], format="terra-folder"), TerraFolderDataset)


def test_registry_errors(originals, tmp_path):
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.txt").write_text("x")
    with pytest.raises(
        TerraError,
        match=r"photos: not a recognised dataset\. Recognised formats: terra-folder: .*; semantickitti: .*; "
        r"kitti-raw: KITTI raw drives .*; rosbag: ROS 1 \.bag",
    ):
        open_dataset(tmp_path / "photos")
    with pytest.raises(TerraError, match="does not exist"):
        open_dataset(tmp_path / "missing")
    with pytest.raises(TerraError, match="unknown dataset format 'rosbag3'"):
        open_dataset(originals["terra-folder"], format="rosbag3")
    with pytest.raises(TerraError, match="not a terra-folder dataset"):
        open_dataset(originals["semantickitti"], format="terra-folder")
    seqs = tmp_path / "two"
    for s in ("00", "01"):
        (seqs / "sequences" / s / "velodyne").mkdir(parents=True)
    with pytest.raises(TerraError, match="2 sequences; open one of them"):
        open_dataset(seqs)


def first(folder, pattern):
    return sorted(folder.glob(pattern))[0]


def damage_terra_folder(root, what):
    if what == "truncated scan":
        path = first(root / "lidar_pc", "*.npy")
        path.write_bytes(path.read_bytes()[:200])
    elif what == "scan shape":
        path = first(root / "lidar_pc", "*.npy")
        np.save(path, np.zeros((10, 3), np.float32))
    elif what == "labels length":
        path = first(root / "lidar_labels", "*.npy")
        np.save(path, np.zeros((3, 2), np.int32))
    elif what == "pose shape":
        path = first(root / "transformations_lidar2global", "*.npy")
        np.save(path, np.zeros(6))
    elif what == "pose quaternion":
        path = first(root / "transformations_lidar2global", "*.npy")
        np.save(path, np.zeros(7))
    elif what == "not npy":
        path = first(root / "lidar_pc", "*.npy")
        path.write_text("hello")
    elif what == "image":
        path = first(root / "camera2_images", "*.jpg")
        path.write_bytes(b"\xff\xd8\xff garbage")
    elif what == "label image":
        path = first(root / "camera1_instance", "*.png")
        path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"x" * 20)
    elif what == "meta":
        path = root / "terra_dataset.json"
        path.write_text("{not json")
    elif what == "classes":
        path = root / "classes.json"
        path.write_text('{"classes": [{"name": "x"}]}')
    elif what == "camera translation 1e308":
        path = root / "terra_dataset.json"
        doc = json.loads(path.read_text())
        doc["cameras"][0]["T_cam_lidar"][0][3] = -1e308  # finite, but no real mount
        path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize(
    "what",
    [
        "truncated scan",
        "scan shape",
        "labels length",
        "pose shape",
        "pose quaternion",
        "not npy",
        "image",
        "label image",
        "meta",
        "classes",
        "camera translation 1e308",
    ],
)
def test_terra_folder_corrupt_file_names_the_file(copy, what):
    root = copy("terra-folder")
    path = damage_terra_folder(root, what)
    with pytest.raises(TerraError) as info:
        ds = open_dataset(root)
        for i in range(len(ds)):
            ds[i]
    message = str(info.value)
    assert message.startswith(str(path)) and "\n" not in message
    if what == "camera translation 1e308":
        assert "T_cam_lidar's translation must be within +-1e+07 m per axis, got 1e+308 m" in message
    if what == "Tr translation 1e308":
        assert (
            message
            == f"{path}:5: Tr's translation must be within +-1e+07 m per axis, got 1e+308 m (a typo or an overflow)"
        )


def test_terra_folder_missing_images_skip_scans_like_the_reference(copy):
    root = copy("terra-folder")
    first(root / "camera1_images", "*.jpg").unlink()  # the first scan has no image within 0.2 s
    ds = open_dataset(root)
    assert isinstance(ds, TerraFolderDataset)
    assert [ds[i].stamp for i in range(len(ds))] == [100.25, 100.625]
    assert ds.skipped == {"scans_unaligned": 1}
    assert ds.skipped_notes["scans_unaligned"].endswith("nearest camera 1 image is 0.250 s away (tolerance 0.2 s)")
    for p in (root / "camera2_images").iterdir():
        p.rename(p.with_name(p.name.replace("_100.", "_103.")))  # every image 3 s late
    with pytest.raises(TerraError, match="no scan with a pose, a LiDAR file and every camera image within 0.2 s"):
        open_dataset(root)
    for p in (root / "camera1_images").iterdir():
        p.unlink()  # a calibrated camera without images is an error, not a silent LiDAR-only run
    with pytest.raises(
        TerraError,
        match=r"terra_dataset.json: calibrates cameras 1, 2 but .* has image folders "
        r"camera2_images/: no images for camera 1$",
    ):
        open_dataset(root)


def damage_kitti(root, what):
    seq = root / "sequences" / "00"
    if what == "bin size":
        path = seq / "velodyne" / "000001.bin"
        path.write_bytes(path.read_bytes()[:-2])
    elif what == "label count":
        path = seq / "labels" / "000001.label"
        path.write_bytes(path.read_bytes()[:-8])
    elif what == "poses lines":
        path = seq / "poses.txt"
        path.write_text("\n".join(path.read_text().splitlines()[:2]) + "\n")
    elif what == "poses text":
        path = seq / "poses.txt"
        path.write_text(path.read_text().replace("0", "zero", 1))
    elif what == "missing poses":
        path = seq / "poses.txt"
        path.unlink()
        path = seq
    elif what == "times":
        path = seq / "times.txt"
        path.write_text("1.0\n2.0\n")
    elif what == "calib":
        path = seq / "calib.txt"
        path.write_text("P0: 1 2 3\nTr: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    elif what == "Tr translation 1e308":
        path = seq / "calib.txt"
        text = path.read_text().splitlines()
        row = text[-1].split()
        row[4] = "1e308"  # Tr's x translation: a finite number that overflows any product
        path.write_text("\n".join(text[:-1] + [" ".join(row)]) + "\n")
    elif what == "cameras json":
        path = seq / "terra_cameras.json"
        path.write_text('{"cameras": [{"name": "x"}]}')
    elif what == "image":
        path = seq / "image_3" / "000001.png"
        path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"x" * 20)
    elif what == "legend":
        path = root / "semantic-kitti.yaml"
        path.write_text("labels: [unclosed")
    return path


@pytest.mark.parametrize(
    "what",
    [
        "bin size",
        "label count",
        "poses lines",
        "poses text",
        "missing poses",
        "times",
        "calib",
        "Tr translation 1e308",
        "cameras json",
        "image",
        "legend",
    ],
)
def test_semantickitti_corrupt_file_names_the_file(copy, what):
    root = copy("semantickitti")
    path = damage_kitti(root, what)
    with pytest.raises(TerraError) as info:
        ds = open_dataset(root)
        for i in range(len(ds)):
            ds[i]
    message = str(info.value)
    assert message.startswith(str(path)) and "\n" not in message
    if what == "camera translation 1e308":
        assert "T_cam_lidar's translation must be within +-1e+07 m per axis, got 1e+308 m" in message
    if what == "Tr translation 1e308":
        assert (
            message
            == f"{path}:5: Tr's translation must be within +-1e+07 m per axis, got 1e+308 m (a typo or an overflow)"
        )


def test_decompose_projection_recovers_scaled_and_rotated_cameras():
    K = np.array([[500.0, 0.5, 320.0], [0.0, 480.0, 240.0], [0.0, 0.0, 1.0]])
    c, s = np.cos(0.4), np.sin(0.4)
    T = make_pose(np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]), np.array([0.54, -0.1, 0.02]))
    for scale in (1.0, -2.5):
        got_K, got_T = decompose_projection(scale * K @ T[:3])
        np.testing.assert_allclose(got_K, K, atol=1e-9)
        np.testing.assert_allclose(got_T, T, atol=1e-12)


def test_folder_extracted_by_the_authors_tools(copy):
    """No Terra extras: intrinsics from the msmap config keys, extrinsics from the per-scan
    lidar2cam files, and images matched to scans by the nearest stamp within 0.2 s."""
    root = copy("terra-folder")
    for extra in ("terra_dataset.json", "classes.json"):
        (root / extra).unlink()
    for extra in (
        "lidar_labels",
        "camera1_semantic",
        "camera1_instance",
        "camera2_semantic",
        "camera2_instance",
        "ground_truth",
    ):
        shutil.rmtree(root / extra)
    # The camera driver stamps images a little after the scan: 0.05 s is matched, 0.3 s is not.
    for n, delay in ((1, 0.05), (2, 0.05)):
        for p in sorted((root / f"camera{n}_images").iterdir()):
            t = float(p.stem.rsplit("_", 1)[-1])
            p.rename(p.with_name(f"cam{n}_img_{t + delay + (0.25 if t == 100.625 else 0.0):.6f}.jpg"))
    ds = open_dataset(root)
    hand = HandDataset()
    assert len(ds) == 2 and ds.classes.by_id(0).name == "unlabeled" and len(ds.classes) == 1
    for i in range(2):
        frame, expected = ds[i], hand.frames[i]
        assert frame.point_labels is None and frame.cameras[0].semantic is None
        np.testing.assert_array_equal(frame.points, expected.points)
        assert frame.cameras[1].stamp == pytest.approx(expected.stamp + 0.05, abs=1e-9)
        for cam, exp in zip(frame.cameras, expected.cameras):
            np.testing.assert_array_equal(cam.calibration.K, exp.calibration.K)
            np.testing.assert_array_equal(cam.calibration.dist, exp.calibration.dist)
            np.testing.assert_allclose(cam.calibration.T_cam_lidar, exp.calibration.T_cam_lidar, atol=1e-12)
    global_map = ds.global_map()
    assert global_map is not None and global_map.shape[1] == 3


@pytest.mark.parametrize(("name", "kind"), [("drive.pcap", "raw sensor packets"), ("scan.pcd", "one point cloud")])
def test_unread_file_kinds_are_named_with_the_recognised_formats(tmp_path, capsys, name, kind):
    """A pcap or PCD file: one line saying what the file is and which formats Terra reads."""
    from terra.cli import run

    (tmp_path / name).write_bytes(b"\xd4\xc3\xb2\xa1" + bytes(20))
    assert run(["map", str(tmp_path / name), "--out", str(tmp_path / "x.terra")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{name}: not a recognised dataset" in err and kind in err
    for format in loader_names():
        assert f"{format}: " in err
    assert not (tmp_path / "x.terra").exists()
