"""KITTI raw drives as the dataset ships them: a drive written here by hand with KITTI's own
2011_09_26 calibration text, read back and checked against hand-worked values (devkit projection,
Mercator poses, date-time stamps); bad files give one line naming the file, line and key."""

import math
import shutil

import numpy as np
import pytest
from PIL import Image

from terra.cli import run
from terra.datasets import open_dataset
from terra.datasets.kitti_common import parse_timestamp, read_calib_file
from terra.datasets.kitti_raw import KittiRawConfig, KittiRawDataset
from terra.datasets.oxts import normalise_poses, world_poses
from terra.errors import TerraError
from terra.geometry import project_points, transform_points

CAM_TO_CAM = (
    "calib_time: 09-Jan-2012 13:57:47\n"
    "corner_dist: 9.950000e-02\n"
    "S_00: 1.392000e+03 5.120000e+02\n"
    "K_00: 9.842439e+02 0.000000e+00 6.900000e+02 0.000000e+00 9.808141e+02 2.331966e+02 0.000000e+00 "
    "0.000000e+00 1.000000e+00\n"
    "D_00: -3.728755e-01 2.037299e-01 2.219027e-03 1.383707e-03 -7.233722e-02\n"
    "R_00: 1.000000e+00 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00 0.000000e+00 "
    "0.000000e+00 1.000000e+00\n"
    "T_00: 2.573699e-16 -1.059758e-16 1.614870e-16\n"
    "S_rect_00: 1.242000e+03 3.750000e+02\n"
    "R_rect_00: 9.999239e-01 9.837760e-03 -7.445048e-03 -9.869795e-03 9.999421e-01 -4.278459e-03 "
    "7.402527e-03 4.351614e-03 9.999631e-01\n"
    "P_rect_00: 7.215377e+02 0.000000e+00 6.095593e+02 0.000000e+00 0.000000e+00 7.215377e+02 1.728540e+02 "
    "0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00\n"
    "S_rect_02: 1.242000e+03 3.750000e+02\n"
    "R_rect_02: 9.998817e-01 1.511453e-02 -2.841595e-03 -1.511724e-02 9.998853e-01 -9.338510e-04 "
    "2.827154e-03 9.766976e-04 9.999955e-01\n"
    "P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01 0.000000e+00 7.215377e+02 1.728540e+02 "
    "2.163791e-01 0.000000e+00 0.000000e+00 1.000000e+00 2.745884e-03\n"
)
VELO_TO_CAM = (
    "calib_time: 15-Mar-2012 11:37:16\n"
    "R: 7.533745e-03 -9.999714e-01 -6.166020e-04 1.480249e-02 7.280733e-04 -9.998902e-01 9.998621e-01 "
    "7.523790e-03 1.480755e-02\n"
    "T: -4.069766e-03 -7.631618e-02 -2.717806e-01\n"
    "delta_f: 0.000000e+00 0.000000e+00\n"
    "delta_c: 0.000000e+00 0.000000e+00\n"
)
IMU_TO_VELO = (
    "calib_time: 25-May-2012 16:47:16\n"
    "R: 9.999976e-01 7.553071e-04 -2.035826e-03 -7.854027e-04 9.998898e-01 -1.482298e-02 2.024406e-03 "
    "1.482454e-02 9.998881e-01\n"
    "T: -8.086759e-01 3.195559e-01 -7.997231e-01\n"
)
STAMPS = ["2011-09-26 13:02:25.964389445", "2011-09-26 13:02:26.068424730", "2011-09-26 13:02:26.172421666"]
IMAGE_STAMPS = ["2011-09-26 13:02:25.951199337", "2011-09-26 13:02:26.054421066", "2011-09-26 13:02:26.157975347"]
# Hand-chosen packets: at rest heading east; 0.001 degrees of longitude further, 1.5 m higher, heading
# north; 0.001 degrees of latitude further north, rolled and pitched.
PACKETS = [
    (49.0, 8.4, 100.0, 0.0, 0.0, 0.0),
    (49.0, 8.401, 101.5, 0.0, 0.0, math.pi / 2),
    (49.001, 8.4, 100.0, 0.1, -0.2, 0.0),
]
REST = "0.1 0.2 0.3 0.4 0.5 0.01 0.02 9.81 0.01 0.02 9.81 0.001 0.002 0.003 0.001 0.002 0.003 0.05 0.05 4 10 4 4 0"


def matrix(text: str, key: str, shape) -> np.ndarray:
    """A calibration entry parsed with plain Python, for the hand computations."""
    line = next(line for line in text.splitlines() if line.startswith(key + ":"))
    return np.array([float(v) for v in line.split(":", 1)[1].split()]).reshape(shape)


