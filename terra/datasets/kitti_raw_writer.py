"""Write any dataset as a KITTI raw drive (terra.datasets.kitti_raw describes the layout).

The drive is `DATE/DATE_drive_NNNN_sync/` with the date folder's three calibration files. KITTI's
images are rectified: the cameras must be undistorted pinhole cameras of one orientation (a
stereo pair at most), written as image_02 and image_03. Rectified camera 0 is the first camera's
frame; the unrectified camera 0 differs from it by KITTI's own R_rect_00 of 2011_09_26, and the IMU
sits where KITTI's does (calib_imu_to_velo of 2011_09_26), so readers must apply both.

OXTS packets come from the ground-truth LiDAR poses (`gt_T_map_lidar(i)` when the dataset has it,
else its frames' T_map_lidar) with the first IMU position at a fixed geodetic origin (or, for the
simulator's drives, the map origin there: `origin_is_map`), map x east, y north, z up. The
reader's map frame then has its origin at that first IMU position: `write_kitti_raw` returns the
shift to apply to the dataset's map coordinates (ground truth) to land in it. Stamps keep their
differences; the drive starts at noon of its date (UTC).

Ground-truth objects seen by the first camera (at least `LABEL_MIN_PIXELS` pixels of its instance
image) are written as KITTI tracking labels, `label_02/NNNN.txt` (track id = instance id).
"""

from __future__ import annotations

import calendar
import time
from pathlib import Path

import numpy as np

from terra.datasets import oxts
from terra.datasets.base import Dataset, Frame
from terra.datasets.folder_io import write_instance_png, write_label_png, write_rgb
from terra.datasets.kitti_common import format_timestamp
from terra.datasets.kitti_labels import rotation_y_of
from terra.datasets.kitti_raw import CAM_TO_CAM, IMU_TO_VELO, OXTS, VELO_TO_CAM, VELODYNE
from terra.errors import TerraError
from terra.geometry import CameraCalibration, invert_pose, make_pose, project_points, transform_points
from terra.progress import progress

DATE = "2011_09_26"
GEODETIC_ORIGIN = (49.011, 8.424, 112.0)  # lat, lon (degrees), alt (metres): Karlsruhe, where KITTI drove
# KITTI's calibration of 2011_09_26 (calib_cam_to_cam.txt R_rect_00, calib_imu_to_velo.txt R and T).
R_RECT_00 = np.array(
    [
        [9.999239e-01, 9.837760e-03, -7.445048e-03],
        [-9.869795e-03, 9.999421e-01, -4.278459e-03],
        [7.402527e-03, 4.351614e-03, 9.999631e-01],
    ]
)
R_VELO_IMU = np.array(
    [
        [9.999976e-01, 7.553071e-04, -2.035826e-03],
        [-7.854027e-04, 9.998898e-01, -1.482298e-02],
        [2.024406e-03, 1.482454e-02, 9.998881e-01],
    ]
)
T_VELO_IMU = np.array([-8.086759e-01, 3.195559e-01, -7.997231e-01])
LABEL_MIN_PIXELS = 20
SWEEP = 0.1  # seconds per Velodyne turn: timestamps_start / _end lie half a sweep around the stamp


def _orthonormal(R: np.ndarray) -> np.ndarray:
    """The rotation nearest R (KITTI prints six digits, so its matrices are orthonormal to ~1e-6)."""
    u, _, vt = np.linalg.svd(R)
    return u @ vt


def kitti_rig() -> tuple[np.ndarray, np.ndarray]:
    """(R_rect_00 as 4x4, T_velo_imu) of the written drives: KITTI's own values, made exactly rigid."""
    R_rect = np.eye(4)
    R_rect[:3, :3] = _orthonormal(R_RECT_00)
    return R_rect, make_pose(_orthonormal(R_VELO_IMU), T_VELO_IMU)


def _fmt(values) -> str:
    """Numbers as KITTI writes them, with more digits (round-off below 1e-12 written as 0)."""
    values = np.ravel(np.asarray(values, np.float64))
    return " ".join(f"{v:.12e}" for v in np.where(np.abs(values) < 1e-12, 0.0, values))


