"""Session fixtures of the perception stage: tiny randomly initialised models (tests/perception/models.py).

`tiny_clip_dir`: a CLIP model folder (32 x 32 images, 16-d embeddings) saved with save_pretrained.
`tiny_models`: that CLIP folder plus terrain and mask ONNX models with constant, known outputs.
`models_section(...)`: the mapping.perception config selecting them.
"""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="session")
def tiny_clip_dir(tmp_path_factory):
    pytest.importorskip("transformers")
    from tests.perception.models import save_clip

    return save_clip(tmp_path_factory.mktemp("clip") / "tiny-clip")


SIM_TERRAIN = ["sidewalk", "grass", "asphalt", "dirt", "water"]


def terrain_detections(asphalt_score: float = 0.5) -> list:
    """Constant terrain detections for 640 x 480 images letterboxed into 64 x 64 (scale 0.1, 8 rows of
    padding above): sidewalk on the bottom-left quarter, grass bottom-right, and an asphalt box across
    both (under them unless its score is the highest)."""
    on = np.array([1.0, 0.0])
    return [
        ((16, 44, 32, 24), 0, 0.9, on),  # image x 0..320, y 240..480
        ((48, 44, 32, 24), 1, 0.8, on),  # image x 320..640, y 240..480
        ((32, 48, 32, 16), 2, asphalt_score, on),
    ]  # image x 160..480, y 320..480


def mask_detections() -> list:
    """Constant class-agnostic masks for 640 x 480 images in a 64 x 64 input."""
    on = np.array([1.0, 0.0])
    return [
        ((16, 23, 16, 14), 0, 0.9, on),  # image x 80..240, y 80..220
        ((48, 16, 16, 8), 0, 0.8, on),  # image x 400..560, y 40..120
        ((32, 46, 64, 20), 0, 0.7, on),
    ]  # image x 0..640, y 280..480: mostly terrain


def all_on_protos() -> np.ndarray:
    protos = np.full((1, 2, 16, 16), 10.0, dtype=np.float32)
    protos[0, 1] = -10.0
    return protos


@pytest.fixture(scope="session")
def tiny_models(tmp_path_factory, tiny_clip_dir):
    """Weight files of the `models` backend: the tiny CLIP folder, a terrain ONNX with the simulator's
    terrain names and a FastSAM-like ONNX with one class, both with constant outputs."""
    pytest.importorskip("onnxruntime")
    from tests.perception.models import raw_output, save_seg_onnx

    folder = tmp_path_factory.mktemp("models")
    terrain = save_seg_onnx(
        folder / "terrain-seg.onnx", raw_output(terrain_detections(), 5, 2, 32), all_on_protos(), (64, 64), SIM_TERRAIN
    )
    masks = save_seg_onnx(
        folder / "fastsam.onnx", raw_output(mask_detections(), 1, 2, 32), all_on_protos(), (64, 64), ["object"]
    )
    return {"clip": tiny_clip_dir, "terrain": terrain, "masks": masks}


def models_section(models: dict, **extra) -> dict:
    """A `mapping.perception` section selecting the models backend with `models`' files."""
    section = {
        "backend": "models",
        "models": {
            "device": "cpu",
            "clip": {"model": str(models["clip"])},
            "terrain": {"model": str(models["terrain"])},
            "masks": {"model": str(models["masks"]), "conf": 0.25},
        },
    }
    for key, value in extra.items():
        if isinstance(value, dict):
            section["models"].setdefault(key, {}).update(value)
        else:
            section["models"][key] = value
    return section
