"""Small file helpers shared by the dataset folder formats (terra_folder, semantickitti).

Images: RGB as JPEG/PNG through Pillow; label images as 16-bit PNG (exact, compact). No pickle.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

from terra.datasets.base import ClassTable
from terra.errors import TerraError
from terra.geometry import CameraCalibration

CLASSES_FILE = "classes.json"


def write_classes(root: Path, classes: ClassTable) -> None:
    (Path(root) / CLASSES_FILE).write_text(json.dumps({"classes": classes.to_json()}, indent=1) + "\n")


def read_classes(root: Path) -> ClassTable | None:
    """The class table in `root/classes.json`, or None when the folder has none."""
    path = Path(root) / CLASSES_FILE
    if not path.is_file():
        return None
    try:
        return ClassTable.from_json(read_json(path)["classes"])
    except (ValueError, KeyError, TypeError) as exc:
        raise TerraError(f"{path}: malformed class table ({exc})") from None


def calibration_to_json(cal: CameraCalibration) -> dict:
    """Exact JSON form of a calibration (floats keep full precision through repr)."""
    return {"name": cal.name, "width": int(cal.width), "height": int(cal.height), "K": cal.K.tolist(),
            "model": cal.model, "dist": cal.dist.tolist(), "T_cam_lidar": cal.T_cam_lidar.tolist()}


def calibration_from_json(d: dict, source: str) -> CameraCalibration:
    try:
        return CameraCalibration(str(d["name"]), int(d["width"]), int(d["height"]), np.asarray(d["K"], float),
                                 np.asarray(d["dist"], float), np.asarray(d["T_cam_lidar"], float),
                                 str(d.get("model", "pinhole")))
    except (KeyError, TypeError, ValueError) as exc:
        raise TerraError(f"{source}: malformed camera calibration ({exc})") from None


def write_label_png(path: Path, labels: np.ndarray) -> None:
    """A label image (H, W) of non-negative ids below 65536 as a 16-bit greyscale PNG."""
    if labels.size and (labels.min() < 0 or labels.max() > 65535):
        raise TerraError(f"{path}: label ids must lie in 0..65535 to be stored as 16-bit PNG")
    Image.fromarray(labels.astype(np.uint16)).save(path, format="PNG", compress_level=6)


def read_label_png(path: Path) -> np.ndarray:
    """(H, W) int32 ids from a 16-bit (or 8-bit) PNG."""
    try:
        with Image.open(path) as im:
            labels = np.asarray(im)
    except OSError as exc:
        raise TerraError(f"{path}: unreadable label image ({exc})") from None
    if labels.ndim != 2:
        raise TerraError(f"{path}: expected a single-channel label image, got shape {labels.shape}")
    return labels.astype(np.int32)


def write_rgb(path: Path, image: np.ndarray, quality: int = 92) -> None:
    """RGB uint8 (H, W, 3) as JPEG (by the .jpg suffix) or PNG (lossless)."""
    im = Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8))
    if Path(path).suffix.lower() in (".jpg", ".jpeg"):
        im.save(path, format="JPEG", quality=quality, subsampling=0)
    else:
        im.save(path, format="PNG", compress_level=6)


def read_rgb(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB, whatever the file's mode."""
    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except OSError as exc:
        raise TerraError(f"{path}: unreadable image ({exc})") from None


def stamp_text(stamp: float) -> str:
    """A stamp (seconds) as the reference layout writes it: exactly six decimals."""
    return f"{stamp:.6f}"


def stamp_of(path: Path) -> float:
    """The stamp in a file name: the text after the last '_' of the stem."""
    text = Path(path).stem.rsplit("_", 1)[-1]
    try:
        return float(text)
    except ValueError:
        raise TerraError(f"{path}: expected a name ending in _<seconds>, e.g. lidar_pc_12.000000.npy") from None


def load_npy(path: Path, shape: tuple[int | None, ...] | None = None, what: str = "") -> np.ndarray:
    """A .npy array (never pickled); with `shape`, TerraError unless it matches (None = any length)."""
    try:
        with open(path, "rb") as f:
            if f.read(6) != b"\x93NUMPY":
                raise TerraError(f"{path}: not a .npy file")
        array = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise TerraError(f"{path}: unreadable array ({exc})") from None
    if shape is not None and (array.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, array.shape))):
        expected = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise TerraError(f"{path}: expected an array of shape {expected}{' ' + what if what else ''}, got {array.shape}")
    return array


def read_json(path: Path) -> dict:
    """A JSON object from `path`; TerraError naming the file when it is unreadable or not an object."""
    try:
        value = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise TerraError(f"{path}: unreadable JSON ({exc})") from None
    if not isinstance(value, dict):
        raise TerraError(f"{path}: expected a JSON object")
    return value
