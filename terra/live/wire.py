"""The wire format of frames pushed to `terra serve --live` (POST /frames), and its decoder.

A robot-side program needs numpy and an HTTP client, nothing of Terra (examples/push_frames.py).

    POST /cameras   Content-Type: application/json
        {"cameras": {"<c>": CALIBRATION, ...}}   once, before the frames that use the cameras
        CALIBRATION = {"name", "width", "height", "K" (3x3 pixels), "model" ("pinhole" or
        "fisheye"), "dist" (OpenCV order), "T_cam_lidar" (4x4, LiDAR -> camera optical frame, metres)}
        (terra_dataset.json's "cameras" entries have this form); <c> is a camera number 0..999.
    POST /frames    Content-Type: application/x-npz
        the body is an uncompressed .npz (numpy.savez, not savez_compressed): one numeric array per
        name below, read with allow_pickle=False (object arrays are refused, never unpickled)

    points        (N, 3) float32          metres, LiDAR frame (NaN rows are "no return", dropped)
    T_map_lidar   (4, 4) float64          rigid pose of the LiDAR in the map frame, or instead
    pose_xyz_quat (7,) float64            [tx, ty, tz, qx, qy, qz, qw] (metres, scalar-last unit quaternion)
    stamp         () float64              seconds, increasing from frame to frame
    times         (N,) float64            optional: seconds from `stamp` per point (deskewing)
    intensity     (N,) float32            optional
    labels        (N,) int32              optional: class ids per point (of the session's classes)
    instances     (N,) int32              optional: instance ids per point (0 = none)
    image_<c>     (H, W, 3) uint8 RGB, or (B,) uint8 = the bytes of a JPEG or PNG file
    semantic_<c>  (H, W) int32 class ids, or (B,) uint8 = a 16-bit greyscale PNG file (optional)
    instance_<c>  (H, W) int32 ids, or (B,) uint8 = a 16-bit grey or 24-bit RGB PNG file (optional)
    image_stamp_<c> () float64            optional: the image's stamp (default: `stamp`)
    camera_<c>    (B,) uint8              optional: CALIBRATION as UTF-8 JSON, for this frame only
                                          (else the one given to POST /cameras)

Cameras are fused in increasing number <c>. Encoded images are decoded by the service exactly as
`terra map` decodes the files of a dataset folder, so a folder pushed frame by frame gives the
same map, byte for byte, as `terra map FOLDER`. Limits: the body (`--max-frame-bytes`, 64 MiB by
default: 413 before it is read), and per frame those of terra.live.frames (points, pixels,
cameras). Every refusal is a LiveFrameError: one line naming the array and what was expected.
"""

from __future__ import annotations

import io
import json
import re
import warnings
import zipfile
from dataclasses import dataclass, field

import numpy as np

from terra.datasets.base import CameraFrame
from terra.errors import TerraError
from terra.geometry import CameraCalibration
from terra.live.frames import MAX_CAMERAS, MAX_PIXELS, LiveFrameError

MEDIA_TYPE = "application/x-npz"
MAX_CAMERA_NUMBER = 999
PER_FRAME = ("points", "T_map_lidar", "pose_xyz_quat", "stamp", "times", "intensity", "labels", "instances")
PER_CAMERA = ("image", "semantic", "instance", "image_stamp", "camera")
_CAMERA_KEY = re.compile(r"^(image_stamp|image|semantic|instance|camera)_(\d{1,3})$")
_MAX_JSON_BYTES = 1 << 16


@dataclass
class WireFrame:
    """One decoded frame: the arguments of terra.live.Session.add_frame."""

    points: np.ndarray
    T_map_lidar: np.ndarray
    stamp: object
    times: np.ndarray | None = None
    intensity: np.ndarray | None = None
    labels: np.ndarray | None = None
    instances: np.ndarray | None = None
    images: list[CameraFrame] = field(default_factory=list)

    def arguments(self) -> dict:
        return {
            "points": self.points,
            "T_map_lidar": self.T_map_lidar,
            "stamp": self.stamp,
            "times": self.times,
            "images": self.images,
            "intensity": self.intensity,
            "labels": self.labels,
            "instances": self.instances,
        }


# ------------------------------------------------------------------------------- public interface
def decode_frame(body: bytes, cameras: dict[int, CameraCalibration]) -> WireFrame:
    """The frame in `body` (an .npz as above) with the registered `cameras`; LiveFrameError otherwise.
    The values are checked further by terra.live.frames.check_live_frame when the session adds them."""
    arrays = read_npz(body)
    for required in ("points", "stamp"):
        if required not in arrays:
            raise LiveFrameError("bad_frame", f"{required}: missing from the frame (see terra.live.wire)")
    stamp = _scalar(arrays["stamp"], "stamp")
    numbers = _camera_numbers(arrays)
    if len(numbers) > MAX_CAMERAS:
        raise LiveFrameError("too_large", f"image_<c>: {len(numbers)} cameras, at most {MAX_CAMERAS}")
    return WireFrame(
        points=arrays["points"],
        T_map_lidar=_pose(arrays),
        stamp=stamp,
        times=arrays.get("times"),
        intensity=arrays.get("intensity"),
        labels=arrays.get("labels"),
        instances=arrays.get("instances"),
        images=[_camera_frame(arrays, c, cameras, stamp) for c in numbers],
    )