# ------------------------------------------------------------------------------------ the writer
def write_kitti_raw(
    dataset: Dataset,
    root: Path,
    date: str = DATE,
    drive: int = 1,
    origin: tuple[float, float, float] = GEODETIC_ORIGIN,
    show_progress: bool = True,
    origin_is_map: bool = False,
) -> np.ndarray:
    """Write `dataset` under `root` (an empty folder) as one KITTI raw drive; returns the (3,)
    shift from the dataset's map frame to the drive's (p_drive = p_map + shift). The first IMU
    position lies at geodetic `origin`; with `origin_is_map`, the dataset's map origin does instead
    (the first position where its map coordinates put it), so drives of one simulated world, each
    written apart, share the Earth as real drives of one place do."""
    folder = Path(root) / date / f"{date}_drive_{drive:04d}_sync"
    (folder / VELODYNE / "data").mkdir(parents=True)
    (folder / OXTS / "data").mkdir(parents=True)
    R_rect, T_velo_imu = kitti_rig()
    ground_truth = getattr(dataset, "ground_truth", None)  # simulated sources know their objects
    gt_pose = getattr(dataset, "gt_T_map_lidar", None)  # and their true poses (odometry wrappers)
    gt = ground_truth() if ground_truth is not None else None
    stamps, poses, camera_stamps, rig, labels = [], [], [], None, []
    frames = (dataset[i] for i in range(len(dataset)))
    for i, frame in enumerate(progress(frames, desc="writing frames", total=len(dataset), enabled=show_progress)):
        if rig is None:
            rig = _check_rig([c.calibration for c in frame.cameras])
        T_map_lidar = gt_pose(i) if gt_pose is not None else frame.T_map_lidar
        _write_scan(folder, i, frame)
        camera_stamps.append(_write_images(folder, i, frame, len(rig)))
        if gt is not None and frame.cameras and frame.cameras[0].instance is not None:
            labels += _label_lines(i, frame.cameras[0], T_map_lidar, gt.objects)
        stamps.append(float(frame.stamp))
        poses.append(np.asarray(T_map_lidar, np.float64))
    if not stamps:
        raise TerraError(f"dataset {dataset.name!r} has no frames to write")
    stamps_a = np.array(stamps)
    if np.any(np.diff(stamps_a) <= 0):
        raise TerraError(f"dataset {dataset.name!r}: frame stamps must increase to be written as a KITTI drive")
    T_map_imu = np.array(poses) @ T_velo_imu
    if origin_is_map:
        origin = _moved(origin, T_map_imu[0, :3, 3])
    _write_oxts(folder, T_map_imu, stamps_a, origin)
    _write_stamps(folder, date, stamps_a, camera_stamps, len(rig or []))
    _write_calibration(folder.parent, date, rig or [], R_rect, T_velo_imu)
    if labels:
        (folder / "label_02").mkdir()
        (folder / "label_02" / f"{drive:04d}.txt").write_text("".join(line + "\n" for line in labels))
    return -T_map_imu[0, :3, 3]


def _check_rig(cameras: list[CameraCalibration]) -> list[CameraCalibration]:
    """The cameras, if KITTI's rectified layout can hold them (TerraError otherwise)."""
    if len(cameras) > 2:
        raise TerraError(
            f"a KITTI raw drive holds two colour cameras (image_02, image_03), the dataset has {len(cameras)}"
        )
    for cam in cameras:
        if cam.distorted:
            raise TerraError(
                f"camera {cam.name}: KITTI raw images are rectified; this camera has lens distortion "
                f"({cam.model}, {cam.dist.tolist()}): simulate it without distortion for kitti-raw"
            )
    if len(cameras) == 2:
        relative = cameras[1].T_cam_lidar[:3, :3] @ cameras[0].T_cam_lidar[:3, :3].T
        if np.abs(relative - np.eye(3)).max() > 1e-6:
            raise TerraError(
                f"cameras {cameras[0].name} and {cameras[1].name} look different ways; KITTI's rectified "
                "cameras share one orientation (a stereo pair)"
            )
    return list(cameras)


