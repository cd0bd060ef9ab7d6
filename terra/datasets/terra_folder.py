"""The reference implementation's extracted folder layout ("terra-folder"): reader and writer.

Layout (stamps t written as {t:.6f} seconds; camera n counts from 0):
- transformations_lidar2global/transform_lidar_to_map_{t}.npy   (7,) T_map_lidar [tx ty tz qx qy qz qw]
- lidar_pc/lidar_pc_{t}.npy                                     (M, 4) x y z intensity, LiDAR frame
- global_pc/global_pc_{t}.npy                                   (N, 4) map frame, 0.4 m voxel centroids
- camera{n}_images/cam{n}_img_{t}.jpg                           RGB image, JPEG as the reference has it
  (quality 92, no chroma subsampling: lossy, mean error under 1 grey level on simulated images;
  the label images below are exact)
- transformations_lidar2cam{n}/transform_lidar_to_cam{n}_{t}.npy (7,) T_cam_lidar
- msmap_camera_config.yaml: the reference config keys for the cameras (IMG_W, IMG_H, cam{n}_K as 9
  row-major floats, cam{n}_dist, cam_axis) to paste into the authors' msmap config.
Terra's additions, which the authors' scripts ignore:
- lidar_labels/lidar_labels_{t}.npy (M, 2) int32 class id, instance id per point;
- camera{n}_semantic/cam{n}_sem_{t}.png, camera{n}_instance/cam{n}_inst_{t}.png: 16-bit label images;
- terra_dataset.json: name, stamps, exact camera calibrations; classes.json; ground_truth/.

The reader pairs each pose file with the nearest LiDAR scan, image and camera transform by stamp
(binary search) and skips a scan when any gap exceeds `max_gap` seconds, as the reference does.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml
from pydantic import Field

from terra.datasets.base import CameraFrame, ClassTable, Dataset, Frame, SemanticClass, SourceInfo
from terra.config import Section
from terra.datasets.folder_io import (calibration_from_json, calibration_to_json, load_npy, read_classes, read_json,
                                      read_label_png, read_rgb, stamp_of, stamp_text, write_label_png, write_rgb)
from terra.datasets.registry import Loader
from terra.datasets.sync import nearest, stamped_files
from terra.errors import TerraError
from terra.geometry import CameraCalibration, pose_from_xyz_quat, pose_to_xyz_quat, transform_points, voxel_keys
from terra.progress import progress

POSES = "transformations_lidar2global"
SCANS = "lidar_pc"
GLOBAL = "global_pc"
LABELS = "lidar_labels"
META = "terra_dataset.json"
CAMERA_YAML = "msmap_camera_config.yaml"
GLOBAL_LEAF = 0.4


def _image_path(n: int, t: float) -> str:
    return f"camera{n}_images/cam{n}_img_{stamp_text(t)}.jpg"


def image_name(camera_index: int, stamp: float) -> str:
    """Relative file name of camera `camera_index`'s image at `stamp` in this layout."""
    return _image_path(camera_index, stamp)


# ------------------------------------------------------------------------------------------ writer
class GlobalMapAccumulator:
    """Voxel-grid downsampling of all scans in the map frame (centroid of points and intensity per
    `leaf`-metre voxel), reduced as it goes so memory follows the map, not the number of scans."""

    def __init__(self, leaf: float = GLOBAL_LEAF, flush_every: int = 2_000_000) -> None:
        self.leaf, self.flush_every = leaf, flush_every
        self._keys = np.zeros(0, np.int64)
        self._sums = np.zeros((0, 5))  # x, y, z, intensity, count
        self._pending: list[tuple[np.ndarray, np.ndarray]] = []
        self._pending_n = 0

    def add(self, points_map: np.ndarray, intensity: np.ndarray) -> None:
        self._pending.append((points_map.astype(np.float64), intensity.astype(np.float64)))
        self._pending_n += len(points_map)
        if self._pending_n >= self.flush_every:
            self._flush()

    def _flush(self) -> None:
        if not self._pending:
            return
        pts = np.concatenate([p for p, _ in self._pending])
        inten = np.concatenate([i for _, i in self._pending])
        rows = np.concatenate([pts, inten[:, None], np.ones((len(pts), 1))], axis=1)
        keys = np.concatenate([self._keys, voxel_keys(pts, self.leaf)])
        rows = np.concatenate([self._sums, rows])
        self._keys, inverse = np.unique(keys, return_inverse=True)
        sums = np.zeros((len(self._keys), 5))
        np.add.at(sums, inverse, rows)
        self._sums = sums
        self._pending, self._pending_n = [], 0

    def result(self) -> np.ndarray:
        """(N, 4) float32 x, y, z, intensity, one row per voxel in key order."""
        self._flush()
        s = self._sums
        return (s[:, :4] / np.maximum(s[:, 4:5], 1.0)).astype(np.float32)


