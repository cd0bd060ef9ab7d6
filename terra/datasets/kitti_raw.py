"""KITTI raw drives as the dataset ships them ("kitti-raw"): reader.

A date folder holds the calibration of its drives and the drives themselves:
- DATE/calib_cam_to_cam.txt: per camera 00..03 S, K, D, R, T (unrectified), S_rect, R_rect,
  P_rect (3x4: rectified camera-0 coordinates -> pixels of camera k), and calib_time;
- DATE/calib_velo_to_cam.txt: R, T (Velodyne -> unrectified camera 0), delta_f, delta_c;
- DATE/calib_imu_to_velo.txt: R, T (OXTS IMU -> Velodyne);
- DATE/DATE_drive_NNNN_sync/velodyne_points/data/NNNNNNNNNN.bin: float32 x y z reflectance
  (metres, Velodyne frame: x forward, y left, z up), with timestamps.txt
  (`2011-09-26 13:02:25.964389445` per line, line i = file i);
- image_02/data/NNNNNNNNNN.png (left colour camera, rectified), image_03 (right), timestamps.txt;
- oxts/data/NNNNNNNNNN.txt: one GPS/IMU packet of 30 numbers (terra.datasets.oxts), timestamps.txt.

Cameras come from the rectified projections: for camera k, K = P_rect_0k[:, :3] and
T_cam_lidar = [I | K^-1 P_rect_0k[:, 3]] R_rect_00 T_cam0_velo; the images are rectified, so
there is no distortion, and their size is S_rect_0k. Poses come from OXTS by the devkit's
Mercator conversion: T_map_lidar = T_map_imu T_velo_imu^-1, the map's origin at the first
frame's IMU position with east, north, up axes (`normalise: first-pose` makes the first IMU pose
the identity, as the devkit's convertOxtsToPose does). Frames pair files by their index.

Terra's additions, which KITTI tools ignore: classes.json and ground_truth/ beside the date folder,
velodyne_points/labels/NNNNNNNNNN.label (class | instance << 16, as SemanticKITTI), and
image_0k/semantic/ and image_0k/instance/ 16-bit label images (instance ids above 65535: 24-bit RGB PNG,
id = R + 256 G + 65536 B). Object labels in the KITTI
tracking format (`label_02/NNNN.txt`) or object format (`label_2/NNNNNNNNNN.txt`, one per frame) in
the drive folder give ground-truth boxes (terra.datasets.kitti_labels).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, field_validator

from terra.datasets import oxts
from terra.datasets.base import CameraFrame, ClassTable, Frame, PosesUnavailable, SourceInfo
from terra.datasets.folder_io import (
    image_size,
    read_classes,
    read_instance_png,
    read_label_png,
    read_point_labels,
    read_rgb,
    read_velodyne_scan,
)
from terra.datasets.kitti_common import (
    CalibFile,
    check_rotation,
    check_translation,
    read_calib_file,
    read_timestamps,
    standard_classes,
)
from terra.datasets.registry import Loader
from terra.errors import TerraError
from terra.geometry import CameraCalibration, invert_pose, make_pose
from terra.schemas import Section

CAM_TO_CAM = "calib_cam_to_cam.txt"
VELO_TO_CAM = "calib_velo_to_cam.txt"
IMU_TO_VELO = "calib_imu_to_velo.txt"
VELODYNE = "velodyne_points"
OXTS = "oxts"
COLOUR_CAMERAS = ("image_02", "image_03")


class KittiRawConfig(Section):
    """Options of the KITTI raw loader."""

    poses: str = Field(
        default="oxts",
        description="where T_map_lidar comes from: 'oxts' (GPS/IMU, the devkit's conversion), 'odometry' "
        "(KISS-ICP on the scans; every scan is a frame, OXTS only measures the error when every scan has a "
        "packet), or another source registered in terra.datasets.kitti_raw.POSE_SOURCES",
    )
    normalise: oxts.Normalise = Field(
        default="first-position",
        description="map origin: 'first-position' (east, north, up axes "
        "at the first IMU position) or 'first-pose' (the first IMU pose is the identity)",
    )
    cameras: list[Literal["image_00", "image_01", "image_02", "image_03"]] = Field(
        default_factory=lambda: list(COLOUR_CAMERAS),
        description="camera folders to use, when present (00/01 are greyscale)",
    )

    @field_validator("poses")
    @classmethod
    def _known_source(cls, value: str) -> str:
        if value not in POSE_SOURCES:
            raise ValueError(f"unknown pose source {value!r}; expected one of: {', '.join(sorted(POSE_SOURCES))}")
        return value


@dataclass(frozen=True)
class DriveCalibration:
    """The date folder's calibration: T_cam0_velo (Velodyne -> unrectified camera 0, metres),
    R_rect_00 (4x4, unrectified -> rectified camera 0), T_velo_imu (IMU -> Velodyne) and the parsed
    calib_cam_to_cam.txt (projections and image sizes per camera)."""

    T_cam0_velo: np.ndarray
    R_rect_00: np.ndarray
    T_velo_imu: np.ndarray
    cam_to_cam: CalibFile

    @property
    def T_rect_velo(self) -> np.ndarray:
        """Velodyne -> rectified camera 0, the frame of KITTI object labels."""
        return self.R_rect_00 @ self.T_cam0_velo

    def camera(self, folder: str, width: int, height: int) -> CameraCalibration:
        """The rectified camera of `folder` (image_0k) from P_rect_0k."""
        k = folder[-2:]
        P = self.cam_to_cam.matrix(f"P_rect_{k}", (3, 4), "the rectified 3x4 projection matrix, row-major")
        K = P[:, :3]
        if abs(K[1, 0]) + abs(K[2, 0]) + abs(K[2, 1]) > 1e-9 or K[2, 2] != 1.0:
            raise TerraError(
                f"{self.cam_to_cam.where(f'P_rect_{k}')}: P_rect_{k} must be [K | K t] with K upper triangular "
                "and K[2, 2] = 1 (a rectified camera)"
            )
        T_cam_rect = make_pose(np.eye(3), np.linalg.solve(K, P[:, 3]))
        check_translation(T_cam_rect[:3, 3], f"{self.cam_to_cam.where(f'P_rect_{k}')}: P_rect_{k}'s baseline K^-1 t")
        try:
            return CameraCalibration(folder, width, height, K, np.zeros(0), T_cam_rect @ self.T_rect_velo)
        except ValueError as exc:
            raise TerraError(f"{self.cam_to_cam.where(f'P_rect_{k}')}: {exc}") from None

    def image_size(self, folder: str) -> tuple[int, int]:
        """(width, height) of camera `folder`'s rectified images, from S_rect_0k (pixels)."""
        key = f"S_rect_{folder[-2:]}"
        size = self.cam_to_cam.matrix(key, (2,), "rectified image width and height, pixels")
        if np.any(size <= 0) or np.any(size != np.round(size)):
            raise TerraError(
                f"{self.cam_to_cam.where(key)}: {key} must be two positive whole numbers, got {size.tolist()}"
            )
        return int(size[0]), int(size[1])