def _write_scan(folder: Path, i: int, frame: Frame) -> None:
    name = f"{i:010d}"
    inten = frame.intensity if frame.intensity is not None else np.zeros(len(frame.points), np.float32)
    # write_bytes, not ndarray.tofile: a short write (full disk) then says why, with its errno
    scan = np.concatenate([frame.points, inten[:, None]], axis=1).astype("<f4")
    (folder / VELODYNE / "data" / f"{name}.bin").write_bytes(scan.tobytes())
    if frame.point_labels is not None:
        inst = frame.point_instances if frame.point_instances is not None else np.zeros_like(frame.point_labels)
        if (
            np.any(frame.point_labels < 0)
            or np.any(frame.point_labels > 0xFFFF)
            or np.any(inst < 0)
            or np.any(inst > 0xFFFF)
        ):
            raise TerraError(f"frame {i}: class and instance ids must lie in 0..65535 for .label files")
        (folder / VELODYNE / "labels").mkdir(exist_ok=True)
        value = frame.point_labels.astype(np.uint32) | (inst.astype(np.uint32) << np.uint32(16))
        (folder / VELODYNE / "labels" / f"{name}.label").write_bytes(value.astype("<u4").tobytes())


def _write_images(folder: Path, i: int, frame: Frame, count: int) -> list[float]:
    if len(frame.cameras) != count:
        raise TerraError(f"frame {i} has {len(frame.cameras)} cameras, the first frame {count}")
    for k, cam in enumerate(frame.cameras):
        camera = folder / f"image_0{2 + k}"
        (camera / "data").mkdir(parents=True, exist_ok=True)
        write_rgb(camera / "data" / f"{i:010d}.png", cam.image)
        for extra, image, write in (
            ("semantic", cam.semantic, write_label_png),
            ("instance", cam.instance, write_instance_png),
        ):
            if image is not None:
                (camera / extra).mkdir(exist_ok=True)
                write(camera / extra / f"{i:010d}.png", image)
    return [float(cam.stamp) for cam in frame.cameras]


def _moved(origin: tuple[float, float, float], offset: np.ndarray) -> tuple[float, float, float]:
    """The geodetic point `offset` (3,) metres (east, north, up) from `origin` (lat, lon degrees, alt
    metres), on the devkit's Mercator scaled at the origin's latitude (as the reader measures)."""
    scale = oxts.mercator_scale(origin[0])
    x, y = oxts.lat_lon_to_mercator(np.array([origin[0]]), np.array([origin[1]]), scale)
    lat, lon = oxts.mercator_to_lat_lon(x + offset[0], y + offset[1], scale)
    return float(lat[0]), float(lon[0]), float(origin[2] + offset[2])


def _write_oxts(folder: Path, T_map_imu: np.ndarray, stamps: np.ndarray, origin: tuple[float, float, float]) -> None:
    packets = oxts.packets_from_poses(T_map_imu, stamps, origin)
    for i, packet in enumerate(packets):
        (folder / OXTS / "data" / f"{i:010d}.txt").write_text(oxts.format_packet(packet) + "\n")


def _write_stamps(folder: Path, date: str, stamps: np.ndarray, camera_stamps: list[list[float]], cameras: int) -> None:
    noon = calendar.timegm(time.strptime(date, "%Y_%m_%d")) + 12 * 3600

    def write(path: Path, values) -> None:
        path.write_text("".join(format_timestamp(v - stamps[0], noon) + "\n" for v in values))

    write(folder / VELODYNE / "timestamps.txt", stamps)
    write(folder / VELODYNE / "timestamps_start.txt", stamps - SWEEP / 2)
    write(folder / VELODYNE / "timestamps_end.txt", stamps + SWEEP / 2)
    write(folder / OXTS / "timestamps.txt", stamps)
    for k in range(cameras):
        write(folder / f"image_0{2 + k}" / "timestamps.txt", [s[k] for s in camera_stamps])


