"""KITTI odometry / SemanticKITTI layout: reader and writer.

A sequence folder `sequences/NN/` holds, with the real dataset's conventions:
- velodyne/NNNNNN.bin: float32 (x, y, z, reflectance) per point, LiDAR frame;
- labels/NNNNNN.label: uint32 per point, class = value & 0xFFFF (SemanticKITTI ids), instance = value >> 16;
- poses.txt: one 3x4 row-major camera-0 pose per scan; the LiDAR pose is Tr^-1 P Tr with `Tr`
  (LiDAR -> camera 0) from calib.txt;
- calib.txt: P0..P3 projection matrices and Tr; times.txt: seconds per scan;
- image_2/NNNNNN.png: the camera image (P2), image_3/ for a second camera.
Terra's writer makes camera 0 its first camera (so P2 = [K | 0]) and writes `poses.txt` in the
map frame (P = Tr T_map_lidar Tr^-1; the first pose is not forced to identity). Beside the real
files it adds, ignored by SemanticKITTI tools: image_{2+n}_semantic/ and image_{2+n}_instance/
(16-bit PNG in the same label ids; an instance image with ids above 65535 as 24-bit RGB
PNG, id = R + 256 G + 65536 B), terra_cameras.json (exact calibrations with distortion), and
at the dataset root classes.json, ground_truth/ and `semantic-kitti.yaml`, a legend in
SemanticKITTI's yaml convention that names every id used, including ids 100+ for classes the
real dataset does not have. Real sequences (no legend) read with the standard SemanticKITTI table,
and their cameras come from P2/P3 (K and the pose relative to camera 0 by RQ decomposition; no
distortion, as KITTI images are rectified).
"""

from __future__ import annotations

import io
import json
import warnings
from pathlib import Path
from typing import Literal

import numpy as np
import yaml
from pydantic import Field

from terra.datasets.base import CameraFrame, ClassTable, Dataset, Frame, PosesUnavailable, SemanticClass, SourceInfo
from terra.datasets.folder_io import (
    calibration_from_json,
    calibration_to_json,
    image_size,
    read_classes,
    read_instance_png,
    read_json,
    read_label_png,
    read_point_labels,
    read_rgb,
    read_velodyne_scan,
    write_instance_png,
    write_label_png,
    write_rgb,
)
from terra.datasets.kitti_common import (
    STANDARD_LABELS,
    STANDARD_TERRAIN,
    check_translation,
    decompose_projection,
    read_calib_file,
    standard_classes,
)
from terra.datasets.registry import Loader
from terra.datasets.sim_classes import CLASS_COLORS, SIM_CLASSES
from terra.errors import TerraError
from terra.fileio import read_text, read_yaml
from terra.geometry import CameraCalibration, invert_pose, make_pose
from terra.progress import progress
from terra.schemas import Section

LEGEND = "semantic-kitti.yaml"
CAMERAS = "terra_cameras.json"
FIRST_FREE_ID = 100  # SemanticKITTI leaves 100..251 unused

# Velodyne -> camera-0 rotation of a KITTI-like rig, used when a dataset has no camera.
_DEFAULT_TR = make_pose(np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]), np.zeros(3))


def kitti_ids(classes: ClassTable) -> dict[int, int]:
    """Our class id -> the id written to .label files: its SemanticKITTI id, or a free id >= 100."""
    used = {c.semantickitti_id for c in classes if c.semantickitti_id is not None}
    out, free = {}, FIRST_FREE_ID
    for c in classes:
        if c.semantickitti_id is not None:
            out[c.id] = int(c.semantickitti_id)
        else:
            while free in used:
                free += 1
            out[c.id] = free
            used.add(free)
    return out


def _fmt(values: np.ndarray) -> str:
    return " ".join(repr(float(v)) for v in np.ravel(values))


