"""The `clip` embedder on a tiny randomly initialised CLIPModel saved with save_pretrained: shapes and
unit norms, batched equals one at a time, RGB (not BGR) reaches the model, the masked crop equals one
built by hand, CLIP's own processor as the reference for preprocessing, and the embedder's name."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("transformers")

from terra.datasets.base import CameraFrame
from terra.errors import TerraError
from terra.geometry import CameraCalibration
from terra.perception.clip import ClipEmbedder, clip_text_embedder, masked_crop, resolve_clip_folder
from terra.perception.device import resolve_device
from terra.perception.masks import MaskSet

CPU = resolve_device("cpu")


@pytest.fixture(scope="module")
def clip(tiny_clip_dir):
    return ClipEmbedder(tiny_clip_dir, CPU, batch_size=4, margin=10, dilation=6)


def _image(h: int = 48, w: int = 64, seed: int = 0) -> np.ndarray:
    """A smooth colour image (red ramp left to right, blue top to bottom) with a little noise."""
    rng = np.random.default_rng(seed)
    image = np.zeros((h, w, 3), dtype=np.float64)
    image[..., 0] = np.linspace(0, 255, w)[None, :]
    image[..., 1] = 60
    image[..., 2] = np.linspace(200, 20, h)[:, None]
    return np.clip(image + rng.normal(0, 8, image.shape), 0, 255).astype(np.uint8)


def _camera(image: np.ndarray) -> CameraFrame:
    h, w = image.shape[:2]
    calib = CameraCalibration(
        "cam0", w, h, np.array([[50.0, 0, w / 2], [0, 50.0, h / 2], [0, 0, 1]]), T_cam_lidar=np.eye(4)
    )
    return CameraFrame(calib, 0.0, image)


def _reference_features(clip: ClipEmbedder, images: list[np.ndarray]) -> np.ndarray:
    """Unit image features through transformers' own CLIPProcessor (the independent reference)."""
    import torch
    from transformers import CLIPProcessor
    from transformers.modeling_outputs import BaseModelOutputWithPooling

    processor = CLIPProcessor.from_pretrained(str(clip.folder))
    clip.embed_crops(images[:1])  # loads the network
    model = clip._model
    assert model is not None
    with torch.no_grad():
        out = model.get_image_features(**processor(images=images, return_tensors="pt"))
    # A tensor in transformers 4; an output object with the projection in pooler_output in transformers 5.
    projected = out.pooler_output if isinstance(out, BaseModelOutputWithPooling) else out
    assert isinstance(projected, torch.Tensor)
    features = projected.numpy()
    return features / np.linalg.norm(features, axis=1, keepdims=True)


def test_name_dimension_and_files(clip, tiny_clip_dir):
    assert clip.dim == 16
    assert clip.name.startswith("clip:tiny-clip@") and len(clip.name.rsplit("@", 1)[1]) == 12
    names = [f.name for f in clip.files]
    assert "model.safetensors" in names and "config.json" in names
    assert all(len(f.sha256) == 64 and f.bytes > 0 for f in clip.files)
    # Other weights, another name: the name encodes the weights, not only the folder.
    from tests.perception.models import save_clip

    other = save_clip(tiny_clip_dir.parent / "other" / "tiny-clip", seed=1)
    assert ClipEmbedder(other, CPU).name != clip.name


def test_unit_vectors_of_the_right_shape(clip):
    image = _image()
    masks = MaskSet.from_label_image(np.pad(np.ones((10, 12), np.int64), ((5, 33), (20, 32))))
    camera = _camera(image)
    vectors = clip.embed_masks(camera, masks)
    assert vectors.shape == (1, 16) and vectors.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(vectors, axis=1), 1.0, rtol=1e-5)
    whole = clip.embed_image(camera)
    assert whole.shape == (16,) and abs(np.linalg.norm(whole) - 1) < 1e-5
    text = clip.embed_text(["grass", "a bicycle rack"])
    assert text.shape == (2, 16)
    np.testing.assert_allclose(np.linalg.norm(text, axis=1), 1.0, rtol=1e-5)
    assert clip.embed_masks(camera, MaskSet((48, 64))).shape == (0, 16)


def test_batched_equals_one_at_a_time(clip, tiny_clip_dir):
    crops = [_image(20 + 7 * i, 30 + 5 * i, seed=i) for i in range(7)]
    batched = clip.embed_crops(crops)  # batches of 4: 4 + 3
    single = ClipEmbedder(tiny_clip_dir, CPU, batch_size=1)
    one_by_one = np.stack([single.embed_crops([c])[0] for c in crops])
    np.testing.assert_allclose(batched, one_by_one, atol=2e-5)


def test_preprocessing_matches_clip_processor(clip):
    from transformers import CLIPProcessor

    processor = CLIPProcessor.from_pretrained(str(clip.folder))
    for shape in [(40, 50), (100, 37), (32, 32), (7, 90)]:
        image = _image(*shape, seed=sum(shape))
        ours = clip.preprocess([image]).numpy()
        reference = processor(images=[image], return_tensors="pt")["pixel_values"].numpy()
        assert ours.shape == reference.shape == (1, 3, 32, 32)
        # Same geometry and normalisation; torch's and PIL's bicubic differ by rounding only.
        assert np.abs(ours - reference).mean() < 0.01 and np.abs(ours - reference).max() < 0.3


