"""Small file helpers shared by the dataset folder formats (terra_folder, semantickitti, kitti_raw).

Images: RGB as JPEG/PNG through Pillow; label images as 16-bit PNG (exact, compact); instance
images as 16-bit PNG while every id fits, else as 24-bit RGB PNG with id = R + 256 G + 65536 B (the
COCO panoptic encoding), so worlds with more than 65,535 objects keep their ids. No pickle.
Reading goes through terra.fileio (no blocking on a FIFO, one line for a folder or an unreadable
file), structured files through terra.schemas, and images are checked for their pixel count from
the header before they are decoded (MAX_IMAGE_PIXELS): a small file declaring 20000 x 20000 pixels
is one line, not gigabytes.
"""

from __future__ import annotations

import io
import json
import struct
import warnings
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from terra.datasets.base import ClassTable, SemanticClass
from terra.errors import TerraError
from terra.fileio import read_bytes
from terra.fileio import read_json as read_json_file
from terra.geometry import CameraCalibration
from terra.npy import ArraySpec, read_npy

CLASSES_FILE = "classes.json"
MAX_IMAGE_PIXELS = 89_478_485  # Pillow's own warning threshold (about 9459 x 9459)
MAX_IMAGE_BYTES = 512 << 20
MAX_LABEL_ID = 65535  # 16-bit greyscale PNG (semantic images, and instance images whose ids fit)
MAX_INSTANCE_ID = (1 << 24) - 1  # 24-bit RGB PNG, id = R + 256 G + 65536 B
# What Pillow's decoders raise on damaged or hostile data (besides OSError): this is the one place
# they are turned into "undecodable image" lines.
IMAGE_ERRORS = (
    OSError,
    SyntaxError,
    ValueError,
    EOFError,
    struct.error,
    TypeError,
    IndexError,
    ZeroDivisionError,
    MemoryError,
    Image.DecompressionBombError,
)


def write_classes(root: Path, classes: ClassTable) -> None:
    (Path(root) / CLASSES_FILE).write_text(json.dumps({"classes": classes.to_json()}, indent=1) + "\n")


def is_terra_dataset(root: Path) -> bool:
    """Whether folder `root` is a dataset Terra wrote: its classes.json reads as a class table
    (TerraError from a malformed one)."""
    return (Path(root) / CLASSES_FILE).is_file() and read_classes(root) is not None


def read_classes(root: Path) -> ClassTable | None:
    """The class table in `root/classes.json`, or None when the folder has none."""
    from terra.schemas import ClassesFile, read_model

    path = Path(root) / CLASSES_FILE
    if not path.exists():
        return None
    rows = read_model(path, ClassesFile, "class table").classes
    try:
        return ClassTable([SemanticClass(r.id, r.name, r.terrain, r.semantickitti_id) for r in rows])
    except ValueError as exc:
        raise TerraError(f"{path}: malformed class table ({exc})") from None


def calibration_to_json(cal: CameraCalibration) -> dict:
    """Exact JSON form of a calibration (floats keep full precision through repr)."""
    return {
        "name": cal.name,
        "width": int(cal.width),
        "height": int(cal.height),
        "K": cal.K.tolist(),
        "model": cal.model,
        "dist": cal.dist.tolist(),
        "T_cam_lidar": cal.T_cam_lidar.tolist(),
    }


def calibration_from_json(d: dict, source: str) -> CameraCalibration:
    """A CameraCalibration from its JSON form (terra.schemas.CalibrationDoc); TerraError naming `source`."""
    from terra.datasets.kitti_common import check_rotation, check_translation
    from terra.schemas import CalibrationDoc, validate_model

    doc = validate_model(d, CalibrationDoc, source)
    T = np.asarray(doc.T_cam_lidar, float)
    # Finite is not enough: a 1e308 translation would reach the map as infinity.
    check_rotation(T[:3, :3], f"{source}: camera {doc.name!r} T_cam_lidar's rotation")
    check_translation(T[:3, 3], f"{source}: camera {doc.name!r} T_cam_lidar's translation")
    try:
        return CameraCalibration(
            doc.name,
            doc.width,
            doc.height,
            np.asarray(doc.K, float),
            np.asarray(doc.dist, float),
            np.asarray(doc.T_cam_lidar, float),
            doc.model,
        )
    except ValueError as exc:
        raise TerraError(f"{source}: malformed camera calibration ({exc})") from None


