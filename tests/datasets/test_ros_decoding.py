"""PointCloud2, Image and CompressedImage decoding against messages built by hand, byte by byte,
for every supported layout and encoding (the expected values are the numbers written in)."""

from __future__ import annotations

import io
from types import SimpleNamespace as NS

import cv2
import numpy as np
import pytest
from PIL import Image

from terra.datasets.ros.images import decode_compressed, decode_image, decode_labels
from terra.datasets.ros.pointcloud2 import decode_pointcloud2
from terra.errors import TerraError

RNG = np.random.default_rng(3)


def _cloud(fields, rows, point_step, big=False, height=1, row_pad=0):
    """A PointCloud2 from per-point value tuples: fields = [(name, offset, datatype, numpy kind)]."""
    order = ">" if big else "<"
    width = len(rows) // height
    row_step = width * point_step + row_pad
    data = bytearray(row_step * height)
    for k, values in enumerate(rows):
        r, c = divmod(k, width)
        base = r * row_step + c * point_step
        for (_name, offset, _, kind), v in zip(fields, values):
            data[base + offset : base + offset + np.dtype(kind).itemsize] = np.array([v], order + kind).tobytes()
    return NS(
        height=height,
        width=width,
        fields=[NS(name=n, offset=o, datatype=d, count=1) for n, o, d, _ in fields],
        is_bigendian=big,
        point_step=point_step,
        row_step=row_step,
        data=np.frombuffer(bytes(data), np.uint8),
    )


OUSTER = [
    ("x", 0, 7, "f4"),
    ("y", 4, 7, "f4"),
    ("z", 8, 7, "f4"),
    ("intensity", 16, 7, "f4"),
    ("t", 20, 6, "u4"),
    ("reflectivity", 24, 4, "u2"),
    ("ring", 26, 4, "u2"),
    ("range", 32, 6, "u4"),
]
VELODYNE = [
    ("x", 0, 7, "f4"),
    ("y", 4, 7, "f4"),
    ("z", 8, 7, "f4"),
    ("intensity", 12, 7, "f4"),
    ("ring", 16, 4, "u2"),
    ("time", 18, 7, "f4"),
]


def _rows(n, with_time):
    xyz = RNG.normal(0, 10, (n, 3)).astype(np.float32)
    inten = RNG.uniform(0, 255, n).astype(np.float32)
    return xyz, inten, [tuple(p) + (i,) + with_time(k) for k, (p, i) in enumerate(zip(xyz, inten))]


@pytest.mark.parametrize("big", [False, True])
def test_ouster_layout_with_padding_and_ns_time(big):
    xyz, inten, rows = _rows(40, lambda k: (k * 2_500_000, 7, k % 16, 1234))
    msg = _cloud(OUSTER, rows, 48, big=big, height=4, row_pad=24)  # organized 4 x 10 with 24 pad bytes per row
    cloud = decode_pointcloud2(msg)
    np.testing.assert_array_equal(cloud.points, xyz)
    np.testing.assert_array_equal(cloud.intensity, inten)
    assert cloud.times is not None
    np.testing.assert_allclose(cloud.times, np.arange(40) * 2.5e-3, rtol=0, atol=1e-12)
    assert cloud.points.dtype == np.float32 and cloud.labels is None


def test_velodyne_layout_seconds_and_nan_or_no_return_points_dropped():
    xyz, inten, rows = _rows(30, lambda k: (k % 32, np.float32(-0.1 + k * 1e-3)))
    xyz[3, 1] = np.nan
    xyz[17] = 0.0  # an organized cloud's "no return"
    xyz[20, :2] = 0.0  # on the z axis: a real point
    rows = [tuple(p) + r[3:] for p, r in zip(xyz, rows)]
    cloud = decode_pointcloud2(_cloud(VELODYNE, rows, 22))
    keep = np.ones(30, bool)
    keep[[3, 17]] = False
    np.testing.assert_array_equal(cloud.points, xyz[keep])
    np.testing.assert_array_equal(cloud.intensity, inten[keep])
    assert cloud.times is not None
    np.testing.assert_allclose(
        cloud.times, (np.float32(-0.1) + np.arange(30, dtype=np.float32) * np.float32(1e-3))[keep].astype(np.float64)
    )