def read_drive_calibration(date_folder: Path) -> DriveCalibration:
    """The three calibration files of a date folder (TerraError naming a missing or bad one)."""
    paths = [date_folder / name for name in (CAM_TO_CAM, VELO_TO_CAM, IMU_TO_VELO)]
    for path in paths:
        if not path.is_file():
            raise TerraError(f"{path}: missing (KITTI raw drives take their calibration from the date folder)")
    cam_to_cam, velo_to_cam, imu_to_velo = (read_calib_file(p) for p in paths)
    R_rect = np.eye(4)
    R_rect[:3, :3] = cam_to_cam.matrix("R_rect_00", (3, 3), "the rectifying rotation of camera 0, row-major")
    check_rotation(R_rect[:3, :3], f"{cam_to_cam.where('R_rect_00')}: R_rect_00")
    return DriveCalibration(velo_to_cam.rigid("R", "T"), R_rect, imu_to_velo.rigid("R", "T"), cam_to_cam)


# ----------------------------------------------------------------------------------- drive paths
def find_drives(path: Path) -> list[Path]:
    """Drive folders (holding velodyne_points/data/) at `path`, in it, or two levels down."""
    path = Path(path)
    if (path / VELODYNE / "data").is_dir():
        return [path]
    if not path.is_dir():
        return []
    drives = sorted(p for p in path.iterdir() if (p / VELODYNE / "data").is_dir())
    if not drives:
        drives = sorted(
            d for date in path.iterdir() if date.is_dir() for d in date.iterdir() if (d / VELODYNE / "data").is_dir()
        )
    return drives