def write_label_png(path: Path, labels: np.ndarray) -> None:
    """A label image (H, W) of non-negative ids below 65536 as a 16-bit greyscale PNG."""
    if labels.size and (labels.min() < 0 or labels.max() > MAX_LABEL_ID):
        raise TerraError(f"{path}: label ids must lie in 0..{MAX_LABEL_ID} to be stored as 16-bit PNG")
    Image.fromarray(labels.astype(np.uint16)).save(path, format="PNG", compress_level=6)


def open_image(path: Path, what: str = "image", formats: tuple[str, ...] = ("JPEG", "PNG")) -> Image.Image:
    """The image in file `path`, opened (header read, pixels not yet decoded) after checking its
    format and pixel count; TerraError naming the file otherwise."""
    data = read_bytes(path, what, MAX_IMAGE_BYTES)
    expected = " or ".join(formats)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # refused below, with its size
            im = Image.open(io.BytesIO(data), formats=list(formats))
    except UnidentifiedImageError:
        raise TerraError(f"{path}: not a {expected} image (unrecognised data)") from None
    except Image.DecompressionBombError:
        raise TerraError(
            f"{path}: {what} declares more pixels than the {MAX_IMAGE_PIXELS:,} Terra decodes "
            "(a damaged or hostile file)"
        ) from None
    except IMAGE_ERRORS as exc:
        raise TerraError(f"{path}: unreadable {what} ({_reason(exc)}); expected {expected}") from None
    width, height = im.size
    if width * height > MAX_IMAGE_PIXELS:
        raise TerraError(
            f"{path}: {what} declares {width} x {height} pixels, more than the {MAX_IMAGE_PIXELS:,} "
            "Terra decodes (a damaged or hostile file)"
        )
    return im


def _reason(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else ""
    return text or type(exc).__name__


def image_size(path: Path, what: str = "image") -> tuple[int, int]:
    """(width, height) of an image from its header, without decoding its pixels."""
    return open_image(path, what).size


def read_label_png(path: Path) -> np.ndarray:
    """(H, W) int32 ids from a 16-bit (or 8-bit) greyscale PNG; TerraError for another format, a
    colour image or ids outside 0..65535."""
    im = open_image(path, "label image", ("PNG",))
    labels = _decode_labels(im, path, "label image")
    if labels.ndim != 2 or labels.dtype.kind not in "biu":
        raise TerraError(f"{path}: expected a single-channel label image, got {im.mode} of shape {labels.shape}")
    return _checked_ids(labels, path, MAX_LABEL_ID, "a 16-bit PNG")


def write_instance_png(path: Path, ids: np.ndarray) -> None:
    """An instance image (H, W) of non-negative ids: a 16-bit greyscale PNG when every id is at most
    65535 (what 16-bit readers know), else a 24-bit RGB PNG with id = R + 256 G + 65536 B (ids up to
    16,777,215; the COCO panoptic encoding). Lossless either way: read_instance_png gives the ids back."""
    ids = np.asarray(ids)
    top = int(ids.max()) if ids.size else 0
    if ids.size and (int(ids.min()) < 0 or top > MAX_INSTANCE_ID):
        raise TerraError(
            f"{path}: instance ids must lie in 0..{MAX_INSTANCE_ID} to be stored as a PNG (got {int(ids.min())}..{top})"
        )
    if top <= MAX_LABEL_ID:
        write_label_png(path, ids)
        return
    wide = ids.astype(np.uint32)
    rgb = np.stack([wide & 0xFF, (wide >> 8) & 0xFF, (wide >> 16) & 0xFF], axis=-1).astype(np.uint8)
    Image.fromarray(rgb).save(path, format="PNG", compress_level=6)


def read_instance_png(path: Path) -> np.ndarray:
    """(H, W) int32 ids from an instance image: 8- or 16-bit greyscale PNG, or 24-bit RGB PNG with
    id = R + 256 G + 65536 B (write_instance_png); TerraError naming the file for anything else."""
    im = open_image(path, "instance image", ("PNG",))
    ids = _decode_labels(im, path, "instance image")
    if im.mode == "RGB" and ids.ndim == 3 and ids.shape[2] == 3 and ids.dtype == np.uint8:
        wide = ids.astype(np.int32)
        return wide[:, :, 0] | (wide[:, :, 1] << 8) | (wide[:, :, 2] << 16)
    if ids.ndim != 2 or ids.dtype.kind not in "biu":
        raise TerraError(
            f"{path}: expected a greyscale or 8-bit RGB instance image, got {im.mode} of shape {ids.shape}"
        )
    return _checked_ids(ids, path, MAX_LABEL_ID, "a 16-bit PNG")


def _decode_labels(im: Image.Image, path: Path, what: str) -> np.ndarray:
    try:
        return np.asarray(im)
    except IMAGE_ERRORS as exc:
        raise TerraError(f"{path}: undecodable {what} ({_reason(exc)})") from None


def _checked_ids(labels: np.ndarray, path: Path, top: int, form: str) -> np.ndarray:
    if labels.size and (int(labels.min()) < 0 or int(labels.max()) > top):
        raise TerraError(
            f"{path}: label ids from {int(labels.min())} to {int(labels.max())}, expected 0..{top} ({form})"
        )
    return labels.astype(np.int32)


def write_rgb(path: Path, image: np.ndarray, quality: int = 92) -> None:
    """RGB uint8 (H, W, 3) as JPEG (by the .jpg suffix) or PNG (lossless)."""
    im = Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8))
    if Path(path).suffix.lower() in (".jpg", ".jpeg"):
        im.save(path, format="JPEG", quality=quality, subsampling=0)
    else:
        im.save(path, format="PNG", compress_level=6)


