"""The camera keys of the authors' msmap config (their `terra/config/**/msmap*.yaml`), read and written.

Their cameras are numbered from 1: `num_cams: N`, then for n = 1..N `cam{n}_K` (9 floats,
row-major) and `cam{n}_dist` (OpenCV coefficients, `[]` for none: 4 and 14 in their configs),
`IMG_W` / `IMG_H` (one image size for every camera) and `cam_axis` (one of '+x', '-x', '+y', '-y'
per camera: the LiDAR half-space the camera looks into). `unaligned_threshold` (seconds) is their
tolerance for pairing a scan with images and transforms. Every other key of their file (paths,
YOLO, DBSCAN, ...) is accepted and ignored. Terra adds `cam{n}_model: fisheye` for equidistant
lenses (their scripts ignore unknown keys); folders written by Terra before cameras were numbered
from 1 hold `cam0_K`, ... and read the same way.

Extrinsics are not in this file: the authors' extraction writes them per scan
(`transformations_lidar2cam{n}/`), so the calibrations read here carry T_cam_lidar = identity.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from terra import lens
from terra.errors import TerraError
from terra.geometry import CameraCalibration

AXES = ("+x", "-x", "+y", "-y")


@dataclass
class MsmapCameras:
    """Cameras of an msmap config: `numbers[i]` is the config's number of `cameras[i]` (1-based in
    the authors' files, 0-based in Terra's earliest folders); `axes` their cam_axis values."""

    source: Path
    cameras: list[CameraCalibration]
    numbers: list[int]
    axes: list[str] = field(default_factory=list)
    unaligned_threshold: float | None = None


def read_msmap_config(path: Path) -> MsmapCameras:
    """The cameras of an msmap YAML file (any of the authors' msmap configs, as it is)."""
    from terra.fileio import parse_yaml, read_text

    path = Path(path)
    text = read_text(path, "camera config")
    cfg = parse_yaml(text, path, "camera config")
    if not isinstance(cfg, dict):
        raise TerraError(f"{path}: expected a mapping with num_cams, IMG_W, IMG_H, cam1_K, cam1_dist, cam_axis")
    where = _Where(path, text)
    numbers = _camera_numbers(cfg, where)
    cameras = []
    if numbers:
        width, height = (_positive_int(cfg, key, where) for key in ("IMG_W", "IMG_H"))
        cameras = [_camera(cfg, n, width, height, where) for n in numbers]
    axes = _axes(cfg.get("cam_axis"), len(numbers), where)
    threshold = cfg.get("unaligned_threshold")
    if threshold is not None and (
        isinstance(threshold, bool) or not isinstance(threshold, (int, float)) or threshold <= 0
    ):
        raise TerraError(
            f"{where('unaligned_threshold')}: unaligned_threshold must be a positive number of seconds, "
            f"got {threshold!r}"
        )
    return MsmapCameras(path, cameras, numbers, axes, None if threshold is None else float(threshold))


class _Where:
    """ "file:line" of a top-level key of a YAML file (the file alone for a missing key)."""

    def __init__(self, path: Path, text: str) -> None:
        self.path = path
        self.lines: dict[str, int] = {}
        node = yaml.compose(text)
        if isinstance(node, yaml.MappingNode):
            for key, _ in node.value:
                if isinstance(key, yaml.ScalarNode):
                    self.lines.setdefault(key.value, key.start_mark.line + 1)

    def __call__(self, key: str | None = None) -> str:
        return f"{self.path}:{self.lines[key]}" if key in self.lines else str(self.path)


def _camera_numbers(cfg: dict, where: _Where) -> list[int]:
    """1..num_cams (or 0.. for Terra's earliest folders); without num_cams, consecutive cam{n}_K keys."""
    first = 0 if "cam0_K" in cfg else 1
    if "num_cams" not in cfg:
        numbers = []
        while f"cam{first + len(numbers)}_K" in cfg:
            numbers.append(first + len(numbers))
        return numbers
    count = cfg["num_cams"]
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise TerraError(f"{where('num_cams')}: num_cams must be a non-negative integer, got {count!r}")
    numbers = range(first, first + count)  # lazy: a num_cams of 10^12 stops at its first missing cam{n}_K
    for n in numbers:
        if f"cam{n}_K" not in cfg:
            raise TerraError(f"{where('num_cams')}: num_cams is {count} but there is no cam{n}_K (9 floats, row-major)")
    return list(numbers)


def _positive_int(cfg: dict, key: str, where: _Where) -> int:
    value = cfg.get(key)
    if value is None:
        raise TerraError(
            f"{where()}: no {key} (image {'width' if key == 'IMG_W' else 'height'} in pixels, one for every camera)"
        )
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise TerraError(f"{where(key)}: {key} must be a positive integer (pixels), got {value!r}")
    return value


def _camera(cfg: dict, n: int, width: int, height: int, where: _Where) -> CameraCalibration:
    k_key, dist_key, model_key = f"cam{n}_K", f"cam{n}_dist", f"cam{n}_model"
    K = _numbers(cfg[k_key], k_key, where)
    if K.size != 9:
        raise TerraError(f"{where(k_key)}: {k_key} has {K.size} numbers, expected 9 (the 3x3 intrinsics, row-major)")
    if dist_key not in cfg:
        raise TerraError(f"{where()}: no {dist_key} (OpenCV distortion coefficients; write {dist_key}: [] for none)")
    model = cfg.get(model_key, lens.PINHOLE)
    if model not in lens.LENS_MODELS:
        raise TerraError(f"{where(model_key)}: {model_key} must be one of {', '.join(lens.LENS_MODELS)}, got {model!r}")
    try:
        dist = lens.check_coefficients(model, _numbers(cfg[dist_key] or [], dist_key, where))
    except ValueError as exc:
        raise TerraError(f"{where(dist_key)}: {dist_key}: {exc}") from None
    try:
        return CameraCalibration(f"cam{n}", width, height, K.reshape(3, 3), dist, np.eye(4), model)
    except ValueError as exc:
        raise TerraError(f"{where(k_key)}: {k_key}: {str(exc).split(': ', 1)[-1]}") from None


def _numbers(value, key: str, where: _Where) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or not all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
    ):
        raise TerraError(f"{where(key)}: {key} must be a list of numbers, got {str(value)[:60]!r}")
    return np.asarray(value, dtype=np.float64)