def _lookup(mapping: dict[int, int], size: int | None = None) -> np.ndarray:
    table = np.zeros((max(mapping) + 1) if size is None else size, np.int64)
    for k, v in mapping.items():
        table[k] = v
    return table


# ------------------------------------------------------------------------------------------ writer
def write_semantickitti(dataset: Dataset, root: Path, sequence: str = "00", show_progress: bool = True) -> None:
    """Write `dataset` under `root` (an empty folder) as `sequences/<sequence>/`."""
    root = Path(root)
    seq = root / "sequences" / sequence
    for d in ("velodyne", "labels"):
        (seq / d).mkdir(parents=True, exist_ok=True)
    ids = kitti_ids(dataset.classes)
    to_kitti = _lookup(ids)
    poses, times, cameras = [], [], []
    Tr = None
    for frame in progress(
        (dataset[i] for i in range(len(dataset))), desc="writing frames", total=len(dataset), enabled=show_progress
    ):
        name = f"{len(times):06d}"
        if Tr is None:
            Tr = frame.cameras[0].calibration.T_cam_lidar if frame.cameras else _DEFAULT_TR
        inten = frame.intensity if frame.intensity is not None else np.zeros(len(frame.points), np.float32)
        # write_bytes, not ndarray.tofile: a short write (full disk) then says why, with its errno
        (seq / "velodyne" / f"{name}.bin").write_bytes(
            np.concatenate([frame.points, inten[:, None]], axis=1).astype("<f4").tobytes()
        )
        if frame.point_labels is not None:
            inst = frame.point_instances if frame.point_instances is not None else np.zeros_like(frame.point_labels)
            if inst.size and (inst.min() < 0 or inst.max() > 0xFFFF):
                raise TerraError("instance ids must lie in 0..65535 for SemanticKITTI .label files")
            value = to_kitti[frame.point_labels].astype(np.uint32) | (inst.astype(np.uint32) << np.uint32(16))
            (seq / "labels" / f"{name}.label").write_bytes(value.astype("<u4").tobytes())
        poses.append(Tr @ frame.T_map_lidar @ invert_pose(Tr))
        times.append(float(frame.stamp))
        for n, cam in enumerate(frame.cameras):
            folder = f"image_{2 + n}"
            if n >= len(cameras):
                cameras.append(cam.calibration)
                for d in (folder, f"{folder}_semantic", f"{folder}_instance"):
                    (seq / d).mkdir(exist_ok=True)
            write_rgb(seq / folder / f"{name}.png", cam.image)
            if cam.semantic is not None:
                write_label_png(seq / f"{folder}_semantic" / f"{name}.png", to_kitti[cam.semantic])
            if cam.instance is not None:
                write_instance_png(seq / f"{folder}_instance" / f"{name}.png", cam.instance)
    Tr = _DEFAULT_TR if Tr is None else Tr
    (seq / "poses.txt").write_text("".join(_fmt(P[:3]) + "\n" for P in poses))
    (seq / "times.txt").write_text("".join(repr(t) + "\n" for t in times))
    lines = []
    cam0 = cameras[0] if cameras else None
    for k in range(max(4, 2 + len(cameras))):
        n = k - 2
        cal = cameras[n] if 0 <= n < len(cameras) else cam0
        # Projection from camera-0 coordinates into camera n: K [R | t] with T_n0 = T_n_lidar Tr^-1.
        P = np.hstack([np.eye(3), np.zeros((3, 1))]) if cal is None else cal.K @ (cal.T_cam_lidar @ invert_pose(Tr))[:3]
        lines.append(f"P{k}: {_fmt(P)}\n")
    lines.append(f"Tr: {_fmt(Tr[:3])}\n")
    (seq / "calib.txt").write_text("".join(lines))
    (seq / CAMERAS).write_text(json.dumps({"cameras": [calibration_to_json(c) for c in cameras]}, indent=1) + "\n")
    (root / LEGEND).write_text(yaml.safe_dump(_legend(dataset.classes, ids), sort_keys=False))


