"""sensor_msgs/Image and sensor_msgs/CompressedImage -> (H, W, 3) uint8 RGB, and label images.

Image encodings (ROS image_encodings names): rgb8, bgr8, rgba8, bgra8, mono8, mono16 (16-bit
greyscale shown as its high byte). Rows may be padded (`step` > width * bytes per pixel);
`is_bigendian` applies to mono16. CompressedImage: JPEG or PNG, by its `format` string
("jpeg", "png", "bgr8; jpeg compressed bgr8", ...); Pillow decodes it to RGB, whatever colour
order the sender compressed from (image_transport writes standard JPEG/PNG, which store RGB).
"""

from __future__ import annotations

import io
import warnings

import numpy as np

from terra.datasets.ros.bag import message_bytes
from terra.errors import TerraError

CHANNELS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "mono16": 1}
LABEL_ENCODINGS = ("mono16", "16UC1", "mono8", "8UC1", "32SC1")


def _pixels(msg, encoding: str, where: str) -> np.ndarray:
    """(H, W, C) view of an Image's pixel bytes with the row padding removed."""
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    sizes = {"mono16": 2, "16UC1": 2, "32SC1": 4}
    item = sizes.get(encoding, 1)
    channels = CHANNELS.get(encoding, 1)
    row = width * channels * item
    data = message_bytes(msg.data, where)
    if height <= 0 or width <= 0 or step < row or data.size < step * height:
        raise TerraError(
            f"{where}: {width}x{height} {encoding} image with step {step} needs {step * height} bytes "
            f"and step >= {row}, got {data.size} bytes"
        )
    rows = data[: step * height].reshape(height, step)[:, :row]
    if item == 1:
        return rows.reshape(height, width, channels)
    order = ">" if int(msg.is_bigendian) else "<"
    kind = {"32SC1": "i4"}.get(encoding, "u2")
    return np.ascontiguousarray(rows).view(order + kind).reshape(height, width, 1)


def decode_image(msg, where: str = "Image") -> np.ndarray:
    """(H, W, 3) uint8 RGB of a sensor_msgs/Image; TerraError naming the encoding if unsupported."""
    encoding = str(msg.encoding)
    if encoding not in CHANNELS:
        raise TerraError(
            f"{where}: image encoding '{encoding}' is not supported; expected one of: {', '.join(CHANNELS)}"
        )
    px = _pixels(msg, encoding, where)
    if encoding == "rgb8":
        return np.ascontiguousarray(px)
    if encoding == "bgr8":
        return np.ascontiguousarray(px[:, :, ::-1])
    if encoding == "rgba8":
        return np.ascontiguousarray(px[:, :, :3])
    if encoding == "bgra8":
        return np.ascontiguousarray(px[:, :, 2::-1])
    grey = px[:, :, 0] if encoding == "mono8" else (px[:, :, 0] >> 8).astype(np.uint8)
    return np.repeat(grey[:, :, None], 3, axis=2)


_MAGIC = {"JPEG": b"\xff\xd8", "PNG": b"\x89PNG\r\n\x1a\n"}


def compressed_codec(data: bytes) -> str | None:
    """JPEG or PNG from the data's first bytes (as image libraries tell them), else None."""
    return next((codec for codec, magic in _MAGIC.items() if data.startswith(magic)), None)


def decode_compressed(msg, where: str = "CompressedImage") -> np.ndarray:
    """(H, W, 3) uint8 RGB of a JPEG or PNG sensor_msgs/CompressedImage. The codec is read from the
    data's magic bytes: drivers fill `format` in many ways ("jpeg", "rgb8; jpeg compressed bgr8") or
    leave it empty. Pixels beyond MAX_IMAGE_PIXELS are refused from the header, before decoding."""
    from PIL import Image, UnidentifiedImageError

    from terra.datasets.folder_io import MAX_IMAGE_PIXELS

    if "compresseddepth" in str(msg.format).lower().replace(" ", ""):
        raise TerraError(f"{where}: compressed format '{msg.format}' is a depth image, not a colour image")
    data = message_bytes(msg.data, where).tobytes()
    codec = compressed_codec(data)
    if codec is None:
        raise TerraError(f"{where}: compressed data is neither JPEG nor PNG (format field {str(msg.format)[:40]!r})")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # refused below, with its size
            im = Image.open(io.BytesIO(data), formats=[codec])
        with im:
            width, height = im.size
            if width * height > MAX_IMAGE_PIXELS:
                raise TerraError(
                    f"{where}: {codec} data declares {width} x {height} pixels, more than the "
                    f"{MAX_IMAGE_PIXELS:,} Terra decodes (a damaged or hostile message)"
                )
            return np.asarray(im if im.mode == "RGB" else im.convert("RGB"))
    except Image.DecompressionBombError:
        raise TerraError(
            f"{where}: {codec} data declares more pixels than the {MAX_IMAGE_PIXELS:,} Terra decodes"
        ) from None
    except (OSError, UnidentifiedImageError, ValueError) as exc:
        raise TerraError(f"{where}: undecodable {codec} data ({str(exc)[:200]})") from None


def decode_labels(msg, where: str = "Image") -> np.ndarray:
    """(H, W) int32 ids of a label image (mono16 / 16UC1 / mono8 / 8UC1 / 32SC1 sensor_msgs/Image)."""
    encoding = str(msg.encoding)
    if encoding not in LABEL_ENCODINGS:
        raise TerraError(
            f"{where}: label image encoding '{encoding}' is not supported; "
            f"expected one of: {', '.join(LABEL_ENCODINGS)}"
        )
    return _pixels(msg, encoding, where)[:, :, 0].astype(np.int32)