def test_missing_intensity_float64_coordinates_and_labels():
    fields = [("z", 0, 8, "f8"), ("x", 8, 8, "f8"), ("y", 16, 8, "f8"), ("label", 24, 6, "u4")]
    pts = RNG.normal(0, 3, (12, 3))
    rows = [(p[2], p[0], p[1], k) for k, p in enumerate(pts)]
    cloud = decode_pointcloud2(_cloud(fields, rows, 32, big=True))
    np.testing.assert_array_equal(cloud.points, pts.astype(np.float32))
    assert cloud.intensity is None and cloud.times is None
    np.testing.assert_array_equal(cloud.labels, np.arange(12))


@pytest.mark.parametrize(
    "fields, step, fragment",
    [
        ([("x", 0, 7, "f4"), ("y", 4, 7, "f4")], 12, "no field 'z'"),
        ([("x", 0, 7, "f4"), ("y", 4, 7, "f4"), ("z", 8, 9, "f4")], 12, "field 'z' has datatype 9"),
        ([("x", 0, 7, "f4"), ("y", 4, 7, "f4"), ("z", 10, 7, "f4")], 12, "field 'z' at offset 10"),
    ],
)
def test_unsupported_layouts_name_the_field(fields, step, fragment):
    msg = NS(
        height=1,
        width=2,
        fields=[NS(name=n, offset=o, datatype=d, count=1) for n, o, d, _ in fields],
        is_bigendian=False,
        point_step=step,
        row_step=2 * step,
        data=np.zeros(2 * step, np.uint8),
    )
    with pytest.raises(TerraError, match=fragment):
        decode_pointcloud2(msg, "bag /points")


def test_truncated_data_is_an_error():
    xyz, inten, rows = _rows(4, lambda k: (0, 0, 0, 0))
    msg = _cloud(OUSTER, rows, 48)
    msg.data = msg.data[:-1]
    with pytest.raises(TerraError, match="expected row_step"):
        decode_pointcloud2(msg)


# ---------------------------------------------------------------------------------- images
RGB = RNG.integers(0, 256, (5, 7, 3), dtype=np.uint8)


def _image(encoding, pixels, pad=0, big=0):
    h = pixels.shape[0]
    flat = [np.ascontiguousarray(pixels[r]).tobytes() + bytes(pad) for r in range(h)]
    return NS(
        height=h,
        width=pixels.shape[1],
        encoding=encoding,
        is_bigendian=big,
        step=len(flat[0]),
        data=np.frombuffer(b"".join(flat), np.uint8),
    )


@pytest.mark.parametrize(
    "encoding, pixels, expected",
    [
        ("rgb8", RGB, RGB),
        ("bgr8", RGB[:, :, ::-1], RGB),
        ("rgba8", np.dstack([RGB, np.full((5, 7), 9, np.uint8)]), RGB),
        ("bgra8", np.dstack([RGB[:, :, ::-1], np.full((5, 7), 9, np.uint8)]), RGB),
        ("mono8", RGB[:, :, 0], np.repeat(RGB[:, :, :1], 3, axis=2)),
    ],
)
def test_image_encodings_become_rgb_with_row_padding(encoding, pixels, expected):
    out = decode_image(_image(encoding, pixels, pad=3))
    np.testing.assert_array_equal(out, expected)
    assert out.dtype == np.uint8 and out.shape == (5, 7, 3)


@pytest.mark.parametrize("big", [0, 1])
def test_mono16_takes_the_high_byte_in_both_byte_orders(big):
    values = RNG.integers(0, 65536, (4, 6)).astype(np.uint16)
    out = decode_image(_image("mono16", values.astype(">u2" if big else "<u2"), pad=2, big=big))
    np.testing.assert_array_equal(out[:, :, 1], (values >> 8).astype(np.uint8))
    labels = decode_labels(_image("mono16", values.astype(">u2" if big else "<u2"), big=big))
    np.testing.assert_array_equal(labels, values.astype(np.int32))


def test_unsupported_encoding_names_it():
    with pytest.raises(TerraError, match="encoding 'yuv422'"):
        decode_image(
            NS(height=1, width=2, encoding="yuv422", is_bigendian=0, step=4, data=np.zeros(4, np.uint8)), "bag /cam"
        )


@pytest.mark.parametrize("fmt", ["png", "jpeg"])
def test_compressed_images_match_opencv(fmt):
    image = RNG.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG" if fmt == "png" else "JPEG", quality=90)
    out = decode_compressed(NS(format=f"bgr8; {fmt} compressed bgr8", data=np.frombuffer(buf.getvalue(), np.uint8)))
    decoded = cv2.imdecode(np.frombuffer(buf.getvalue(), np.uint8), cv2.IMREAD_COLOR)
    assert decoded is not None
    reference = cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB)
    if fmt == "png":
        np.testing.assert_array_equal(out, image)
        np.testing.assert_array_equal(reference, image)
    else:  # two JPEG decoders may round the colour conversion differently by one level
        assert np.abs(out.astype(int) - reference.astype(int)).max() <= 2


