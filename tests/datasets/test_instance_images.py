"""Instance images wider than 16 bits: a world with more than 65,535 objects keeps its ids.

Terra's own folders store an instance image as a 16-bit greyscale PNG while every id fits (the
files 16-bit readers know) and as a 24-bit RGB PNG with id = R + 256 G + 65536 B otherwise (the
COCO panoptic encoding). The expected pixel bytes below are worked by hand from that formula.
SemanticKITTI's .label keeps the instance in the upper 16 bits of a uint32: that limit stays.
"""

import numpy as np
import pytest
from PIL import Image

from terra.datasets import open_dataset
from terra.datasets.base import CameraFrame, Frame
from terra.datasets.folder_io import read_instance_png, read_label_png, write_instance_png, write_label_png
from terra.datasets.ros.images import decode_labels
from terra.datasets.ros.messages import MessageFactory
from terra.errors import TerraError
from terra.sim.bag_writer import label_encoding
from terra.sim.writer import write_dataset
from tests.datasets.fixtures import HandDataset

WIDE = np.array([[0, 1, 65535, 65536], [70000, 76955, 1 << 23, (1 << 24) - 1]], dtype=np.int32)


def test_ids_above_65535_round_trip_through_a_24_bit_rgb_png(tmp_path):
    path = tmp_path / "inst.png"
    write_instance_png(path, WIDE)
    with Image.open(path) as im:
        assert (im.format, im.mode) == ("PNG", "RGB")
        # 70000 = 0x011170: R 0x70, G 0x11, B 0x01; 76955 = 0x012C9B; 2^24 - 1 = all channels full.
        assert im.getpixel((0, 1)) == (0x70, 0x11, 0x01)
        assert im.getpixel((1, 1)) == (0x9B, 0x2C, 0x01)
        assert im.getpixel((3, 1)) == (255, 255, 255)
        assert im.getpixel((3, 0)) == (0, 0, 1)
    got = read_instance_png(path)
    assert got.dtype == np.int32
    np.testing.assert_array_equal(got, WIDE)


def test_ids_that_fit_stay_a_16_bit_png_byte_for_byte(tmp_path):
    ids = np.array([[0, 7, 300], [65535, 2, 1]], dtype=np.int32)
    write_instance_png(tmp_path / "inst.png", ids)
    write_label_png(tmp_path / "label.png", ids)
    assert (tmp_path / "inst.png").read_bytes() == (tmp_path / "label.png").read_bytes()
    with Image.open(tmp_path / "inst.png") as im:
        assert im.mode.startswith("I")
    np.testing.assert_array_equal(read_instance_png(tmp_path / "inst.png"), ids)


@pytest.mark.parametrize("mode, dtype", [("I;16", np.uint16), ("L", np.uint8)])
def test_old_greyscale_instance_images_still_read(tmp_path, mode, dtype):
    ids = np.array([[0, 5, 200], [255, 1, 3]], dtype=dtype)
    path = tmp_path / "old.png"
    Image.fromarray(ids).save(path, format="PNG")
    with Image.open(path) as im:
        assert im.mode == mode
    np.testing.assert_array_equal(read_instance_png(path), ids.astype(np.int32))


def test_semantic_label_images_stay_16_bit_only(tmp_path):
    write_instance_png(tmp_path / "wide.png", WIDE)
    with pytest.raises(TerraError, match="single-channel label image"):
        read_label_png(tmp_path / "wide.png")
    with pytest.raises(TerraError, match="0..65535"):
        write_label_png(tmp_path / "sem.png", WIDE)


@pytest.mark.parametrize(
    "make, fragment",
    [
        (lambda p: Image.new("RGBA", (4, 3)).save(p), "greyscale or 8-bit RGB instance image, got RGBA"),
        (lambda p: Image.new("LA", (4, 3)).save(p), "greyscale or 8-bit RGB instance image, got LA"),
        (lambda p: p.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40), "PNG"),
        (lambda p: Image.new("RGB", (4, 3)).save(p, format="JPEG"), "not a PNG image"),
    ],
)
def test_a_malformed_instance_image_is_one_line_naming_the_file(tmp_path, make, fragment):
    path = tmp_path / "bad.png"
    make(path)
    with pytest.raises(TerraError) as err:
        read_instance_png(path)
    assert str(path) in str(err.value) and fragment in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("value", [-1, 1 << 24])
def test_ids_a_png_cannot_hold_are_refused(tmp_path, value):
    with pytest.raises(TerraError, match=r"instance ids must lie in 0\.\.16777215"):
        write_instance_png(tmp_path / "x.png", np.array([[0, value]], dtype=np.int64))
    assert not (tmp_path / "x.png").exists()


def _wide(dataset: HandDataset) -> HandDataset:
    """The hand dataset with instance ids beyond 16 bits in its images and scans."""
    frames = []
    for f in dataset.frames:
        cams = []
        for c in f.cameras:
            assert c.instance is not None
            wide = np.where(c.instance > 0, c.instance + 76000, 0)
            cams.append(CameraFrame(c.calibration, c.stamp, c.image, c.semantic, wide))
        assert f.point_instances is not None
        frames.append(
            Frame(
                f.index, f.stamp, f.points, f.T_map_lidar, cams, f.intensity, f.point_labels, f.point_instances + 100000
            )
        )
    dataset.frames = frames
    return dataset


def test_a_terra_folder_keeps_ids_above_65535(tmp_path):
    hand = _wide(HandDataset())
    ds = open_dataset(write_dataset(hand, tmp_path / "wide", progress=False))
    for i, expected in enumerate(hand.frames):
        got = ds[i]
        np.testing.assert_array_equal(got.point_instances, expected.point_instances)
        for cam, exp in zip(got.cameras, expected.cameras):
            assert cam.instance is not None and cam.instance.max() > 65535
            np.testing.assert_array_equal(cam.instance, exp.instance)
            np.testing.assert_array_equal(cam.semantic, exp.semantic)
    assert sorted(p.name for p in (tmp_path / "wide" / "camera1_semantic").iterdir())  # semantics unchanged: 16-bit
    with Image.open(next((tmp_path / "wide" / "camera1_semantic").iterdir())) as im:
        assert im.mode.startswith("I")


def test_a_damaged_instance_image_in_a_terra_folder_is_one_line(tmp_path):
    root = write_dataset(_wide(HandDataset()), tmp_path / "wide", progress=False)
    bad = sorted((root / "camera1_instance").iterdir())[1]
    Image.new("RGBA", (64, 48)).save(bad)
    with pytest.raises(TerraError) as err:
        open_dataset(root)[1]
    assert str(bad) in str(err.value) and "\n" not in str(err.value)


def test_semantickitti_keeps_its_16_bit_instance_limit(tmp_path):
    with pytest.raises(TerraError, match="instance ids must lie in 0..65535 for SemanticKITTI .label files"):
        write_dataset(_wide(HandDataset()), tmp_path / "kitti", format="semantickitti", progress=False)
    assert not (tmp_path / "kitti").exists()


def test_bag_instance_images_widen_to_32sc1_only_when_needed():
    from rosbags.typesys import Stores, get_typestore

    factory = MessageFactory(get_typestore(Stores.ROS2_HUMBLE), ros1=False)
    narrow = np.array([[0, 65535]], dtype=np.int32)
    assert label_encoding(narrow) == "mono16" and label_encoding(WIDE) == "32SC1"
    for ids in (narrow, WIDE):
        msg = factory.image(0, "cam", ids, label_encoding(ids))
        np.testing.assert_array_equal(decode_labels(msg), ids)