def write_drive(root, points_per_scan=50, seed=0):
    """DATE/DATE_drive_0005_sync with three scans, image_02, OXTS, as KITTI ships them."""
    rng = np.random.default_rng(seed)
    date = root / "2011_09_26"
    drive = date / "2011_09_26_drive_0005_sync"
    for sub in ("velodyne_points/data", "image_02/data", "oxts/data"):
        (drive / sub).mkdir(parents=True)
    (date / "calib_cam_to_cam.txt").write_text(CAM_TO_CAM)
    (date / "calib_velo_to_cam.txt").write_text(VELO_TO_CAM)
    (date / "calib_imu_to_velo.txt").write_text(IMU_TO_VELO)
    for i, packet in enumerate(PACKETS):
        name = f"{i:010d}"
        scan = np.c_[rng.uniform(-20, 20, (points_per_scan, 3)), rng.uniform(0, 1, points_per_scan)].astype(np.float32)
        scan.tofile(drive / "velodyne_points" / "data" / f"{name}.bin")
        Image.fromarray(rng.integers(0, 255, (375, 1242, 3), dtype=np.uint8)).save(
            drive / "image_02" / "data" / f"{name}.png"
        )
        (drive / "oxts" / "data" / f"{name}.txt").write_text(" ".join(repr(v) for v in packet) + " " + REST + "\n")
    for folder, stamps in (("velodyne_points", STAMPS), ("image_02", IMAGE_STAMPS), ("oxts", STAMPS)):
        (drive / folder / "timestamps.txt").write_text("\n".join(stamps) + "\n")
    return drive


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    return write_drive(tmp_path_factory.mktemp("kitti"))


@pytest.fixture
def copy(drive, tmp_path):
    shutil.copytree(drive.parent, tmp_path / "raw" / drive.parent.name)
    return tmp_path / "raw" / drive.parent.name / drive.name


def test_stamps_as_kitti_writes_them():
    # 2011-09-26 13:02:25 UTC is 1317042145 s after 1970; the nine decimals are nanoseconds.
    assert parse_timestamp("2011-09-26 13:02:25.964389445") == pytest.approx(1317042145.964389445, abs=1e-6)
    assert parse_timestamp("2011-09-26 13:02:25") == 1317042145.0
    for bad in (
        "2011-09-26T13:02:25.9",
        "26.09.2011 13:02:25",
        "2011-09-26 13:02:25.12345678901",
        "2011-09-26 25:02:25.1",
    ):
        with pytest.raises(ValueError):
            parse_timestamp(bad)


def test_calibration_files_parse_with_their_text_keys(drive):
    calib = read_calib_file(drive.parent / "calib_cam_to_cam.txt")
    assert calib.text["calib_time"] == "09-Jan-2012 13:57:47" and "calib_time" not in calib
    assert calib.lines["P_rect_02"] == 13 and calib.matrix("S_rect_02", (2,)).tolist() == [1242.0, 375.0]
    # The tracking benchmark writes some keys without a colon.
    tracking = drive.parent / "tracking_calib.txt"
    tracking.write_text(
        "P2: 1 0 0 0 0 1 0 0 0 0 1 0\nR_rect 1 0 0 0 1 0 0 0 1\nTr_velo_cam 0 -1 0 0 0 0 -1 0 1 0 0 0\n"
    )
    parsed = read_calib_file(tracking)
    assert (
        parsed.matrix("R_rect", (3, 3)).tolist() == np.eye(3).tolist() and parsed.pose_3x4("Tr_velo_cam")[2, 0] == 1.0
    )


def test_cameras_project_like_the_devkit(drive):
    """u, v of a Velodyne point by the devkit's chain P_rect_02 R_rect_00 [R | T], computed here
    with plain numpy from the file text, equal Terra's projection through the camera it reads."""
    ds = open_dataset(drive)
    assert isinstance(ds, KittiRawDataset) and [c.name for c in ds.cameras] == ["image_02"]
    cam = ds.cameras[0]
    assert (cam.width, cam.height) == (1242, 375) and cam.dist.size == 0
    R_rect = np.eye(4)
    R_rect[:3, :3] = matrix(CAM_TO_CAM, "R_rect_00", (3, 3))
    velo_to_cam = np.eye(4)
    velo_to_cam[:3, :3], velo_to_cam[:3, 3] = matrix(VELO_TO_CAM, "R", (3, 3)), matrix(VELO_TO_CAM, "T", (3,))
    points = np.array([[12.0, 1.5, -0.8], [25.0, -6.0, 1.2], [7.5, 3.0, -1.6]])
    uvw = matrix(CAM_TO_CAM, "P_rect_02", (3, 4)) @ R_rect @ velo_to_cam @ np.c_[points, np.ones(3)].T
    expected = (uvw[:2] / uvw[2]).T
    uv, valid = project_points(transform_points(cam.T_cam_lidar, points), cam)
    assert valid.all()
    np.testing.assert_allclose(uv, expected, atol=1e-9)


