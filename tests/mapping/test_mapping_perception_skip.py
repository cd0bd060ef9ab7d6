"""`terra map` and a perception backend's exceptions: `PerceptionSkip` ("this image cannot be
perceived") skips the image and counts it; any other exception, such as a ValueError from a
backend's own code, stops the run with that error instead of being counted as a skipped image."""

from pathlib import Path
from typing import cast

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.cli import run
from terra.datasets.base import Dataset
from terra.perception.base import PerceptionSkip
from terra.sim.writer import write_dataset
from tests.mapping.fixtures import BoxScene


class _RaisingSegmenter:
    """A terrain segmenter that raises `error` for every image."""

    def __init__(self, terrain_classes: list[str], error: Exception):
        self.terrain_classes = terrain_classes
        self.error = error

    def segment_terrain(self, camera, rng: np.random.Generator) -> np.ndarray:
        raise self.error


@pytest.fixture(scope="module")
def box_folder(tmp_path_factory) -> Path:
    scene = cast(Dataset, BoxScene())  # a Dataset by its methods, not by inheritance
    return write_dataset(scene, tmp_path_factory.mktemp("boxdata") / "box", format="terra-folder", progress=False)


@pytest.fixture
def raising_backend(monkeypatch, tmp_path):
    """Registers backend `raising` (the labels backend whose terrain segmenter raises the error it
    is given) for one test, and returns (set_error, config file selecting it)."""
    from terra.perception import registry
    from terra.perception.labels import labels_backend

    backends = registry.BACKENDS
    for attribute in ("_loaded", "_lazy", "_order"):  # the registration ends with the test
        monkeypatch.setattr(backends, attribute, type(getattr(backends, attribute))(getattr(backends, attribute)))
    raised: list[Exception] = []

    def factory(config, classes):
        perception = labels_backend(config, classes)
        perception.terrain = _RaisingSegmenter(perception.terrain_classes, raised[0])
        return perception

    registry.register_backend("raising", factory)
    config = tmp_path / "terra.yaml"
    config.write_text("mapping:\n  perception:\n    backend: raising\n    cache:\n      mode: 'off'\n")
    return raised.append, config


def test_an_unexpected_value_error_fails_the_map(raising_backend, box_folder, tmp_path, text_embedder):
    set_error, config = raising_backend
    set_error(ValueError("image is (48, 64), letterbox was fitted for (480, 640)"))
    out = tmp_path / "m.terra"
    with pytest.raises(ValueError, match="letterbox was fitted for"):
        run(["map", str(box_folder), "--out", str(out), "--config", str(config), "-q"])
    assert not out.exists()


def test_an_unexpected_value_error_is_reported_by_the_command(
    raising_backend, box_folder, tmp_path, capsys, text_embedder
):
    """Through the console entry point: the error and its traceback, exit code 1 (a defect, not bad input)."""
    from terra.cli import main

    set_error, config = raising_backend
    set_error(ValueError("image is (48, 64), letterbox was fitted for (480, 640)"))
    with pytest.raises(SystemExit) as exit_info:
        main(["map", str(box_folder), "--out", str(tmp_path / "m.terra"), "--config", str(config), "-q"])
    assert exit_info.value.code == 1
    assert "ValueError: image is (48, 64), letterbox was fitted for (480, 640)" in capsys.readouterr().err


def test_perception_skip_still_skips_and_counts_the_image(raising_backend, box_folder, tmp_path, text_embedder):
    set_error, config = raising_backend
    set_error(PerceptionSkip("this image has no labels"))
    out = tmp_path / "m.terra"
    assert run(["map", str(box_folder), "--out", str(out), "--config", str(config), "-q"]) == 0
    info = Bundle(out).model.components.map
    assert info is not None
    assert info.stats["images_skipped_no_labels"] == len(BoxScene())
    assert info.stats.get("images_fused", 0) == 0