def read_rgb(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a JPEG or PNG, whatever its mode."""
    im = open_image(path)
    try:
        return np.asarray(im.convert("RGB"))
    except IMAGE_ERRORS as exc:
        raise TerraError(f"{path}: undecodable image ({_reason(exc)})") from None


def stamp_text(stamp: float) -> str:
    """A stamp (seconds) as the reference layout writes it: exactly six decimals."""
    return f"{stamp:.6f}"


def stamp_of(path: Path) -> float:
    """The stamp in a file name: the text after the last '_' of the stem."""
    text = Path(path).stem.rsplit("_", 1)[-1]
    try:
        stamp = float(text)
    except ValueError:
        stamp = float("nan")
    if not np.isfinite(stamp):
        raise TerraError(f"{path}: expected a name ending in _<seconds>, e.g. lidar_pc_12.000000.npy")
    return stamp


def load_npy(path: Path, shape: tuple[int | None, ...] | None = None, what: str = "") -> np.ndarray:
    """A numeric .npy array (never pickled, header checked before reading: terra.npy); with
    `shape`, TerraError unless it matches (None = any length)."""
    return read_npy(path, ArraySpec(shape=shape, what=what) if shape is not None else None)


def read_raw(path: Path, dtype: str, what: str) -> np.ndarray:
    """The values of a headerless binary file (KITTI .bin scans, .label files) as a flat writable
    array of `dtype`; TerraError naming the file when it cannot be read or its size is not a whole
    number of values."""
    data = bytearray(read_bytes(path, what))
    itemsize = np.dtype(dtype).itemsize
    if len(data) % itemsize:
        raise TerraError(f"{path}: {len(data)} bytes is not a whole number of {np.dtype(dtype).name} values ({what})")
    return np.frombuffer(data, dtype=dtype)


def read_velodyne_scan(path: Path) -> np.ndarray:
    """A KITTI Velodyne scan file: (N, 4) float32 x, y, z (metres, sensor frame) and reflectance;
    TerraError naming the file when it cannot be read or is not whole points."""
    raw = read_raw(path, "<f4", "LiDAR scan")
    if raw.size % 4:
        raise TerraError(f"{path}: size is not a multiple of 4 float32 (x, y, z, reflectance)")
    return raw.reshape(-1, 4)


def read_point_labels(path: Path, points: int) -> np.ndarray:
    """A SemanticKITTI .label file: (N,) uint32, one per point of its scan of `points` points (class =
    value & 0xFFFF, instance = value >> 16); TerraError naming the file otherwise."""
    value = read_raw(path, "<u4", "SemanticKITTI label file")
    if value.size != points:
        raise TerraError(f"{path}: {value.size} labels for {points} points")
    return value


def read_json(path: Path) -> dict:
    """A JSON object from `path`; TerraError naming the file when it is unreadable or not an object."""
    value = read_json_file(path, "JSON file")
    if not isinstance(value, dict):
        raise TerraError(f"{path}: expected a JSON object")
    return value