def _legend(classes: ClassTable, ids: dict[int, int]) -> dict:
    """semantic-kitti.yaml-style legend for the ids this dataset writes."""
    labels, colors, learning = {}, {}, {}
    from_sim = _sim_colors()
    for train, c in enumerate(sorted(classes, key=lambda c: ids[c.id])):
        k = ids[c.id]
        labels[k] = c.name
        if k in STANDARD_LABELS:
            colors[k] = list(STANDARD_LABELS[k][1])
        else:
            rgb = from_sim.get(c.name, (128, 128, 128))
            colors[k] = [int(rgb[2]), int(rgb[1]), int(rgb[0])]
        learning[k] = train
    return {
        "labels": labels,
        "color_map": colors,
        "learning_map": learning,
        "learning_map_inv": {v: k for k, v in learning.items()},
        "learning_ignore": {v: v == 0 for v in learning.values()},
    }


def _sim_colors() -> dict[str, tuple[int, int, int]]:
    """RGB render colour of each simulator class, by name (the legend's colours for classes
    SemanticKITTI does not have)."""
    colors: dict[str, tuple[int, int, int]] = {}
    for c in SIM_CLASSES:
        r, g, b = (int(v) for v in CLASS_COLORS[c.id])
        colors[c.name] = (r, g, b)
    return colors


# ------------------------------------------------------------------------------------------ reader
def sequence_dir(path: Path) -> Path:
    """The sequence folder (the one holding velodyne/) at `path`: itself, or the only
    `sequences/NN/` of a dataset root; TerraError naming `path` otherwise."""
    path = Path(path)
    if (path / "velodyne").is_dir():
        return path
    seqs = (
        sorted(p for p in (path / "sequences").iterdir() if (p / "velodyne").is_dir())
        if (path / "sequences").is_dir()
        else []
    )
    if len(seqs) == 1:
        return seqs[0]
    if not seqs:
        raise TerraError(f"{path}: no sequences/NN/velodyne/ folder (expected a SemanticKITTI layout)")
    raise TerraError(f"{path}: {len(seqs)} sequences; open one of them, e.g. {seqs[0]}")


class SemanticKittiConfig(Section):
    """Options of the KITTI odometry / SemanticKITTI loader."""

    poses: Literal["poses.txt", "odometry"] = Field(
        default="poses.txt",
        description="where T_map_lidar comes from: 'poses.txt' (the sequence's ground truth) or 'odometry' "
        "(KISS-ICP on the scans; poses.txt, when present, only measures its error)",
    )