def _one_drive(path: Path) -> Path:
    drives = find_drives(path)
    if not drives:
        raise TerraError(f"{path}: no KITTI raw drive (DATE/DATE_drive_NNNN_sync/velodyne_points/data/)")
    if len(drives) > 1:
        raise TerraError(f"{path}: {len(drives)} drives; open one of them, e.g. {drives[0]}")
    if drives[0].name.endswith("_extract"):
        raise TerraError(
            f"{drives[0]}: an unsynced '_extract' drive (unrectified images, sensor clocks apart); "
            "Terra reads the synced and rectified '_sync' drives"
        )
    return drives[0]


def _header_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image file from its header (no decoding)."""
    return image_size(path)


def _indexed_files(folder: Path, suffix: str) -> dict[int, Path]:
    """index -> file for the `NNNNNNNNNN{suffix}` files of a data folder."""
    out = {}
    if folder.is_dir():
        for p in folder.iterdir():
            if p.suffix == suffix and p.stem.isdigit():
                out[int(p.stem)] = p
    return dict(sorted(out.items()))


# ---------------------------------------------------------------------------------------- reader
PoseSource = Callable[["KittiRawDataset", KittiRawConfig], np.ndarray]


def oxts_poses(drive: KittiRawDataset, config: KittiRawConfig) -> np.ndarray:
    """(F, 4, 4) T_map_lidar of every frame from its OXTS packet (the devkit's conversion)."""
    if drive.packets is None:
        raise PosesUnavailable(f"{drive.drive / OXTS / 'data'}: a frame has no OXTS packet")
    T_world_imu = oxts.normalise_poses(oxts.world_poses(drive.packets), config.normalise)
    return T_world_imu @ invert_pose(drive.calibration.T_velo_imu)


def odometry_poses(drive: KittiRawDataset, config: KittiRawConfig) -> np.ndarray:
    """(F, 4, 4) NaN poses for LiDAR odometry to fill; the OXTS poses when every scan has a packet
    (the odometry then starts from the first and its error is measured against them)."""
    if drive.packets is not None:
        return oxts_poses(drive, config)
    return np.full((len(drive), 4, 4), np.nan)


# Where poses come from, by the name `KittiRawConfig.poses` takes: a source is a function of the
# opened drive (its scans, packets, calibration) and the options returning (F, 4, 4) T_map_lidar.
# "odometry" leaves them to LiDAR odometry (the drive's `needs_odometry`).
POSE_SOURCES: dict[str, PoseSource] = {"oxts": oxts_poses, "odometry": odometry_poses}


class KittiRawDataset:
    """Frames of one KITTI raw drive (its scans that have an OXTS packet), in index order."""

    def __init__(self, path: Path, config: KittiRawConfig | None = None) -> None:
        config = config or KittiRawConfig()
        self.drive = drive = _one_drive(path)
        self.date_folder = drive.parent
        self.name = drive.name
        self.calibration = read_drive_calibration(
            self.date_folder if (self.date_folder / CAM_TO_CAM).is_file() else drive
        )
        self.skipped: dict[str, int] = {}
        self.skipped_notes: dict[str, str] = {}
        self.needs_odometry = config.poses == "odometry"
        self.indices, self.scans, self.stamps = self._scans()
        self.packets = self._packets()
        self.cameras, self._camera_folders, self._camera_stamps = self._cameras(config.cameras)
        self.root = next(
            (d for d in (drive, self.date_folder, self.date_folder.parent) if (d / "classes.json").is_file()),
            self.date_folder.parent,
        )
        self.classes: ClassTable = read_classes(self.root) or standard_classes()
        self.pose_source = config.poses
        self.normalise = config.normalise
        self.poses = POSE_SOURCES[config.poses](self, config)

    def wgs84_anchor(self) -> dict[str, Any] | None:
        """Where the map frame lies on the Earth (terra.schemas.Wgs84Anchor): with OXTS poses
        normalised to the first position, the map origin is the first frame's IMU at its packet's
        lat, lon, alt, and the map's x, y are the devkit's Mercator metres (east, north); None
        otherwise (odometry poses drift from OXTS; 'first-pose' tilts the map by the first roll and pitch)."""
        if self.pose_source != "oxts" or self.normalise != "first-position" or self.packets is None:
            return None
        lat, lon, alt = (float(v) for v in self.packets[0, :3])
        return {
            "lat": lat,
            "lon": lon,
            "alt": alt,
            "yaw_deg": 0.0,
            "projection": "kitti-mercator",
            "source": f"kitti-raw OXTS, first frame of {self.drive.name}",
        }

    def _skip(self, reason: str, note: str) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + 1
        self.skipped_notes.setdefault(reason, note)

    def _scans(self) -> tuple[np.ndarray, list[Path], np.ndarray]:
        """Scan indices with an OXTS packet, their files and stamps (velodyne_points/timestamps.txt)."""
        velodyne = self.drive / VELODYNE
        scans = _indexed_files(velodyne / "data", ".bin")
        if not scans:
            raise TerraError(f"{velodyne / 'data'}: no NNNNNNNNNN.bin scans")
        stamps = read_timestamps(velodyne / "timestamps.txt") if (velodyne / "timestamps.txt").is_file() else None
        if stamps is None:
            raise TerraError(f"{velodyne / 'timestamps.txt'}: missing (one stamp per scan)")
        last = max(scans)
        if last >= len(stamps):
            raise TerraError(
                f"{velodyne / 'timestamps.txt'}: {len(stamps)} stamps, but there is a scan {scans[last].name}"
            )
        packets = _indexed_files(self.drive / OXTS / "data", ".txt")
        keep = []
        for index, scan in scans.items():
            if index in packets or self.needs_odometry:
                keep.append(index)
            else:
                self._skip("scans_without_oxts", f"{scan}: no {self.drive / OXTS / 'data' / f'{index:010d}.txt'}")
        if not keep:
            raise PosesUnavailable(f"{self.drive / OXTS / 'data'}: no OXTS packet for any scan (poses come from OXTS)")
        return np.array(keep), [scans[i] for i in keep], stamps[keep]

    def _packets(self) -> np.ndarray | None:
        """The OXTS packets of the frames (None when odometry makes the poses and a frame has none)."""
        paths = [self.drive / OXTS / "data" / f"{i:010d}.txt" for i in self.indices]
        if self.needs_odometry and not all(p.is_file() for p in paths):
            return None
        return oxts.read_packets(paths)

    def _cameras(self, folders: Sequence[str]) -> tuple[list[CameraCalibration], list[str], list[np.ndarray | None]]:
        """Calibrations of the configured camera folders present, checked against their first image."""
        cams, names, stamps = [], [], []
        for folder in folders:
            images = _indexed_files(self.drive / folder / "data", ".png")
            if not images:
                continue
            width, height = self.calibration.image_size(folder)
            first = next(iter(images.values()))
            size = _header_size(first)
            if size != (width, height):
                key = f"S_rect_{folder[-2:]}"
                raise TerraError(
                    f"{first}: image is {size[0]}x{size[1]}, but {self.calibration.cam_to_cam.where(key)} "
                    f"{key} says {width}x{height}"
                )
            cams.append(self.calibration.camera(folder, width, height))
            names.append(folder)
            for index in self.indices:
                if int(index) not in images:
                    self._skip("images_missing", f"{self.drive / folder / 'data' / f'{int(index):010d}.png'}: missing")
            path = self.drive / folder / "timestamps.txt"
            stamps.append(read_timestamps(path) if path.is_file() else None)
        return cams, names, stamps

    def __len__(self) -> int:
        return len(self.scans)

    def __getitem__(self, index: int) -> Frame:
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range (0..{len(self) - 1})")
        scan_path, number = self.scans[index], int(self.indices[index])
        raw = read_velodyne_scan(scan_path)
        labels = instances = None
        label_path = self.drive / VELODYNE / "labels" / f"{number:010d}.label"
        if label_path.exists():
            value = read_point_labels(label_path, raw.shape[0])
            labels, instances = (value & 0xFFFF).astype(np.int32), (value >> 16).astype(np.int32)
        stamp = float(self.stamps[index])
        cams = [
            cam for cam in (self._camera_frame(c, number, stamp) for c in range(len(self.cameras))) if cam is not None
        ]
        return Frame(
            index,
            stamp,
            np.ascontiguousarray(raw[:, :3]),
            self.poses[index],
            cams,
            np.ascontiguousarray(raw[:, 3]),
            labels,
            instances,
        )

    def _camera_frame(self, c: int, number: int, scan_stamp: float) -> CameraFrame | None:
        folder = self.drive / self._camera_folders[c]
        path = folder / "data" / f"{number:010d}.png"
        if not path.is_file():
            return None
        stamps = self._camera_stamps[c]
        stamp = float(stamps[number]) if stamps is not None and number < len(stamps) else scan_stamp
        sem, inst = folder / "semantic" / path.name, folder / "instance" / path.name
        return CameraFrame(
            self.cameras[c],
            stamp,
            read_rgb(path),
            read_label_png(sem) if sem.is_file() else None,
            read_instance_png(inst) if inst.is_file() else None,
            name=str(path.relative_to(self.date_folder.parent)),
        )

    def global_map(self) -> np.ndarray | None:
        return None

    def ground_truth(self):
        """The simulator's ground_truth/ when the drive has one, else the boxes of its KITTI labels."""
        from terra.datasets.ground_truth import GROUND_TRUTH_DIR, load_ground_truth

        if (self.root / GROUND_TRUTH_DIR).is_dir():
            return load_ground_truth(self.root)
        from terra.datasets.kitti_labels import ground_truth_from_labels, read_drive_labels

        labels = read_drive_labels(self.drive)
        if labels and not np.isfinite(self.poses).all():
            raise TerraError(
                f"{self.drive}: KITTI labels give ground truth in the OXTS poses' frame; this drive has none"
            )
        if not labels:
            raise TerraError(
                f"{self.drive}: no ground truth (no {GROUND_TRUTH_DIR}/ beside it and no KITTI labels: "
                "label_02/NNNN.txt or label_2/NNNNNNNNNN.txt)"
            )
        T_map_rect = {int(i): T @ invert_pose(self.calibration.T_rect_velo) for i, T in zip(self.indices, self.poses)}
        return ground_truth_from_labels(labels, T_map_rect, str(self.drive))

    def info(self) -> SourceInfo:
        """What the drive holds (no scan is read)."""
        details: dict = {
            "date": self.date_folder.name,
            "drive": self.drive.name,
            "calib_time": self.calibration.cam_to_cam.text.get("calib_time", ""),
            "camera_folders": list(self._camera_folders),
        }
        pose = {"odometry": "odometry (KISS-ICP)"}
        if self.packets is not None:
            lat, lon, alt = (float(v) for v in self.packets[0, :3])
            scale = oxts.mercator_scale(lat)
            details.update({"oxts_origin": {"lat": lat, "lon": lon, "alt": alt}, "mercator_scale": scale})
            pose["oxts"] = f"OXTS (Mercator, scale cos({lat:.6f} deg) = {scale:.6f}; origin {self.normalise})"
        details["normalise"] = self.normalise
        from terra.datasets.kitti_labels import label_files

        labels = label_files(self.drive)
        if labels:
            details["labels"] = [str(p.relative_to(self.drive)) for p in labels[:3]] + (
                ["..."] if len(labels) > 3 else []
            )
        return SourceInfo(
            "kitti-raw",
            str(self.drive),
            len(self),
            (float(self.stamps[0]), float(self.stamps[-1])),
            list(self.cameras),
            pose.get(self.pose_source, self.pose_source),
            dict(self.skipped),
            dict(self.skipped_notes),
            details,
        )


def _detect(path: Path) -> bool:
    drives = find_drives(path)
    return bool(drives) and any((d.parent / CAM_TO_CAM).is_file() or (d / CAM_TO_CAM).is_file() for d in drives)


def _open(path: Path, config: KittiRawConfig) -> KittiRawDataset:
    return KittiRawDataset(path, config)


LOADER = Loader(
    "kitti-raw",
    _detect,
    _open,
    KittiRawConfig,
    "KITTI raw drives (DATE/DATE_drive_NNNN_sync/ with velodyne_points, image_02/03, oxts; calib_*.txt in DATE/)",
    without_poses={"poses": "odometry"},
)