def test_oxts_poses_against_hand_worked_values(drive):
    """Scale cos(49 deg) from the first latitude: 0.001 deg of longitude east is
    6378137 cos(49 deg) 0.001 pi / 180 = 73.0322 m; 0.001 deg of latitude north is
    cos(49 deg) 6378137 [ln tan(69.5005 deg) - ln tan(69.5 deg)] = 111.3206 m (R dphi = 111.3195 m
    plus R tan(phi) dphi^2 / 2 = 1.1 mm)."""
    packets = np.array([list(p) + [float(v) for v in REST.split()] for p in PACKETS])
    T = normalise_poses(world_poses(packets))
    np.testing.assert_allclose(T[0], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(T[1, :3, 3], [73.0322, 0.0, 1.5], atol=1e-4)
    np.testing.assert_allclose(T[1, :3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)  # forward is north
    np.testing.assert_allclose(T[2, :3, 3], [0.0, 111.3206, 0.0], atol=1e-4)
    forward, left = T[2, :3, 0], T[2, :3, 1]
    assert forward[2] == pytest.approx(math.sin(0.2))  # pitch -0.2: the front is up
    assert left[2] == pytest.approx(math.sin(0.1) * math.cos(0.2))  # roll 0.1: the left side is up
    devkit = normalise_poses(world_poses(packets), "first-pose")
    np.testing.assert_allclose(devkit, np.linalg.inv(T[0]) @ T, atol=1e-9)  # the first pose is the identity already
    ds = open_dataset(drive)
    velo_imu = np.eye(4)
    velo_imu[:3, :3], velo_imu[:3, 3] = matrix(IMU_TO_VELO, "R", (3, 3)), matrix(IMU_TO_VELO, "T", (3,))
    for i in range(3):
        np.testing.assert_allclose(ds[i].T_map_lidar, T[i] @ np.linalg.inv(velo_imu), atol=1e-6)


def test_frames_stamps_and_info(drive):
    ds = open_dataset(drive.parent.parent)  # the folder above the date folder opens too
    assert isinstance(ds, KittiRawDataset)
    assert len(ds) == 3 and ds.name == "2011_09_26_drive_0005_sync"
    frame = ds[2]
    assert frame.stamp == pytest.approx(1317042146.172421666, abs=1e-6)
    assert frame.cameras[0].stamp == pytest.approx(1317042146.157975347, abs=1e-6)
    assert frame.cameras[0].image.shape == (375, 1242, 3) and frame.points.shape == (50, 3)
    assert frame.cameras[0].name == "2011_09_26/2011_09_26_drive_0005_sync/image_02/data/0000000002.png"
    assert ds.classes.by_id(10).name == "car"  # the standard KITTI table
    info = ds.info()
    assert info.format == "kitti-raw" and info.frames == 3 and info.time_span == (ds.stamps[0], ds.stamps[2])
    assert info.pose_source.startswith("OXTS (Mercator, scale cos(49.000000 deg) = 0.656059")
    assert info.details["calib_time"] == "09-Jan-2012 13:57:47" and info.details["camera_folders"] == ["image_02"]


def test_scans_without_a_packet_are_skipped_and_counted(copy):
    (copy / "oxts" / "data" / "0000000000.txt").unlink()
    (copy / "image_02" / "data" / "0000000002.png").unlink()
    ds = open_dataset(copy)
    assert isinstance(ds, KittiRawDataset)
    assert len(ds) == 2 and ds.info().skipped == {"scans_without_oxts": 1, "images_missing": 1}
    assert len(ds[0].cameras) == 1 and ds[1].cameras == []
    assert ds.info().skipped_notes["scans_without_oxts"].endswith("0000000000.txt")
    # The map's origin is the IMU of the first frame that has a packet (heading north: yaw 90 deg).
    x, y, z = np.linalg.inv(ds.calibration.T_velo_imu)[:3, 3]
    np.testing.assert_allclose(ds[0].T_map_lidar[:3, 3], [-y, x, z], atol=1e-9)


def damage(drive, what):
    date = drive.parent
    if what == "calib number":
        path = date / "calib_cam_to_cam.txt"
        path.write_text(path.read_text().replace("R_rect_00: 9.999239e-01", "R_rect_00: 9.99923q-01"))
        return rf"{path}:9: R_rect_00 has a value that is not a number"
    if what == "P_rect length":
        path = date / "calib_cam_to_cam.txt"
        path.write_text(path.read_text().replace(" 2.745884e-03\n", "\n"))
        return rf"{path}:13: P_rect_02 has 11 numbers, expected 12 \(the rectified 3x4 projection matrix, row-major\)"
    if what == "velo rotation":
        path = date / "calib_velo_to_cam.txt"
        path.write_text(path.read_text().replace("R: 7.533745e-03", "R: 1.533745e-01"))
        return rf"{path}:2: R is not a rotation matrix"
    if what == "imu translation 1e308":
        path = date / "calib_imu_to_velo.txt"
        path.write_text(path.read_text().replace("T: -8.086759e-01", "T: 1e308"))
        return rf"{path}:3: T must be within \+-1e\+07 m per axis, got 1e\+308 m"
    if what == "velo rotation 1e308":
        path = date / "calib_velo_to_cam.txt"
        path.write_text(path.read_text().replace("R: 7.533745e-03", "R: 1e308"))
        return rf"{path}:2: R is not a rotation matrix"
    if what == "P_rect baseline 1e308":
        path = date / "calib_cam_to_cam.txt"
        path.write_text(
            path.read_text().replace(
                "P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+01",
                "P_rect_02: 7.215377e+02 0.000000e+00 6.095593e+02 4.485728e+300",
            )
        )
        return rf"{path}:13: P_rect_02's baseline K\^-1 t must be within \+-1e\+07 m per axis"
    if what == "missing calib":
        path = date / "calib_imu_to_velo.txt"
        path.unlink()
        return rf"{path}: missing"
    if what == "stamp":
        path = drive / "velodyne_points" / "timestamps.txt"
        path.write_text(path.read_text().replace("13:02:26.068424730", "13:02:26,068424730"))
        return rf"{path}:2: expected a stamp like 2011-09-26 13:02:25.964389445"
    if what == "oxts fields":
        path = drive / "oxts" / "data" / "0000000001.txt"
        path.write_text(path.read_text().rsplit(" ", 1)[0] + "\n")
        return rf"{path}: expected 30 numbers \(lat, lon, alt, roll, pitch, yaw, ... orimode\), got 29"
    if what == "oxts text":
        path = drive / "oxts" / "data" / "0000000002.txt"
        path.write_text(path.read_text().replace("100.0", "high", 1))
        return rf"{path}: alt is not a number \('high'\)"
    if what == "image size":
        path = drive / "image_02" / "data" / "0000000000.png"
        Image.new("RGB", (1241, 376)).save(path)
        return rf"{path}: image is 1241x376, but {date / 'calib_cam_to_cam.txt'}:11 S_rect_02 says 1242x375"
    raise AssertionError(what)


@pytest.mark.parametrize(
    "what",
    [
        "calib number",
        "P_rect length",
        "velo rotation",
        "imu translation 1e308",
        "velo rotation 1e308",
        "P_rect baseline 1e308",
        "missing calib",
        "stamp",
        "oxts fields",
        "oxts text",
        "image size",
    ],
)
def test_bad_files_are_one_line_with_exit_2_and_nothing_written(copy, tmp_path, capsys, what):
    message = damage(copy, what)
    with pytest.raises(TerraError, match=f"^{message}"):
        KittiRawDataset(copy)
    out = tmp_path / "map.terra"
    assert run(["map", str(copy), "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0]
    assert not out.exists() and not (tmp_path / "map.terra.partial").exists()


def test_loader_options_are_validated(drive):
    with pytest.raises(TerraError, match=r"dataset options \[kitti-raw\]: field 'poses'"):
        open_dataset(drive, options={"poses": "gps"})
    ds = open_dataset(drive, "kitti-raw", {"normalise": "first-pose", "cameras": ["image_03"]})
    assert isinstance(ds, KittiRawDataset)
    assert ds.cameras == [] and ds.normalise == "first-pose"
    assert KittiRawConfig().cameras == ["image_02", "image_03"]


def test_two_drives_need_one_chosen(drive, tmp_path):
    date = shutil.copytree(drive.parent, tmp_path / "2011_09_26")
    shutil.copytree(date / drive.name, date / "2011_09_26_drive_0009_sync")
    with pytest.raises(TerraError, match=r"2 drives; open one of them, e.g. .*drive_0005_sync"):
        open_dataset(date)
    assert len(open_dataset(date / "2011_09_26_drive_0009_sync")) == 3


def test_unsynced_extract_drives_are_refused_with_a_reason(drive, tmp_path):
    date = shutil.copytree(drive.parent, tmp_path / "2011_09_26")
    (date / drive.name).rename(date / "2011_09_26_drive_0005_extract")
    with pytest.raises(
        TerraError, match=r"drive_0005_extract: an unsynced '_extract' drive .* reads the synced and rectified"
    ):
        open_dataset(date)