class SemanticKittiDataset:
    """Frames of one SemanticKITTI / KITTI odometry sequence."""

    def __init__(self, path: Path, config: SemanticKittiConfig | None = None) -> None:
        config = config or SemanticKittiConfig()
        self.seq = seq = sequence_dir(path)
        root = seq.parent.parent if seq.parent.name == "sequences" else seq
        self.root = root
        self.name = f"{root.name}/{seq.name}" if root != seq else seq.name
        self.scans = sorted((seq / "velodyne").glob("*.bin"))
        if not self.scans:
            raise TerraError(f"{seq / 'velodyne'}: no .bin scans")
        calib_path = seq / "calib.txt"
        calib_file = read_calib_file(calib_path) if calib_path.exists() else None
        calib: dict[str, np.ndarray] = {}
        self.Tr = np.eye(4)
        if calib_file is not None:
            keys = calib_file.keys()
            calib = {key: calib_file.matrix(key, (3, 4), "a 3x4 matrix, row-major") for key in keys}
            if "Tr" in calib:
                self.Tr = calib_file.pose_3x4("Tr")
        self._calib_file = calib_file
        self.needs_odometry = config.poses == "odometry"
        self.poses = self._read_poses(seq / "poses.txt")
        times_path = seq / "times.txt"
        if times_path.is_file():
            self.stamps = _read_table(times_path, 1, len(self.scans), "one time in seconds")[:, 0]
        else:
            self.stamps = np.arange(len(self.scans), dtype=float)
        self.cameras, self._camera_folders = self._cameras(calib)
        self._ids_from_kitti, self.classes = self._class_mapping(root)

    def _read_poses(self, poses_path: Path) -> np.ndarray:
        """(F, 4, 4) T_map_lidar from poses.txt (NaN without it when odometry makes the poses)."""
        if not poses_path.is_file():
            if self.needs_odometry:
                return np.full((len(self.scans), 4, 4), np.nan)
            raise PosesUnavailable(f"{self.seq}: no poses.txt (the sequence's ground-truth poses)")
        rows = _read_table(poses_path, 12, len(self.scans), "12 numbers (a 3x4 camera-0 pose, row-major)")
        # poses.txt holds camera-0 poses P; the LiDAR pose is Tr^-1 P Tr.
        P = np.zeros((len(rows), 4, 4))
        P[:, :3, :] = rows.reshape(-1, 3, 4)
        P[:, 3, 3] = 1.0
        return invert_pose(self.Tr) @ P @ self.Tr

    def _cameras(self, calib: dict[str, np.ndarray]) -> tuple[list[CameraCalibration], list[str]]:
        """Calibrations and image folders: exact ones from terra_cameras.json (ours, with
        distortion), else from P2/P3 of calib.txt for the image folders present."""
        exact = self.seq / CAMERAS
        if exact.is_file():
            rows = read_json(exact).get("cameras")
            if not isinstance(rows, list):
                raise TerraError(f'{exact}: expected {{"cameras": [calibration, ...]}}')
            cams = [calibration_from_json(c, str(exact)) for c in rows]
            return cams, [f"image_{2 + n}" for n in range(len(cams))]
        cams, folders = [], []
        for k in (2, 3):
            folder = self.seq / f"image_{k}"
            first = sorted(folder.glob("*.png")) if folder.is_dir() else []
            if f"P{k}" not in calib or not first:
                continue
            try:
                K, T_k_0 = decompose_projection(calib[f"P{k}"].reshape(3, 4))
            except ValueError as exc:
                raise TerraError(f"{self._calib_where(k)}: P{k} {exc}") from None
            check_translation(T_k_0[:3, 3], f"{self._calib_where(k)}: P{k}'s baseline K^-1 t")
            w, h = image_size(first[0])
            cams.append(CameraCalibration(f"image_{k}", w, h, K, np.zeros(5), T_k_0 @ self.Tr))
            folders.append(f"image_{k}")
        return cams, folders

    def _calib_where(self, k: int) -> str:
        return self._calib_file.where(f"P{k}") if self._calib_file else str(self.seq / "calib.txt")

    def _class_mapping(self, root: Path) -> tuple[np.ndarray, ClassTable]:
        legend_path = root / LEGEND
        legend = _read_legend(legend_path) if legend_path.exists() else None
        ours = read_classes(root)
        if ours is not None and legend is not None:
            mapping = {}
            for kid, name in legend.items():
                try:
                    mapping[kid] = ours.by_name(name).id
                except KeyError:
                    raise TerraError(f"{legend_path}: label {kid} {name!r} is not in {root / 'classes.json'}") from None
            return _lookup(mapping, 1 << 16), ours
        if legend is not None:
            table = ClassTable([SemanticClass(k, v, k in STANDARD_TERRAIN, k) for k, v in sorted(legend.items())])
        else:
            table = standard_classes()
        return _lookup({c.id: c.id for c in table}, 1 << 16), table

    def __len__(self) -> int:
        return len(self.scans)

    def __getitem__(self, index: int) -> Frame:
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range (0..{len(self) - 1})")
        scan_path = self.scans[index]
        raw = read_velodyne_scan(scan_path)
        stem = scan_path.stem
        labels = instances = None
        label_path = self.seq / "labels" / f"{stem}.label"
        if label_path.exists():
            value = read_point_labels(label_path, raw.shape[0])
            labels = self._ids_from_kitti[value & 0xFFFF].astype(np.int32)
            instances = (value >> 16).astype(np.int32)
        stamp = float(self.stamps[index])
        cams = []
        for cal, folder in zip(self.cameras, self._camera_folders):
            img_path = self.seq / folder / f"{stem}.png"
            if not img_path.is_file():
                continue
            sem_path = self.seq / f"{folder}_semantic" / f"{stem}.png"
            inst_path = self.seq / f"{folder}_instance" / f"{stem}.png"
            sem = self._ids_from_kitti[read_label_png(sem_path)].astype(np.int32) if sem_path.is_file() else None
            inst = read_instance_png(inst_path) if inst_path.is_file() else None
            cams.append(
                CameraFrame(cal, stamp, read_rgb(img_path), sem, inst, name=str(img_path.relative_to(self.root)))
            )
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

    def global_map(self) -> np.ndarray | None:
        return None

    def ground_truth(self):
        from terra.datasets.ground_truth import load_ground_truth

        return load_ground_truth(self.root)

    def info(self) -> SourceInfo:
        """What `terra inspect` reports: scans, cameras (exact or from P2/P3), label files present."""
        labels = len(list((self.seq / "labels").glob("*.label"))) if (self.seq / "labels").is_dir() else 0
        span = (float(self.stamps[0]), float(self.stamps[-1]))
        return SourceInfo(
            "semantickitti",
            str(self.seq),
            len(self.scans),
            span,
            list(self.cameras),
            "odometry (KISS-ICP)" if self.needs_odometry else "poses.txt (camera-0 poses, LiDAR pose = Tr^-1 P Tr)",
            {},
            {},
            {
                "sequence": self.name,
                "label_files": labels,
                "camera_folders": list(self._camera_folders),
                "calibrations_from": CAMERAS if (self.seq / CAMERAS).is_file() else "calib.txt",
            },
        )


