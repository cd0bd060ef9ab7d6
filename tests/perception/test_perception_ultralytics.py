"""The optional `ultralytics` runtime (.pt checkpoints, YOLOE prompts). ultralytics needs torchvision;
where torchvision cannot be imported (this project's CPU machine), these tests skip and say why."""

from __future__ import annotations

import importlib
import os

import numpy as np
import pytest

from terra.perception.device import resolve_device
from terra.perception.yolo import DecodeSettings


@pytest.fixture(scope="module")
def ultralytics_module():
    try:
        importlib.import_module("torchvision")
    except Exception as exc:  # a CUDA build of torchvision on a CPU machine fails with various errors
        pytest.skip(
            f"the ultralytics runtime needs torchvision, which cannot be imported here ({type(exc).__name__}: {exc})"
        )
    from terra.errors import TerraError
    from terra.perception.ultralytics_yolo import import_ultralytics

    try:
        return import_ultralytics("test")
    except TerraError as exc:
        pytest.skip(f"ultralytics is not usable here: {exc}")


def test_ultralytics_runs_offline(ultralytics_module):
    settings = ultralytics_module.settings

    assert os.environ["YOLO_OFFLINE"] == "1" and os.environ["YOLO_AUTOINSTALL"] == "0"
    assert os.environ["YOLO_CONFIG_DIR"] and settings["sync"] is False


def test_a_random_checkpoint_gives_masks_on_the_original_image(ultralytics_module, tmp_path):
    from terra.perception.ultralytics_yolo import UltralyticsSegmentationModel

    built = ultralytics_module.YOLO("yolov8n-seg.yaml")  # architecture only: random weights, nothing downloaded
    weights = tmp_path / "random-seg.pt"
    built.save(str(weights))
    model = UltralyticsSegmentationModel(weights, resolve_device("cpu"), "masks", "perception.models.masks.model")
    assert len(model.names) == 80 and model.files[0].name == "random-seg.pt"
    image = np.random.default_rng(0).integers(0, 256, (300, 500, 3), dtype=np.uint8)
    found = model.predict(image, DecodeSettings(conf=1e-4, iou=0.5, max_det=20, agnostic=True))
    assert found.shape == (300, 500) and len(found) <= 20
    for (r0, c0, r1, c1), crop in zip(found.mask_boxes, found.mask_crops):
        assert 0 <= r0 < r1 <= 300 and 0 <= c0 < c1 <= 500 and crop.shape == (r1 - r0, c1 - c0)
        assert crop[0].any() and crop[-1].any() and crop[:, 0].any() and crop[:, -1].any()  # tight boxes
