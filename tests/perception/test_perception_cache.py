"""The per-frame perception cache: exact round trips of the documented format, keys (content, backend,
noise), a second run that does no inference, invalidation by a changed config, corrupt entries, and
`--perception-only` filling the cache that `terra map` then reads."""

from __future__ import annotations

import json

import numpy as np
import pytest

from terra.mapping.config import MappingConfig
from terra.mapping.perceive import run_perception
from terra.mapping.pipeline import run_mapping
from terra.mapping.results import CacheSummary
from terra.perception.base import ImagePerception, Perception
from terra.perception.cache import (
    CachedPerception,
    PerceptionCache,
    decode,
    encode,
    pack_masks,
    run_length,
    run_length_decode,
    unpack_masks,
)
from terra.perception.masks import MaskSet
from terra.perception.registry import get_perception
from tests.mapping.fixtures import BoxScene, folder_digest

CACHE_ON = {"perception": {"cache": {"mode": "on"}}}


def _sample(seed: int = 0, with_ids: bool = True) -> ImagePerception:
    rng = np.random.default_rng(seed)
    terrain = np.full((30, 40), -1, np.int16)
    terrain[18:, :] = 0
    terrain[24:, 25:] = 2
    labels = np.zeros((30, 40), np.int64)
    labels[2:9, 3:17] = 1
    labels[10:20, 20:23] = 2
    labels[11, 30] = 3
    masks = MaskSet.from_label_image(labels, np.array([5, 6, 7]) if with_ids else None)
    vectors = rng.normal(size=(3, 8)).astype(np.float32)
    return ImagePerception(
        terrain, masks, vectors / np.linalg.norm(vectors, axis=1, keepdims=True), rng.normal(size=8).astype(np.float32)
    )


def test_run_length_by_hand():
    image = np.array([[-1, -1, 0], [0, 0, 2]], np.int16)
    np.testing.assert_array_equal(run_length(image), [[-1, 2], [0, 3], [2, 1]])
    np.testing.assert_array_equal(run_length_decode(run_length(image), (2, 3)), image)


def test_mask_bits_by_hand():
    masks = MaskSet(
        (4, 4), np.array([[0, 0, 1, 3], [1, 1, 3, 3]]), [np.array([[1, 0, 1]], bool), np.ones((2, 2), bool)]
    )
    bits = pack_masks(masks)
    # 1 0 1 | 1 1 1 1, padded to a byte: 0b10111110
    np.testing.assert_array_equal(bits, [0b10111110])
    back = unpack_masks((4, 4), masks.boxes, bits, None)
    np.testing.assert_array_equal(back.to_stack(), masks.to_stack())


@pytest.mark.parametrize("with_ids", [True, False])
def test_entry_round_trip_is_exact(with_ids):
    seen = _sample(with_ids=with_ids)
    arrays = encode(seen)
    meta = {"shape": [30, 40], "masks": 3, "class_ids": with_ids}
    back = decode(arrays, meta, 8)
    np.testing.assert_array_equal(back.terrain, seen.terrain)
    assert back.terrain.dtype == np.int16
    np.testing.assert_array_equal(back.masks.to_stack(), seen.masks.to_stack())
    np.testing.assert_array_equal(back.masks.boxes, seen.masks.boxes)
    assert (back.masks.class_ids is None) == (not with_ids)
    assert back.mask_embeddings.tobytes() == seen.mask_embeddings.tobytes()
    assert back.image_embedding.tobytes() == seen.image_embedding.tobytes()


class _NoParts:
    """The four perception parts of a backend that overrides `perceive`: never called."""

    name = "counting"
    dim = 8
    terrain_classes: list[str] = []

    def segment_terrain(self, camera, rng) -> np.ndarray:
        raise AssertionError("Counting.perceive does not segment")

    def propose_masks(self, camera, rng) -> MaskSet:
        raise AssertionError("Counting.perceive does not propose masks")

    def embed_masks(self, camera, masks) -> np.ndarray:
        raise AssertionError("Counting.perceive does not embed masks")

    def embed_text(self, texts) -> np.ndarray:
        raise AssertionError("Counting.perceive does not embed texts")

    def embed_image(self, camera) -> np.ndarray:
        raise AssertionError("Counting.perceive does not embed images")


class Counting(Perception):
    """A perception that counts its inferences and returns `_sample` (shifted by the image's mean)."""

    def __init__(self, random: bool = False):
        parts = _NoParts()
        super().__init__(
            parts,
            parts,
            parts,
            parts,
            backend="counting",
            identity={"backend": "counting"},
            random=random,
            uses_labels=False,
        )
        self.calls = 0

    @property
    def dim(self) -> int:
        return 8

    def perceive(self, camera, rng):
        self.calls += 1
        seen = _sample(int(np.asarray(camera.image).mean()) + int(rng.integers(100)))
        return seen


def _camera(value: int, name: str = "front"):
    from terra.datasets.base import CameraFrame
    from tests.mapping.fixtures import box_camera

    camera = box_camera(40, 30)
    camera.name = name
    return CameraFrame(camera, 0.0, np.full((30, 40, 3), value, np.uint8))