def _read_table(path: Path, columns: int, rows: int, what: str) -> np.ndarray:
    """(rows, columns) finite numbers of a whitespace-separated text file; TerraError naming the file."""
    text = read_text(path, what)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data": the shape check below says it
            table = np.loadtxt(io.StringIO(text), ndmin=2, dtype=np.float64)
    except ValueError as exc:
        raise TerraError(f"{path}: expected {rows} lines of {what} ({str(exc).splitlines()[0][:100]})") from None
    if table.shape != (rows, columns):
        raise TerraError(f"{path}: expected {rows} lines of {what}, got shape {table.shape}")
    if not np.isfinite(table).all():
        raise TerraError(f"{path}: holds non-finite numbers; expected {rows} lines of {what}")
    return table


def _read_legend(path: Path) -> dict[int, str]:
    """id -> name of a semantic-kitti.yaml legend's `labels` mapping (ids 0..65535)."""
    legend = read_yaml(path, "SemanticKITTI legend")
    labels = legend.get("labels") if isinstance(legend, dict) else None
    if not isinstance(labels, dict) or not all(
        isinstance(k, int) and not isinstance(k, bool) and 0 <= k <= 0xFFFF and isinstance(v, str) and v
        for k, v in labels.items()
    ):
        raise TerraError(f"{path}: malformed legend; expected a 'labels' mapping of ids 0..65535 to names")
    return dict(labels)


def _detect(path: Path) -> bool:
    path = Path(path)
    return (path / "velodyne").is_dir() or (path / "sequences").is_dir()


LOADER = Loader(
    "semantickitti",
    _detect,
    lambda path, options: SemanticKittiDataset(path, options),
    SemanticKittiConfig,
    "KITTI odometry / SemanticKITTI sequences (velodyne/, labels/, poses.txt, calib.txt)",
    without_poses={"poses": "odometry"},
)