def _write_calibration(
    date_folder: Path, date: str, cameras: list[CameraCalibration], R_rect: np.ndarray, T_velo_imu: np.ndarray
) -> None:
    """calib_cam_to_cam.txt, calib_velo_to_cam.txt and calib_imu_to_velo.txt of the date folder."""
    stamp = time.strftime("%d-%b-%Y %H:%M:%S", time.strptime(date, "%Y_%m_%d"))
    T_rect_velo = (
        cameras[0].T_cam_lidar
        if cameras
        else make_pose(np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]), np.zeros(3))
    )
    T_cam0_velo = invert_pose(R_rect) @ T_rect_velo
    lines = [f"calib_time: {stamp}", "corner_dist: 9.950000e-02"]
    for k in range(4):
        cam = cameras[k % 2] if len(cameras) == 2 else (cameras[0] if cameras else None)
        K = cam.K if cam is not None else np.array([[700.0, 0.0, 600.0], [0.0, 700.0, 180.0], [0.0, 0.0, 1.0]])
        size = (cam.width, cam.height) if cam is not None else (1242, 375)
        t_rect = (cam.T_cam_lidar @ invert_pose(T_rect_velo))[:3, 3] if cam is not None else np.zeros(3)
        lines += [
            f"S_0{k}: {_fmt(size)}",
            f"K_0{k}: {_fmt(K)}",
            f"D_0{k}: {_fmt(np.zeros(5))}",
            f"R_0{k}: {_fmt(np.eye(3))}",
            f"T_0{k}: {_fmt(R_rect[:3, :3].T @ t_rect)}",
            f"S_rect_0{k}: {_fmt(size)}",
            f"R_rect_0{k}: {_fmt(R_rect[:3, :3])}",
            f"P_rect_0{k}: {_fmt(np.hstack([K, (K @ t_rect)[:, None]]))}",
        ]
    (date_folder / CAM_TO_CAM).write_text("\n".join(lines) + "\n")
    (date_folder / VELO_TO_CAM).write_text(
        f"calib_time: {stamp}\nR: {_fmt(T_cam0_velo[:3, :3])}\nT: {_fmt(T_cam0_velo[:3, 3])}\n"
        f"delta_f: {_fmt(np.zeros(2))}\ndelta_c: {_fmt(np.zeros(2))}\n"
    )
    (date_folder / IMU_TO_VELO).write_text(
        f"calib_time: {stamp}\nR: {_fmt(T_velo_imu[:3, :3])}\nT: {_fmt(T_velo_imu[:3, 3])}\n"
    )


# ------------------------------------------------------------------------------------ the labels
def label_type(class_name: str) -> str:
    """A class name as a KITTI type word: 'bicycle rack' -> 'Bicycle_rack', 'car' -> 'Car'."""
    word = class_name.strip().replace(" ", "_")
    return word[:1].upper() + word[1:]


def _label_lines(i: int, camera, T_map_lidar: np.ndarray, objects) -> list[str]:
    """KITTI tracking label lines of the ground-truth objects camera 02 sees in frame i (its
    instance image has at least LABEL_MIN_PIXELS of them). Occlusion is written as 3 (unknown)."""
    ids, counts = np.unique(camera.instance, return_counts=True)
    seen = {int(k) for k, n in zip(ids, counts) if k > 0 and n >= LABEL_MIN_PIXELS}
    T_rect_map = camera.calibration.T_cam_lidar @ invert_pose(T_map_lidar)
    lines = []
    for obj in objects:
        if obj.instance_id not in seen:
            continue
        length, width, height = (float(v) for v in obj.size)
        bottom = transform_points(T_rect_map, (np.asarray(obj.center) - [0.0, 0.0, height / 2])[None])[0]
        ry = rotation_y_of(T_rect_map[:3, :3] @ np.array([np.cos(obj.yaw), np.sin(obj.yaw), 0.0]))
        alpha = (ry - np.arctan2(bottom[0], bottom[2]) + np.pi) % (2 * np.pi) - np.pi
        rows, cols = np.nonzero(camera.instance == obj.instance_id)
        truncated = _truncation(obj, T_rect_map, camera.calibration)
        fields = [
            i,
            obj.instance_id,
            label_type(obj.class_name),
            f"{truncated:.2f}",
            3,
            f"{alpha:.6f}",
            *(f"{v:.2f}" for v in (cols.min(), rows.min(), cols.max(), rows.max())),
            *(f"{v:.6f}" for v in (height, width, length, *bottom, ry)),
        ]
        lines.append(" ".join(str(f) for f in fields))
    return lines


def _truncation(obj, T_rect_map: np.ndarray, camera: CameraCalibration) -> float:
    """Share of the box's eight corners outside the image (KITTI: 0 = fully inside, 1 = fully out)."""
    c, s = np.cos(obj.yaw), np.sin(obj.yaw)
    half = np.asarray(obj.size) / 2
    signs = np.array([[a, b, d] for a in (-1, 1) for b in (-1, 1) for d in (-1, 1)], float)
    local = signs * half
    corners = np.asarray(obj.center) + local @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    _, inside = project_points(transform_points(T_rect_map, corners), camera)
    return float(1.0 - inside.mean())