def test_corrupt_and_unknown_compressed_data():
    with pytest.raises(TerraError, match="undecodable"):
        decode_compressed(NS(format="jpeg", data=np.frombuffer(b"\xff\xd8 not really", np.uint8)))
    with pytest.raises(TerraError, match="'tiff'"):
        decode_compressed(NS(format="tiff", data=np.zeros(4, np.uint8)))


@pytest.mark.parametrize(
    "model, d, ours, count",
    [
        ("plumb_bob", [0.1, -0.02, 0.001, 0.002, 0.003], "pinhole", 5),
        ("rational_polynomial", [0.1, -0.02, 0.001, 0.002, 0.003, 0.01, 0.0, 0.02], "pinhole", 8),
        ("equidistant", [0.01, -0.002, 0.0003, 0.0], "fisheye", 4),
        ("plumb_bob", [], "pinhole", 0),
    ],
)
def test_camera_info_models(model, d, ours, count):
    from terra.datasets.ros.camera_info import camera_from_info

    K = [400.0, 0.0, 320.0, 0.0, 410.0, 240.0, 0.0, 0.0, 1.0]
    cal = camera_from_info(NS(k=K, d=d, distortion_model=model, width=640, height=480), "cam", np.eye(4))
    assert cal.model == ours and cal.dist.size == count and (cal.width, cal.height) == (640, 480)
    np.testing.assert_array_equal(cal.K.ravel(), K)
    ros1 = camera_from_info(
        NS(K=K, D=d, distortion_model=model, width=0, height=0), "cam", np.eye(4), image_size=(640, 480)
    )
    np.testing.assert_array_equal(ros1.dist, cal.dist)


def test_camera_info_errors_name_the_field():
    from terra.datasets.ros.camera_info import camera_from_info

    K = [400.0, 0.0, 320.0, 0.0, 410.0, 240.0, 0.0, 0.0, 1.0]
    with pytest.raises(TerraError, match="distortion_model 'kannala'"):
        camera_from_info(NS(k=K, d=[0.1], distortion_model="kannala", width=640, height=480), "cam", np.eye(4))
    with pytest.raises(TerraError, match="field 'k'"):
        camera_from_info(NS(k=[0.0] * 9, d=[], distortion_model="plumb_bob", width=640, height=480), "cam", np.eye(4))
    with pytest.raises(TerraError, match="images are 320x240"):
        camera_from_info(
            NS(k=K, d=[], distortion_model="plumb_bob", width=640, height=480), "cam", np.eye(4), image_size=(320, 240)
        )


def _compressed(data: bytes, fmt: str):
    from types import SimpleNamespace

    return SimpleNamespace(format=fmt, data=np.frombuffer(data, np.uint8))


@pytest.mark.parametrize("codec", ["JPEG", "PNG"])
@pytest.mark.parametrize("fmt", ["", "rgb8; jpeg compressed bgr8", "png", "tiff"])
def test_compressed_images_are_decoded_by_their_magic_bytes(codec, fmt):
    import io

    from PIL import Image

    from terra.datasets.ros.images import decode_compressed

    rgb = np.zeros((6, 8, 3), np.uint8)
    rgb[:, :4] = (200, 40, 10)
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format=codec, **({"quality": 100, "subsampling": 0} if codec == "JPEG" else {}))
    out = decode_compressed(_compressed(buf.getvalue(), fmt))
    assert out.shape == (6, 8, 3) and np.abs(out.astype(int) - rgb).max() <= (0 if codec == "PNG" else 8)


def test_a_compressed_image_bomb_and_garbage_are_one_line():
    import io
    import zlib

    from PIL import Image

    from terra.datasets.ros.images import decode_compressed
    from terra.errors import TerraError

    small = io.BytesIO()
    Image.new("L", (1, 1)).save(small, format="PNG")
    png = bytearray(small.getvalue())
    png[16:24] = (30000).to_bytes(4, "big") * 2  # IHDR width and height: 30000 x 30000
    png[29:33] = zlib.crc32(bytes(png[12:29])).to_bytes(4, "big")
    with pytest.raises(TerraError, match="more pixels than the"):
        decode_compressed(_compressed(bytes(png), "png"))
    with pytest.raises(TerraError, match="neither JPEG nor PNG"):
        decode_compressed(_compressed(b"GIF89a" + bytes(20), "jpeg"))