def _axes(value, count: int, where: _Where) -> list[str]:
    if value is None:
        return []
    axes = [value] if isinstance(value, str) else value
    if not isinstance(axes, list) or any(a not in AXES for a in axes):
        raise TerraError(f"{where('cam_axis')}: cam_axis must be one of {', '.join(AXES)} per camera, got {value!r}")
    if count and len(axes) != count:
        raise TerraError(f"{where('cam_axis')}: cam_axis has {len(axes)} entries for {count} cameras")
    return list(axes)


def msmap_camera_keys(cameras: list[CameraCalibration]) -> dict:
    """The authors' msmap camera keys for `cameras` (numbered from 1), exact coefficient vectors
    included. Their format has one image size: cameras of different sizes are refused."""
    out: dict = {"num_cams": len(cameras)}
    if cameras:
        sizes = {(c.width, c.height) for c in cameras}
        if len(sizes) > 1:
            raise TerraError(
                f"the authors' layout has one image size (IMG_W x IMG_H) for all cameras, got {sorted(sizes)}"
            )
        out["IMG_W"], out["IMG_H"] = int(cameras[0].width), int(cameras[0].height)
    for n, cam in enumerate(cameras, start=1):
        out[f"cam{n}_K"] = [float(v) for v in cam.K.ravel()]
        out[f"cam{n}_dist"] = [float(v) for v in cam.dist]
        if cam.model != lens.PINHOLE:
            out[f"cam{n}_model"] = cam.model
    out["cam_axis"] = [camera_axis(cam.T_cam_lidar) for cam in cameras]
    return out


def camera_axis(T_cam_lidar: np.ndarray) -> str:
    """The LiDAR half-space a camera looks into ('+x', '-x', '+y', '-y'): the horizontal LiDAR axis
    closest to its optical axis."""
    z_in_lidar = np.asarray(T_cam_lidar)[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    a = int(np.argmax(np.abs(z_in_lidar[:2])))
    return ("+" if z_in_lidar[a] >= 0 else "-") + "xy"[a]