def read_npz(body: bytes) -> dict[str, np.ndarray]:
    """The arrays of an uncompressed .npz, each checked to be a known, numeric, unpickled array."""
    if not body.startswith(b"PK"):
        raise LiveFrameError("bad_frame", "body: expected an .npz (a zip made by numpy.savez), got other data")
    try:
        archive = zipfile.ZipFile(io.BytesIO(body))
        members = archive.infolist()
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise LiveFrameError("bad_frame", f"body: not a readable .npz ({exc})") from None
    arrays: dict[str, np.ndarray] = {}
    for member in members:
        name = member.filename.removesuffix(".npy")
        if member.filename == name or (name not in PER_FRAME and not _CAMERA_KEY.match(name)):
            raise LiveFrameError(
                "bad_frame", f"{member.filename}: not an array of the frame format (see terra.live.wire)"
            )
        if member.compress_type != zipfile.ZIP_STORED:
            raise LiveFrameError("bad_frame", f"{name}: compressed; send an uncompressed .npz (numpy.savez)")
        if name in arrays:
            raise LiveFrameError("bad_frame", f"{name}: given twice")
        arrays[name] = _member(archive, member, name)
    return arrays


def parse_cameras(document: object, source: str = "POST /cameras") -> dict[int, CameraCalibration]:
    """The calibrations of a {"cameras": {"<c>": CALIBRATION}} document; TerraError naming the camera."""
    from terra.datasets.folder_io import calibration_from_json

    cameras = document.get("cameras") if isinstance(document, dict) and set(document) == {"cameras"} else None
    if not isinstance(cameras, dict) or not cameras:
        raise TerraError(f'{source}: expected {{"cameras": {{"<c>": calibration, ...}}}}')
    if len(cameras) > MAX_CAMERAS:
        raise TerraError(f"{source}: {len(cameras)} cameras, at most {MAX_CAMERAS}")
    parsed = {}
    for key, value in cameras.items():
        if not (isinstance(key, str) and key.isdigit() and int(key) <= MAX_CAMERA_NUMBER):
            raise TerraError(f"{source}: camera key {key!r}: expected a number 0..{MAX_CAMERA_NUMBER}")
        calibration = calibration_from_json(value, f"{source} camera {key}")
        if calibration.width * calibration.height > MAX_PIXELS:
            raise TerraError(f"{source} camera {key}: {calibration.width} x {calibration.height} pixels, too many")
        parsed[int(key)] = calibration
    return parsed


# ------------------------------------------------------------------------------ private interface
def _member(archive: zipfile.ZipFile, member: zipfile.ZipInfo, name: str) -> np.ndarray:
    try:
        with archive.open(member) as stream:
            array = np.lib.format.read_array(stream, allow_pickle=False)
    except ValueError as exc:
        if "allow_pickle" in str(exc) or "Object arrays" in str(exc):
            raise LiveFrameError("bad_frame", f"{name}: an object array; only numeric arrays are accepted") from None
        raise LiveFrameError("bad_frame", f"{name}: not a readable .npy ({exc})") from None
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise LiveFrameError("bad_frame", f"{name}: not a readable .npy ({exc})") from None
    if not np.issubdtype(array.dtype, np.number):
        raise LiveFrameError(f"bad_{_field(name)}", f"{name}: expected numbers, got dtype {array.dtype}")
    return array


def _camera_numbers(arrays: dict[str, np.ndarray]) -> list[int]:
    """The camera numbers <c> the frame's arrays name, in increasing order."""
    matches = (_CAMERA_KEY.match(name) for name in arrays)
    return sorted({int(match.group(2)) for match in matches if match is not None})


def _field(name: str) -> str:
    """The counter a bad array is counted under (bad_points, bad_pose, bad_image, ...)."""
    match = _CAMERA_KEY.match(name)
    if match is not None:
        return "camera" if match.group(1) == "camera" else "image"
    return "pose" if name in ("T_map_lidar", "pose_xyz_quat") else name


def _scalar(array: np.ndarray, name: str) -> float:
    if array.shape not in ((), (1,)) or not np.issubdtype(array.dtype, np.number):
        raise LiveFrameError(f"bad_{_field(name)}", f"{name}: expected one number of seconds, got shape {array.shape}")
    return float(array.reshape(()))