def test_second_request_reads_back_without_inference(tmp_path):
    inner = Counting()
    cached = CachedPerception(inner, PerceptionCache(tmp_path, inner.identity))
    first = cached.perceive(_camera(3), np.random.default_rng(0))
    again = cached.perceive(_camera(3), np.random.default_rng(1))  # the backend is not random: same key
    assert inner.calls == 1 and cached.counts.to_json() == {"hits": 1, "computed": 1}
    assert again.mask_embeddings.tobytes() == first.mask_embeddings.tobytes()
    cached.perceive(_camera(4), np.random.default_rng(0))  # other pixels: computed
    cached.perceive(_camera(3, "rear"), np.random.default_rng(0))  # other camera: computed
    assert inner.calls == 3
    # A new process on the same folder reads everything back.
    fresh = Counting()
    reread = CachedPerception(fresh, PerceptionCache(tmp_path, fresh.identity))
    reread.perceive(_camera(3), np.random.default_rng(0))
    assert fresh.calls == 0
    # Another backend identity (a changed setting or model) shares nothing.
    other = Counting()
    other.identity = {"backend": "counting", "threshold": 0.3}
    CachedPerception(other, PerceptionCache(tmp_path, other.identity)).perceive(_camera(3), np.random.default_rng(0))
    assert other.calls == 1
    description = json.loads(next(tmp_path.glob("*/backend.json")).read_text())
    assert description["format"] == 1 and "identity" in description


def test_random_backends_are_keyed_by_the_generator_state(tmp_path):
    inner = Counting(random=True)
    cached = CachedPerception(inner, PerceptionCache(tmp_path, inner.identity))
    a = cached.perceive(_camera(3), np.random.default_rng([0, 1, 0]))
    b = cached.perceive(_camera(3), np.random.default_rng([0, 1, 0]))
    cached.perceive(_camera(3), np.random.default_rng([0, 2, 0]))
    assert inner.calls == 2 and a.image_embedding.tobytes() == b.image_embedding.tobytes()


def test_a_corrupt_entry_is_recomputed(tmp_path):
    inner = Counting()
    cached = CachedPerception(inner, PerceptionCache(tmp_path, inner.identity))
    first = cached.perceive(_camera(3), np.random.default_rng(0))
    bits = next(tmp_path.glob("*/entries/*/*/mask_bits.npy"))
    data = bytearray(bits.read_bytes())
    data[-1] ^= 0xFF
    bits.write_bytes(bytes(data))
    again = cached.perceive(_camera(3), np.random.default_rng(0))
    assert inner.calls == 2
    np.testing.assert_array_equal(again.masks.to_stack(), first.masks.to_stack())
    assert cached.perceive(_camera(3), np.random.default_rng(0)) is not None and inner.calls == 2  # replaced


class CountingBackend:
    """The labels backend with its inferences counted."""

    def __init__(self, config):
        self.calls = 0
        self.perception = get_perception(config.perception, BoxScene().classes)
        original = self.perception.perceive

        def counted(camera, rng):
            self.calls += 1
            return original(camera, rng)

        self.perception.perceive = counted


def test_map_twice_second_run_does_no_inference_and_gives_the_same_bytes(tmp_path, text_embedder):
    config = MappingConfig.model_validate(CACHE_ON)
    first = CountingBackend(config)
    run1 = run_mapping(BoxScene(), config, tmp_path / "a.terra", show_progress=False, perception=first.perception)
    assert run1.cache is not None
    assert first.calls == 6 and run1.cache.computed == 6 and run1.cache.hits == 0
    assert (tmp_path / "a.terra.work" / "perception").is_dir()
    second = CountingBackend(config)
    shared = MappingConfig.model_validate(
        {"perception": {"cache": {"mode": "on", "folder": str(tmp_path / "a.terra.work" / "perception")}}}
    )
    run2 = run_mapping(BoxScene(), shared, tmp_path / "b.terra", show_progress=False, perception=second.perception)
    assert second.calls == 0 and run2.cache == CacheSummary(run1.cache.folder, hits=6, computed=0)
    a, b = folder_digest(run1.bundle.path), folder_digest(run2.bundle.path)
    assert {k: v for k, v in a.items() if k != "manifest.json"} == {k: v for k, v in b.items() if k != "manifest.json"}
    # Fusion settings do not touch the cache: re-fusing with another DBSCAN radius runs no model.
    refuse = shared.model_copy(deep=True)
    refuse.fusion.dbscan_eps = 0.5
    third = CountingBackend(refuse)
    run_mapping(BoxScene(), refuse, tmp_path / "c.terra", show_progress=False, perception=third.perception)
    assert third.calls == 0
    # A changed perception setting (noise) invalidates.
    noisy = MappingConfig.model_validate(
        {"perception": {"noise": "realistic", "cache": shared.perception.cache.model_dump()}}
    )
    fourth = CountingBackend(noisy)
    run_mapping(BoxScene(), noisy, tmp_path / "d.terra", show_progress=False, perception=fourth.perception)
    assert fourth.calls == 6


def test_perception_only_fills_what_the_map_reads(tmp_path, text_embedder):
    config = MappingConfig.model_validate(CACHE_ON)
    filler = CountingBackend(config)
    run = run_perception(BoxScene(), config, tmp_path / "m.terra", show_progress=False, perception=filler.perception)
    assert (run.frames, run.images, run.computed, run.hits) == (6, 6, 6, 0) and filler.calls == 6
    assert not (tmp_path / "m.terra").exists()  # no bundle
    mapper = CountingBackend(config)
    mapped = run_mapping(BoxScene(), config, tmp_path / "m.terra", show_progress=False, perception=mapper.perception)
    assert mapped.cache is not None
    assert mapper.calls == 0 and mapped.cache.hits == 6


def test_perception_only_needs_the_cache(tmp_path, text_embedder):
    from terra.errors import TerraError

    with pytest.raises(TerraError, match="cache.mode: off"):
        run_perception(
            BoxScene(),
            MappingConfig.model_validate({"perception": {"cache": {"mode": "off"}}}),
            tmp_path / "x.terra",
            show_progress=False,
        )