def write_terra_folder(dataset: Dataset, root: Path, show_progress: bool = True) -> None:
    """Write every frame of `dataset` under `root` (an empty folder) in this layout."""
    root = Path(root)
    for d in (POSES, SCANS, GLOBAL, LABELS):
        (root / d).mkdir(parents=True, exist_ok=True)
    acc = GlobalMapAccumulator()
    cameras: list[CameraCalibration] = []
    stamps: list[float] = []
    for frame in progress((dataset[i] for i in range(len(dataset))), desc="writing frames", total=len(dataset), enabled=show_progress):
        t = stamp_text(frame.stamp)
        stamps.append(float(t))
        np.save(root / POSES / f"transform_lidar_to_map_{t}.npy", pose_to_xyz_quat(frame.T_map_lidar), allow_pickle=False)
        inten = frame.intensity if frame.intensity is not None else np.zeros(len(frame.points), np.float32)
        scan = np.concatenate([frame.points, inten[:, None]], axis=1).astype(np.float32)
        np.save(root / SCANS / f"lidar_pc_{t}.npy", scan, allow_pickle=False)
        if frame.point_labels is not None:
            inst = frame.point_instances if frame.point_instances is not None else np.zeros_like(frame.point_labels)
            np.save(root / LABELS / f"lidar_labels_{t}.npy", np.stack([frame.point_labels, inst], 1).astype(np.int32), allow_pickle=False)
        acc.add(transform_points(frame.T_map_lidar, frame.points.astype(np.float64)), inten)
        for n, cam in enumerate(frame.cameras):
            if n >= len(cameras):
                cameras.append(cam.calibration)
                for d in (f"camera{n}_images", f"transformations_lidar2cam{n}", f"camera{n}_semantic", f"camera{n}_instance"):
                    (root / d).mkdir(exist_ok=True)
            write_rgb(root / _image_path(n, frame.stamp), cam.image)
            np.save(root / f"transformations_lidar2cam{n}" / f"transform_lidar_to_cam{n}_{t}.npy",
                    pose_to_xyz_quat(cam.calibration.T_cam_lidar), allow_pickle=False)
            if cam.semantic is not None:
                write_label_png(root / f"camera{n}_semantic" / f"cam{n}_sem_{t}.png", cam.semantic)
            if cam.instance is not None:
                write_label_png(root / f"camera{n}_instance" / f"cam{n}_inst_{t}.png", cam.instance)
    last = stamp_text(max(stamps)) if stamps else stamp_text(0.0)
    np.save(root / GLOBAL / f"global_pc_{last}.npy", acc.result(), allow_pickle=False)
    meta = {"format": "terra-folder", "version": 1, "name": dataset.name, "frames": len(stamps),
            "cameras": [calibration_to_json(c) for c in cameras]}
    (root / META).write_text(json.dumps(meta, indent=1) + "\n")
    (root / CAMERA_YAML).write_text(yaml.safe_dump(_reference_camera_keys(cameras), sort_keys=False))


def _reference_camera_keys(cameras: list[CameraCalibration]) -> dict:
    """The authors' msmap config keys for these cameras (their IMG_W / IMG_H are global)."""
    out: dict = {}
    if cameras:
        out["IMG_W"], out["IMG_H"] = int(cameras[0].width), int(cameras[0].height)
    axes = []
    for n, c in enumerate(cameras):
        out[f"cam{n}_K"] = [float(v) for v in c.K.ravel()]
        out[f"cam{n}_dist"] = [float(v) for v in c.dist] if np.any(c.dist) else []
        # The LiDAR half-space the camera looks into: the LiDAR axis closest to the optical axis.
        z_in_lidar = c.T_cam_lidar[:3, :3].T @ np.array([0.0, 0.0, 1.0])
        a = int(np.argmax(np.abs(z_in_lidar[:2])))
        axes.append(("+" if z_in_lidar[a] >= 0 else "-") + "xy"[a])
    out["cam_axis"] = axes if len(axes) != 1 else axes[0]
    return out


