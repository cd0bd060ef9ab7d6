"""The reference implementation's extracted folder layout ("terra-folder"): reader and writer.

Layout, as the authors' extraction tools write it (stamps t as {t:.6f} seconds; cameras numbered
n = 1..num_cams, like their config keys):
- transformations_lidar2global/transform_lidar_to_map_{t}.npy   (7,) T_map_lidar [tx ty tz qx qy qz qw]
- lidar_pc/lidar_pc_{t}.npy                                     (M, 4) x y z intensity, LiDAR frame
- global_pc/global_pc_{t}.npy                                   (N, 4) map frame, 0.4 m voxel centroids
- camera{n}_images/cam{n}_img_{t}.jpg                           RGB image, JPEG as the reference has it
  (quality 92, no chroma subsampling: lossy, mean error under 1 grey level on simulated images;
  the label images below are exact)
- transformations_lidar2cam{n}/transform_lidar_to_cam{n}_{t}.npy (7,) T_cam_lidar, one per scan
- msmap_camera_config.yaml: the authors' msmap camera keys (num_cams, IMG_W, IMG_H, cam{n}_K,
  cam{n}_dist, cam_axis; terra.datasets.msmap_config) to paste into their msmap config.
Terra's additions, which the authors' scripts ignore:
- lidar_labels/lidar_labels_{t}.npy (M, 2) int32 class id, instance id per point;
- camera{n}_semantic/cam{n}_sem_{t}.png, camera{n}_instance/cam{n}_inst_{t}.png: 16-bit label images
  (an instance image whose ids exceed 65535 is a 24-bit RGB PNG, id = R + 256 G + 65536 B);
- terra_dataset.json: name, stamps, exact camera calibrations (lens model and every coefficient);
  classes.json; ground_truth/;
- gnss.csv: GNSS fixes of the drive (terra.datasets.gnss), which anchor its frame on the Earth.
Folders written by Terra before it numbered cameras from 1 (camera0_images, cam0_K) read as well.

Cameras: the exact calibrations of terra_dataset.json, or the intrinsics of an msmap config (the
folder's own msmap_camera_config.yaml, or the authors' config given as `camera_config`, which wins)
with extrinsics from the per-scan lidar2cam files. The cameras a config calibrates and the image
folders present must agree: a camera without images or images without a calibration is an error,
so a folder with images never maps from its LiDAR alone.

The reader pairs each pose file with the nearest LiDAR scan, image and camera transform by stamp
(binary search) and skips a scan when any gap exceeds `max_gap` seconds (the config's
`unaligned_threshold` when it has one), as the reference does.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import yaml
from pydantic import Field

from terra.datasets.base import CameraFrame, ClassTable, Dataset, Frame, GnssDataset, SemanticClass, SourceInfo
from terra.datasets.folder_io import (
    calibration_from_json,
    calibration_to_json,
    image_size,
    load_npy,
    read_classes,
    read_instance_png,
    read_label_png,
    read_rgb,
    stamp_of,
    stamp_text,
    write_instance_png,
    write_label_png,
    write_rgb,
)
from terra.datasets.gnss import GNSS_CSV, NOT_READ, anchor_fields, read_gnss_csv, write_gnss_csv
from terra.datasets.msmap_config import msmap_camera_keys, read_msmap_config
from terra.datasets.registry import Loader
from terra.datasets.sync import nearest, stamped_files
from terra.errors import TerraError
from terra.geometry import CameraCalibration, pose_from_xyz_quat, pose_to_xyz_quat, transform_points, voxel_keys
from terra.npy import write_npy
from terra.progress import progress
from terra.schemas import Section

POSES = "transformations_lidar2global"
SCANS = "lidar_pc"
GLOBAL = "global_pc"
LABELS = "lidar_labels"
META = "terra_dataset.json"
CAMERA_YAML = "msmap_camera_config.yaml"
GLOBAL_LEAF = 0.4
FIRST_CAMERA = 1  # the authors' numbering; Terra's first folders started at 0
DEFAULT_MAX_GAP = 0.2  # seconds, the authors' simulation configs' unaligned_threshold
MAX_ANCHOR_POSES = 2000  # poses read (evenly spread) to fit the GNSS anchor: plenty for a heading
_IMAGE_FOLDER = re.compile(r"^camera(\d+)_images$")


class CameraFiles:
    """The file names of camera number `n` (1-based in the authors' layout) at a stamp."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.images = f"camera{n}_images"
        self.transforms = f"transformations_lidar2cam{n}"
        self.semantic = f"camera{n}_semantic"
        self.instance = f"camera{n}_instance"

    def image(self, t: float) -> str:
        return f"{self.images}/cam{self.n}_img_{stamp_text(t)}.jpg"

    def transform(self, t: float) -> str:
        return f"{self.transforms}/transform_lidar_to_cam{self.n}_{stamp_text(t)}.npy"

    def semantic_image(self, t: float) -> str:
        return f"{self.semantic}/cam{self.n}_sem_{stamp_text(t)}.png"

    def instance_image(self, t: float) -> str:
        return f"{self.instance}/cam{self.n}_inst_{stamp_text(t)}.png"


def image_name(camera_index: int, stamp: float) -> str:
    """Relative file name of the image of the `camera_index`-th camera (0-based) at `stamp`."""
    return CameraFiles(camera_index + FIRST_CAMERA).image(stamp)


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
        # Each flush re-sorts every voxel so far: waiting for half as many new points as there are
        # voxels keeps the total cost n log n on big maps. Sums come out the same whenever the
        # flushes happen (each voxel adds its rows in arrival order either way).
        if self._pending_n >= max(self.flush_every, len(self._keys) // 2):
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
    for frame in progress(
        (dataset[i] for i in range(len(dataset))), desc="writing frames", total=len(dataset), enabled=show_progress
    ):
        t = stamp_text(frame.stamp)
        stamps.append(float(t))
        write_npy(root / POSES / f"transform_lidar_to_map_{t}.npy", pose_to_xyz_quat(frame.T_map_lidar))
        inten = frame.intensity if frame.intensity is not None else np.zeros(len(frame.points), np.float32)
        scan = np.concatenate([frame.points, inten[:, None]], axis=1).astype(np.float32)
        write_npy(root / SCANS / f"lidar_pc_{t}.npy", scan)
        if frame.point_labels is not None:
            inst = frame.point_instances if frame.point_instances is not None else np.zeros_like(frame.point_labels)
            write_npy(root / LABELS / f"lidar_labels_{t}.npy", np.stack([frame.point_labels, inst], 1).astype(np.int32))
        acc.add(transform_points(frame.T_map_lidar, frame.points.astype(np.float64)), inten)
        for index, cam in enumerate(frame.cameras):
            files = CameraFiles(index + FIRST_CAMERA)
            if index >= len(cameras):
                cameras.append(cam.calibration)
                for d in (files.images, files.transforms, files.semantic, files.instance):
                    (root / d).mkdir(exist_ok=True)
            write_rgb(root / files.image(frame.stamp), cam.image)
            T_cam_lidar = pose_to_xyz_quat(cam.calibration.T_cam_lidar)
            write_npy(root / files.transform(frame.stamp), T_cam_lidar)
            if cam.semantic is not None:
                write_label_png(root / files.semantic_image(frame.stamp), cam.semantic)
            if cam.instance is not None:
                write_instance_png(root / files.instance_image(frame.stamp), cam.instance)
        if len(stamps) == 1:
            msmap_camera_keys(cameras)  # refuse what the authors' layout cannot hold before writing more
    last = stamp_text(max(stamps)) if stamps else stamp_text(0.0)
    write_npy(root / GLOBAL / f"global_pc_{last}.npy", acc.result())
    meta = {
        "format": "terra-folder",
        "version": 2,
        "name": dataset.name,
        "frames": len(stamps),
        "first_camera": FIRST_CAMERA,
        "cameras": [calibration_to_json(c) for c in cameras],
    }
    (root / META).write_text(json.dumps(meta, indent=1) + "\n")
    fixes = dataset.gnss_fixes() if isinstance(dataset, GnssDataset) else None
    if fixes is not None:
        write_gnss_csv(root / GNSS_CSV, fixes)
    (root / CAMERA_YAML).write_text(yaml.safe_dump(msmap_camera_keys(cameras), sort_keys=False))


# ------------------------------------------------------------------------------------------ reader
class TerraFolderDataset:
    """Frames of a folder in the reference layout (ours or the authors' own extraction).

    `cameras` (exact calibrations) or `camera_config` (an msmap YAML, the authors' own) replace the
    folder's calibration. `max_gap` None takes the config's unaligned_threshold, else 0.2 s.
    After opening, `skipped` / `skipped_notes` count the scans left out and why, `camera_source`
    names where the intrinsics came from and `camera_numbers` the cameras' numbers in the layout.
    """

    def __init__(
        self,
        root: Path,
        max_gap: float | None = None,
        cameras: list[CameraCalibration] | None = None,
        camera_config: Path | None = None,
    ) -> None:
        self.root = root = Path(root)
        if not (root / POSES).is_dir():
            raise TerraError(f"{root}: not a terra-folder dataset (no {POSES}/ folder)")
        meta = _read_meta(root / META)
        self.name = str(meta.get("name") or root.name)
        numbers, calibrations, exact, threshold = self._calibration(meta, cameras, camera_config)
        self.calibrations, self.camera_numbers, self._exact_cameras = calibrations, numbers, exact
        _check_image_folders(root, numbers, self.camera_source)
        tolerance = max_gap if max_gap is not None else threshold
        self.max_gap = float(tolerance if tolerance is not None else DEFAULT_MAX_GAP)
        self.classes: ClassTable = read_classes(root) or ClassTable([SemanticClass(0, "unlabeled")])
        self.skipped: dict[str, int] = {}
        self.skipped_notes: dict[str, str] = {}
        self._anchor: dict | None | object = NOT_READ  # wgs84_anchor, read once
        self._frames = self._pair_streams()
        if not self._frames:
            raise TerraError(
                f"{root}: no scan with a pose, a LiDAR file and every camera image within {self.max_gap} s"
            )
        self._check_image_sizes()

    def _calibration(
        self, meta: dict, cameras: list[CameraCalibration] | None, camera_config: Path | None
    ) -> tuple[list[int], list[CameraCalibration], bool, float | None]:
        """(camera numbers, calibrations, whether extrinsics are exact, unaligned_threshold)."""
        root = self.root
        if cameras is not None:
            self.camera_source = "given calibrations"
            return [_first_camera(root, meta) + i for i in range(len(cameras))], list(cameras), True, None
        if camera_config is not None:
            config = read_msmap_config(Path(camera_config))
            self.camera_source = str(camera_config)
            return config.numbers, config.cameras, False, config.unaligned_threshold
        if meta.get("cameras") is not None:
            self.camera_source = str(root / META)
            first = int(meta.get("first_camera") or 0)
            return (
                [first + i for i in range(len(meta["cameras"]))],
                [calibration_from_json(c, str(root / META)) for c in meta["cameras"]],
                True,
                None,
            )
        if (root / CAMERA_YAML).is_file():
            config = read_msmap_config(root / CAMERA_YAML)
            self.camera_source = str(root / CAMERA_YAML)
            return config.numbers, config.cameras, False, config.unaligned_threshold
        self.camera_source = ""
        return [], [], True, None

    def _pair_streams(self) -> list[tuple[float, Path, Path, list[tuple[Path, Path | None]]]]:
        """Each pose file with its nearest scan, image and transform per camera, within max_gap."""
        root = self.root
        pose_t, pose_f = stamped_files(root / POSES, "transform_lidar_to_map_*.npy")
        scan_t, scan_f = stamped_files(root / SCANS, "lidar_pc_*.npy")
        streams = []
        for n in self.camera_numbers:
            files = CameraFiles(n)
            transforms = stamped_files(root / files.transforms, f"transform_lidar_to_cam{n}_*.npy")
            if not self._exact_cameras and not transforms[1]:
                raise TerraError(
                    f"{root / files.transforms}: no lidar -> camera {n} transforms "
                    f"(transform_lidar_to_cam{n}_<t>.npy); camera {n}'s extrinsics are unknown"
                )
            streams.append((stamped_files(root / files.images, f"cam{n}_img_*.jpg"), transforms))
        frames = []
        for t, pose_file in zip(pose_t, pose_f):
            s, gap = nearest(scan_t, t)
            picks, gaps = [], [("LiDAR scan", gap)]
            for n, ((img_t, img_f), (tf_t, tf_f)) in zip(self.camera_numbers, streams):
                i, gi = nearest(img_t, t)
                k, gk = nearest(tf_t, t)
                gaps += [(f"camera {n} image", gi)] + ([(f"camera {n} transform", gk)] if tf_t.size else [])
                picks.append((img_f[i] if i >= 0 else None, tf_f[k] if k >= 0 else None))
            what, gap = max(gaps, key=lambda g: g[1])
            if gap <= self.max_gap:
                frames.append((float(t), pose_file, scan_f[s], picks))
            else:
                self.skipped["scans_unaligned"] = self.skipped.get("scans_unaligned", 0) + 1
                where = "missing" if np.isinf(gap) else f"{gap:.3f} s away"
                self.skipped_notes.setdefault(
                    "scans_unaligned", f"{pose_file}: nearest {what} is {where} (tolerance {self.max_gap} s)"
                )
        return frames

    def _check_image_sizes(self) -> None:
        """The first image of every camera has the calibrated size (the reference asserts it)."""
        for cal, (image_file, _) in zip(self.calibrations, self._frames[0][3]):
            size = image_size(image_file)
            if size != (cal.width, cal.height):
                source = self.camera_source or "the calibration"
                raise TerraError(
                    f"{image_file}: image is {size[0]}x{size[1]}, but {source} says "
                    f"{cal.width}x{cal.height} (IMG_W x IMG_H)"
                )

    def __len__(self) -> int:
        return len(self._frames)

    def __getitem__(self, index: int) -> Frame:
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range (0..{len(self) - 1})")
        t, pose_file, scan_file, picks = self._frames[index]
        scan = load_npy(scan_file, (None, 4), "x, y, z, intensity")
        labels = instances = None
        label_file = self.root / LABELS / f"lidar_labels_{stamp_text(t)}.npy"
        if label_file.is_file():
            li = load_npy(label_file, (len(scan), 2), "class id, instance id per point of its scan")
            labels, instances = li[:, 0].astype(np.int32), li[:, 1].astype(np.int32)
        cams = [
            self._camera_frame(n, cal, image_file, tf_file)
            for n, cal, (image_file, tf_file) in zip(self.camera_numbers, self.calibrations, picks)
        ]
        return Frame(
            index,
            t,
            np.ascontiguousarray(scan[:, :3], dtype=np.float32),
            _read_pose(pose_file),
            cams,
            scan[:, 3].astype(np.float32),
            labels,
            instances,
        )

    def _camera_frame(self, n: int, cal: CameraCalibration, image_file: Path, tf_file: Path | None) -> CameraFrame:
        if tf_file is not None and not self._exact_cameras:
            cal = CameraCalibration(cal.name, cal.width, cal.height, cal.K, cal.dist, _read_pose(tf_file), cal.model)
        image = read_rgb(image_file)
        if image.shape[:2] != (cal.height, cal.width):
            raise TerraError(
                f"{image_file}: image is {image.shape[1]}x{image.shape[0]}, calibration says {cal.width}x{cal.height}"
            )
        stamp = stamp_of(image_file)
        files = CameraFiles(n)
        sem_file, inst_file = self.root / files.semantic_image(stamp), self.root / files.instance_image(stamp)
        semantic = read_label_png(sem_file) if sem_file.is_file() else None
        instance = read_instance_png(inst_file) if inst_file.is_file() else None
        return CameraFrame(cal, stamp, image, semantic, instance, name=str(image_file.relative_to(self.root)))

    def wgs84_anchor(self) -> dict | None:
        """The anchor of the poses' frame fitted to the folder's GNSS fixes (gnss.csv, terra.datasets.gnss),
        or None without them or when they do not fix the frame (fewer than 3 in the drive's time span, a
        drive that hardly moves)."""
        if self._anchor is NOT_READ:
            self._anchor = self._fit_anchor()
        return self._anchor  # pyright: ignore[reportReturnType]  # read: a dict or None

    def _fit_anchor(self) -> dict | None:
        if not (self.root / GNSS_CSV).is_file():
            return None
        fixes = read_gnss_csv(self.root / GNSS_CSV)
        picks = np.unique(np.linspace(0, len(self._frames) - 1, min(len(self._frames), MAX_ANCHOR_POSES)).astype(int))
        stamps = np.array([self._frames[i][0] for i in picks])
        positions = np.array([_read_pose(self._frames[i][1])[:3, 3] for i in picks])
        return anchor_fields(stamps, positions, fixes, f"GNSS fixes of {self.name} ({GNSS_CSV})")

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
        """What `terra inspect` reports: frames, cameras as read, and the scans left out and why."""
        return SourceInfo(
            "terra-folder",
            str(self.root),
            len(self._frames),
            (self._frames[0][0], self._frames[-1][0]),
            list(self.calibrations),
            f"{POSES}/ (one T_map_lidar file per scan)",
            dict(self.skipped),
            dict(self.skipped_notes),
            {
                "calibrations_from": self.camera_source or "none (LiDAR only)",
                "camera_numbers": list(self.camera_numbers),
                "max_gap_s": self.max_gap,
                "global_map": bool(stamped_files(self.root / GLOBAL, "global_pc_*.npy")[1]),
                **({"gnss": self._gnss_info()} if (self.root / GNSS_CSV).is_file() else {}),
            },
        )

    def _gnss_info(self) -> dict:
        """The fixes of gnss.csv and the anchor they give the drive's frame (None: they do not fix it)."""
        return {
            "file": GNSS_CSV,
            "fixes": len(read_gnss_csv(self.root / GNSS_CSV)),
            "wgs84_anchor": self.wgs84_anchor(),
        }


def _read_meta(path: Path) -> dict:
    """terra_dataset.json as a plain dict of validated values ({} when the folder has none)."""
    from terra.schemas import TerraDatasetFile, read_model

    if not path.exists():
        return {}
    return read_model(path, TerraDatasetFile, "dataset description").model_dump()


def _first_camera(root: Path, meta: dict) -> int:
    """1 for the authors' numbering, 0 for folders Terra wrote before it followed it."""
    if meta.get("first_camera") is not None:
        return int(meta["first_camera"])
    return 0 if (root / "camera0_images").is_dir() else FIRST_CAMERA


def image_folders(root: Path) -> dict[int, Path]:
    """Camera number -> its `camera{n}_images/` folder, for folders holding at least one image."""
    out = {}
    for path in Path(root).iterdir():
        match = _IMAGE_FOLDER.match(path.name)
        if match and path.is_dir() and any(path.glob(f"cam{match.group(1)}_img_*.jpg")):
            out[int(match.group(1))] = path
    return dict(sorted(out.items()))


def _check_image_folders(root: Path, numbers: list[int], source: str) -> None:
    """TerraError naming both sides when the calibrated cameras and the image folders disagree."""
    folders = image_folders(root)
    if not numbers and folders:
        names = ", ".join(f"{p.name}/" for p in folders.values())
        raise TerraError(
            f"{root}: has images ({names}) but no camera calibration (no {META} or {CAMERA_YAML}); "
            f"pass the authors' msmap config with --camera-config MSMAP.yaml"
        )
    missing = [n for n in numbers if n not in folders]
    extra = [n for n in folders if n not in numbers]
    if missing or extra:
        calibrated = ", ".join(str(n) for n in numbers)
        found = ", ".join(f"{p.name}/" for p in folders.values()) or "none"
        problems = []
        if missing:
            problems.append(
                f"no images for camera{'s' if len(missing) > 1 else ''} {', '.join(str(n) for n in missing)}"
            )
        if extra:
            problems.append(f"no calibration for {', '.join(folders[n].name + '/' for n in extra)}")
        raise TerraError(
            f"{source}: calibrates cameras {calibrated} but {root} has image folders {found}: {'; '.join(problems)}"
        )


def _read_pose(path: Path) -> np.ndarray:
    """4x4 pose from a (7,) [tx ty tz qx qy qz qw] file (metres, scalar-last quaternion)."""
    xyz_quat = load_npy(path, (7,), "[tx, ty, tz, qx, qy, qz, qw]")
    if not np.all(np.isfinite(xyz_quat)) or abs(np.linalg.norm(xyz_quat[3:]) - 1.0) > 1e-3:
        raise TerraError(
            f"{path}: expected finite values and a unit quaternion [qx, qy, qz, qw], got {xyz_quat.tolist()}"
        )
    return pose_from_xyz_quat(xyz_quat)


class TerraFolderConfig(Section):
    """Options of the reference folder layout."""

    max_gap: float | None = Field(
        default=None,
        gt=0.0,
        description="seconds a scan's LiDAR file, images and camera transforms "
        "may lie from its pose stamp; None = the camera config's unaligned_threshold, else 0.2",
    )
    camera_config: Path | None = Field(
        default=None,
        description="the authors' msmap YAML (num_cams, IMG_W, IMG_H, cam{n}_K, "
        "cam{n}_dist, cam_axis; other keys ignored): replaces the folder's own calibration",
    )


def _detect(path: Path) -> bool:
    return (Path(path) / POSES).is_dir() and (Path(path) / SCANS).is_dir()


def _open(path: Path, config: TerraFolderConfig) -> TerraFolderDataset:
    return TerraFolderDataset(path, max_gap=config.max_gap, camera_config=config.camera_config)


LOADER = Loader(
    "terra-folder",
    _detect,
    _open,
    TerraFolderConfig,
    "the authors' extracted folder layout (Terra's own simulator output too)",
)