def test_rgb_reaches_the_model_not_bgr(clip):
    image = _image()
    ours = clip.embed_image(_camera(image))
    rgb, bgr = _reference_features(clip, [image, np.ascontiguousarray(image[..., ::-1])])
    assert float(ours @ rgb) > 0.999
    assert float(ours @ bgr) < float(ours @ rgb) - 0.02


def _dilated_by_hand(mask: np.ndarray, d: int) -> np.ndarray:
    out = np.zeros_like(mask)
    rows, cols = np.nonzero(mask)
    for r in range(mask.shape[0]):
        for c in range(mask.shape[1]):
            out[r, c] = bool(np.any((np.abs(rows - r) <= d) & (np.abs(cols - c) <= d)))
    return out


def test_masked_crop_equals_a_hand_built_crop():
    image = _image(40, 50, seed=4)
    mask = np.zeros((40, 50), dtype=bool)
    mask[12:20, 30:33] = True  # an L: a bar and a foot
    mask[18:20, 33:38] = True
    masks = MaskSet.from_stack(mask[None])
    (r0, c0, r1, c1), crop = masks.boxes[0], masks.crops[0]
    assert (r0, c0, r1, c1) == (12, 30, 20, 38)
    got = masked_crop(image, masks.boxes[0], crop, margin=10, dilation=2)
    # By hand: box widened by 10 (rows 2..30, cols 20..48, the right edge clipped at 50), black outside
    # the mask dilated by 2 pixels (Chebyshev distance <= 2 to a mask pixel).
    keep = _dilated_by_hand(mask, 2)
    expected = np.where(keep[..., None], image, 0)[2:30, 20:48]
    np.testing.assert_array_equal(got, expected)
    # At the image border the window is clipped, not padded.
    corner = MaskSet.from_stack(np.pad(np.ones((3, 3), bool), ((0, 37), (0, 47)))[None])
    assert masked_crop(image, corner.boxes[0], corner.crops[0], 10, 0).shape == (13, 13, 3)


def test_mask_embeddings_are_the_masked_crops_embedded(clip):
    image = _image()
    labels = np.zeros((48, 64), np.int64)
    labels[5:15, 5:25] = 1
    labels[30:45, 40:60] = 2
    masks = MaskSet.from_label_image(labels)
    crops = [masked_crop(image, b, c, 10, 6) for b, c in zip(masks.boxes, masks.crops)]
    np.testing.assert_allclose(clip.embed_masks(_camera(image), masks), clip.embed_crops(crops), atol=1e-6)


def test_text_vectors_do_not_depend_on_the_call(clip, tiny_clip_dir):
    alone = ClipEmbedder(tiny_clip_dir, CPU).embed_text(["grass"])
    together = clip.embed_text(["a very long sentence about a dumpster behind the building", "grass"])
    np.testing.assert_array_equal(alone[0], together[1])
    templates = ["a photo of {}.", "{} on the ground"]
    ensemble = clip.embed_prompts(["grass"], templates)[0]
    mean = clip.embed_text(["a photo of grass."])[0] + clip.embed_text(["grass on the ground"])[0]
    np.testing.assert_allclose(ensemble, mean / np.linalg.norm(mean), rtol=1e-6)
    np.testing.assert_array_equal(clip.embed_prompts(["grass"], []), clip.embed_text(["grass"]))


def test_queries_find_the_weights_through_terra_clip_path(clip, tiny_clip_dir, monkeypatch):
    monkeypatch.setenv("TERRA_CLIP_PATH", str(tiny_clip_dir.parent))
    found = clip_text_embedder(clip.name)
    assert found.name == clip.name
    np.testing.assert_allclose(found.embed_text(["asphalt"]), clip.embed_text(["asphalt"]), atol=1e-6)
    monkeypatch.setenv("TERRA_CLIP_PATH", "")
    with pytest.raises(TerraError, match="set TERRA_CLIP_PATH to the folder holding the CLIP model 'tiny-clip'"):
        clip_text_embedder(clip.name)
    with pytest.raises(TerraError, match="set TERRA_CLIP_PATH"):
        clip_text_embedder("clip:tiny-clip@000000000000")


def test_missing_or_empty_model_folders_say_what_to_provide(tmp_path):
    with pytest.raises(TerraError, match=r"perception.models.clip.model is not set: give the folder of a CLIP model"):
        resolve_clip_folder(None, False)
    with pytest.raises(TerraError, match=r"folder .*nowhere not found; give the folder .*allow_download: true"):
        resolve_clip_folder(str(tmp_path / "nowhere"), False)
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "config.json").write_text("{}")
    with pytest.raises(TerraError, match="holds no weights"):
        ClipEmbedder(tmp_path / "empty", CPU)