# ------------------------------------------------------------------------------------------ reader
class TerraFolderDataset:
    """Frames of a folder in the reference layout (ours or the authors' own extraction)."""

    def __init__(self, root: Path, max_gap: float = 0.2, cameras: list[CameraCalibration] | None = None) -> None:
        self.root = root = Path(root)
        if not (root / POSES).is_dir():
            raise TerraError(f"{root}: not a terra-folder dataset (no {POSES}/ folder)")
        meta_path = root / META
        meta = read_json(meta_path) if meta_path.is_file() else {}
        self.name = str(meta.get("name", root.name))
        # Our own folders carry exact calibrations; others get extrinsics from the per-scan files.
        self._exact_cameras = cameras is not None or "cameras" in meta
        if cameras is None:
            if "cameras" in meta:
                if not isinstance(meta["cameras"], list):
                    raise TerraError(f"{meta_path}: 'cameras' must be a list of calibrations")
                cameras = [calibration_from_json(c, str(meta_path)) for c in meta["cameras"]]
            else:
                cameras = _cameras_from_yaml(root)
        self.calibrations = cameras
        self.classes: ClassTable = read_classes(root) or ClassTable([SemanticClass(0, "unlabeled")])
        pose_t, pose_f = stamped_files(root / POSES, "transform_lidar_to_map_*.npy")
        scan_t, scan_f = stamped_files(root / SCANS, "lidar_pc_*.npy")
        cam_files = [(stamped_files(root / f"camera{n}_images", f"cam{n}_img_*.jpg"),
                      stamped_files(root / f"transformations_lidar2cam{n}", f"transform_lidar_to_cam{n}_*.npy"))
                     for n in range(len(cameras))]
        self._frames = []
        for t, pf in zip(pose_t, pose_f):
            s, gap = nearest(scan_t, t)
            picks, gaps = [], [gap]
            for (img_t, img_f), (tf_t, tf_f) in cam_files:
                i, gi = nearest(img_t, t)
                k, gk = nearest(tf_t, t)
                gaps += [gi, gk if tf_t.size else 0.0]
                picks.append((img_f[i] if i >= 0 else None, tf_f[k] if k >= 0 else None))
            if max(gaps) <= max_gap:
                self._frames.append((float(t), pf, scan_f[s], picks))
        if not self._frames:
            raise TerraError(f"{root}: no scan with a pose, a LiDAR file and every camera image within {max_gap} s")

    def __len__(self) -> int:
        return len(self._frames)

    def __getitem__(self, index: int) -> Frame:
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range (0..{len(self) - 1})")
        t, pose_file, scan_file, picks = self._frames[index]
        root = self.root
        text = stamp_text(t)
        scan = load_npy(scan_file, (None, 4), "x, y, z, intensity")
        labels = instances = None
        label_file = root / LABELS / f"lidar_labels_{text}.npy"
        if label_file.is_file():
            li = load_npy(label_file, (len(scan), 2), "class id, instance id per point of its scan")
            labels, instances = li[:, 0].astype(np.int32), li[:, 1].astype(np.int32)
        cams = []
        for n, (img_file, tf_file) in enumerate(picks):
            cal = self.calibrations[n]
            if tf_file is not None and not self._exact_cameras:
                cal = CameraCalibration(cal.name, cal.width, cal.height, cal.K, cal.dist, _read_pose(tf_file))
            image = read_rgb(img_file)
            if image.shape[:2] != (cal.height, cal.width):
                raise TerraError(f"{img_file}: image is {image.shape[1]}x{image.shape[0]}, calibration says {cal.width}x{cal.height}")
            sem_file = root / f"camera{n}_semantic" / f"cam{n}_sem_{stamp_text(stamp_of(img_file))}.png"
            inst_file = root / f"camera{n}_instance" / f"cam{n}_inst_{stamp_text(stamp_of(img_file))}.png"
            cams.append(CameraFrame(cal, stamp_of(img_file), image,
                                    read_label_png(sem_file) if sem_file.is_file() else None,
                                    read_label_png(inst_file) if inst_file.is_file() else None,
                                    name=str(img_file.relative_to(root))))
        return Frame(index, t, np.ascontiguousarray(scan[:, :3], dtype=np.float32), _read_pose(pose_file),
                     cams, scan[:, 3].astype(np.float32), labels, instances)

    def global_map(self) -> np.ndarray | None:
        """[:, :3] of the global_pc file with the largest stamp (as the reference uses it)."""
        t, files = stamped_files(self.root / GLOBAL, "global_pc_*.npy")
        if not files:
            return None
        return np.ascontiguousarray(load_npy(files[-1], (None, 4), "x, y, z, intensity")[:, :3], dtype=np.float32)

    def ground_truth(self):
        from terra.datasets.ground_truth import load_ground_truth

        return load_ground_truth(self.root)

    def info(self) -> SourceInfo:
        """What `terra inspect` reports: frames, cameras as read, and pose files left unpaired."""
        poses = len(stamped_files(self.root / POSES, "transform_lidar_to_map_*.npy")[0])
        unpaired = poses - len(self._frames)
        skipped = {"poses_without_scan_or_image": unpaired} if unpaired else {}
        notes = {"poses_without_scan_or_image": f"{unpaired} of {poses} pose files have no LiDAR scan, image or camera "
                 f"transform within max_gap of their stamp"} if unpaired else {}
        return SourceInfo("terra-folder", str(self.root), len(self._frames), (self._frames[0][0], self._frames[-1][0]),
                          list(self.calibrations), f"{POSES}/ (one T_map_lidar file per scan)", skipped, notes,
                          {"calibrations_from": META if self._exact_cameras else CAMERA_YAML,
                           "global_map": bool(stamped_files(self.root / GLOBAL, "global_pc_*.npy")[1])})