def _pose(arrays: dict[str, np.ndarray]) -> np.ndarray:
    given = [k for k in ("T_map_lidar", "pose_xyz_quat") if k in arrays]
    if len(given) != 1:
        raise LiveFrameError("bad_pose", "T_map_lidar: give either T_map_lidar (4, 4) or pose_xyz_quat (7,)")
    if given[0] == "T_map_lidar":
        return arrays["T_map_lidar"]
    from terra.geometry import pose_from_xyz_quat

    xyz_quat = np.asarray(arrays["pose_xyz_quat"], np.float64)
    if xyz_quat.shape != (7,) or not np.isfinite(xyz_quat).all() or abs(np.linalg.norm(xyz_quat[3:]) - 1.0) > 1e-3:
        raise LiveFrameError(
            "bad_pose", "pose_xyz_quat: expected 7 finite values [tx, ty, tz, qx, qy, qz, qw] with a unit quaternion"
        )
    return pose_from_xyz_quat(xyz_quat)  # as terra-folder reads its pose files


def _camera_frame(arrays: dict, c: int, cameras: dict[int, CameraCalibration], stamp: float) -> CameraFrame:
    if f"image_{c}" not in arrays:
        raise LiveFrameError("bad_image", f"image_{c}: missing, though the frame has other arrays of camera {c}")
    calibration = _calibration(arrays[f"camera_{c}"], c) if f"camera_{c}" in arrays else cameras.get(c)
    if calibration is None:
        raise LiveFrameError(
            "bad_camera", f"image_{c}: camera {c} has no calibration; POST /cameras first or send camera_{c}"
        )
    when = _scalar(arrays[f"image_stamp_{c}"], f"image_stamp_{c}") if f"image_stamp_{c}" in arrays else stamp
    image = _rgb(arrays[f"image_{c}"], f"image_{c}")
    semantic = _ids(arrays.get(f"semantic_{c}"), f"semantic_{c}", rgb_ids=False)
    instance = _ids(arrays.get(f"instance_{c}"), f"instance_{c}", rgb_ids=True)
    return CameraFrame(calibration, when, image, semantic, instance)


def _calibration(array: np.ndarray, c: int) -> CameraCalibration:
    from terra.datasets.folder_io import calibration_from_json

    if array.ndim != 1 or array.dtype != np.uint8 or array.size > _MAX_JSON_BYTES:
        raise LiveFrameError("bad_camera", f"camera_{c}: expected the calibration as UTF-8 JSON bytes (uint8, (B,))")
    try:
        return calibration_from_json(json.loads(array.tobytes().decode("utf-8")), f"camera_{c}")
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise LiveFrameError("bad_camera", f"camera_{c}: not JSON ({exc})") from None
    except TerraError as exc:
        raise LiveFrameError("bad_camera", str(exc)) from None


def _rgb(array: np.ndarray, name: str) -> np.ndarray:
    if array.ndim != 1:
        return array  # raw pixels, checked against the calibration by check_live_frame
    image = _decoded(array, name, ("JPEG", "PNG"))
    try:
        return np.asarray(image.convert("RGB"))  # as folder_io.read_rgb
    except _image_errors() as exc:
        raise LiveFrameError("bad_image", f"{name}: undecodable image ({exc})") from None


def _ids(array: np.ndarray | None, name: str, rgb_ids: bool) -> np.ndarray | None:
    """Label ids: an (H, W) integer array as given, or a PNG decoded as folder_io reads label files."""
    if array is None or array.ndim != 1:
        if array is not None and not np.issubdtype(array.dtype, np.integer):
            raise LiveFrameError("bad_image", f"{name}: expected integer ids, got {array.dtype}")
        return array
    image = _decoded(array, name, ("PNG",))
    try:
        ids = np.asarray(image)
    except _image_errors() as exc:
        raise LiveFrameError("bad_image", f"{name}: undecodable PNG ({exc})") from None
    if rgb_ids and image.mode == "RGB" and ids.ndim == 3 and ids.shape[2] == 3 and ids.dtype == np.uint8:
        wide = ids.astype(np.int32)
        return wide[:, :, 0] | (wide[:, :, 1] << 8) | (wide[:, :, 2] << 16)
    if ids.ndim != 2 or ids.dtype.kind not in "biu":
        raise LiveFrameError("bad_image", f"{name}: expected a single-channel label PNG, got {image.mode} {ids.shape}")
    return ids.astype(np.int32)


def _decoded(array: np.ndarray, name: str, formats: tuple[str, ...]):
    """The image file held in a (B,) uint8 array, opened after checking its format and pixel count."""
    from PIL import Image, UnidentifiedImageError

    if array.dtype != np.uint8:
        raise LiveFrameError("bad_image", f"{name}: a 1-D array must hold file bytes (uint8), got {array.dtype}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            image = Image.open(io.BytesIO(array.tobytes()), formats=list(formats))
    except UnidentifiedImageError:
        raise LiveFrameError("bad_image", f"{name}: not a {' or '.join(formats)} file") from None
    except _image_errors() as exc:
        raise LiveFrameError("bad_image", f"{name}: unreadable image ({exc})") from None
    width, height = image.size
    if width * height > MAX_PIXELS:
        raise LiveFrameError("too_large", f"{name}: {width} x {height} pixels, at most {MAX_PIXELS}")
    return image


def _image_errors() -> tuple[type[BaseException], ...]:
    from terra.datasets.folder_io import IMAGE_ERRORS

    return IMAGE_ERRORS