def _read_pose(path: Path) -> np.ndarray:
    """4x4 pose from a (7,) [tx ty tz qx qy qz qw] file (metres, scalar-last quaternion)."""
    xyz_quat = load_npy(path, (7,), "[tx, ty, tz, qx, qy, qz, qw]")
    if not np.all(np.isfinite(xyz_quat)) or abs(np.linalg.norm(xyz_quat[3:]) - 1.0) > 1e-3:
        raise TerraError(f"{path}: expected finite values and a unit quaternion [qx, qy, qz, qw], got {xyz_quat.tolist()}")
    return pose_from_xyz_quat(xyz_quat)


def _cameras_from_yaml(root: Path) -> list[CameraCalibration]:
    """Calibrations from the reference config keys (for folders the authors' tools extracted)."""
    path = root / CAMERA_YAML
    if not path.is_file():
        raise TerraError(f"{root}: no {META} or {CAMERA_YAML} with camera intrinsics (cam0_K, cam0_dist, IMG_W, IMG_H)")
    try:
        cfg = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise TerraError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(cfg, dict):
        raise TerraError(f"{path}: expected a mapping with cam0_K, cam0_dist, IMG_W, IMG_H")
    cams = []
    n = 0
    while f"cam{n}_K" in cfg:
        try:
            K = np.asarray(cfg[f"cam{n}_K"], float).reshape(3, 3)
            dist = np.asarray(cfg.get(f"cam{n}_dist") or [], float)
            cams.append(CameraCalibration(f"cam{n}", int(cfg["IMG_W"]), int(cfg["IMG_H"]), K, dist))
        except (KeyError, ValueError, TypeError) as exc:
            raise TerraError(f"{path}: bad camera {n} keys ({exc}); expected cam{n}_K (9 floats), cam{n}_dist, IMG_W, IMG_H") from None
        n += 1
    return cams


class TerraFolderConfig(Section):
    """Options of the reference folder layout."""

    max_gap: float = Field(0.2, gt=0.0, description="seconds a scan's LiDAR file, images and camera transforms may lie from its pose stamp")


def _detect(path: Path) -> bool:
    return (Path(path) / POSES).is_dir() and (Path(path) / SCANS).is_dir()


def _open(path: Path, config: TerraFolderConfig) -> TerraFolderDataset:
    return TerraFolderDataset(path, max_gap=config.max_gap)


LOADER = Loader("terra-folder", _detect, _open, TerraFolderConfig, "the authors' extracted folder layout (Terra's own simulator output too)")
