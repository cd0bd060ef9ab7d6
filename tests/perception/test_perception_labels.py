"""The `labels` perception backend, its masks and its noise model, on hand-made label images."""

import numpy as np
import pytest

from terra.datasets.base import CameraFrame, ClassTable, Frame, SemanticClass
from terra.geometry import CameraCalibration
from terra.perception import MaskSet, get_perception
from terra.perception.config import PerceptionConfig

CLASSES = ClassTable(
    [
        SemanticClass(0, "unlabeled"),
        SemanticClass(1, "sidewalk", terrain=True),
        SemanticClass(2, "asphalt", terrain=True),
        SemanticClass(5, "car"),
        SemanticClass(6, "truck"),
        SemanticClass(7, "building"),
    ]
)


def labelled_camera() -> CameraFrame:
    """12 x 16 image: sky rows 0-1, building rows 2-4 (no instance), asphalt below with two cars
    (instances 3 and 9) and a sidewalk strip on the right."""
    H, W = 12, 16
    sem = np.zeros((H, W), np.int32)
    inst = np.zeros((H, W), np.int32)
    sem[2:5] = 7
    sem[5:] = 2
    sem[5:, 12:] = 1
    sem[6:9, 1:4] = 5
    inst[6:9, 1:4] = 3
    sem[7:11, 6:10] = 5
    inst[7:11, 6:10] = 9
    calib = CameraCalibration("cam", W, H, np.array([[10, 0, 8], [0, 10, 6], [0, 0, 1]]))
    return CameraFrame(calib, 0.0, np.zeros((H, W, 3), np.uint8), sem, inst, "cam.png")


@pytest.fixture(scope="module")
def backend(text_embedder):
    return get_perception(PerceptionConfig(), CLASSES)


def test_masks_terrain_and_embeddings_from_labels(backend, text_embedder):
    cam = labelled_camera()
    seen = backend.perceive(cam, np.random.default_rng(0))
    assert backend.terrain_classes == ["sidewalk", "asphalt"]
    expected_terrain = np.where(cam.semantic == 1, 0, np.where(cam.semantic == 2, 1, -1))
    np.testing.assert_array_equal(seen.terrain, expected_terrain)
    # Stuff class 'building' first (by class id), then instances 3 and 9.
    stack = seen.masks.to_stack()
    np.testing.assert_array_equal(stack[0], cam.semantic == 7)
    np.testing.assert_array_equal(stack[1], cam.instance == 3)
    np.testing.assert_array_equal(stack[2], cam.instance == 9)
    assert seen.masks.class_ids.tolist() == [7, 5, 5]
    names = text_embedder.embed_text(["building", "car", "car"])
    np.testing.assert_allclose(seen.mask_embeddings, names, atol=1e-6)
    # Whole image: pixel-share-weighted mean of visible class names, normalised (dense reference).
    shares = {name: np.count_nonzero(cam.semantic == c.id) for c in CLASSES for name in [c.name] if c.id}
    mean = sum(n * text_embedder.embed_text([name])[0] for name, n in shares.items())
    np.testing.assert_allclose(seen.image_embedding, mean / np.linalg.norm(mean), atol=1e-5)


def test_mask_set_members_match_dense_lookup():
    rng = np.random.default_rng(1)
    stack = rng.random((4, 20, 30)) > 0.7
    stack[3] = False  # an empty mask
    masks = MaskSet.from_stack(stack)
    rows, cols = rng.integers(0, 20, 500), rng.integers(0, 30, 500)
    pix, mask = masks.members(rows, cols)
    ref_mask, ref_pix = np.nonzero(stack[:, rows, cols])
    assert sorted(zip(mask.tolist(), pix.tolist())) == sorted(zip(ref_mask.tolist(), ref_pix.tolist()))
    np.testing.assert_array_equal(masks.to_stack(), stack)
    np.testing.assert_array_equal(masks.pixel_counts(), stack.sum(axis=(1, 2)))
    other = rng.random((20, 30)) > 0.5
    np.testing.assert_array_equal(masks.overlap_counts(other), (stack & other).sum(axis=(1, 2)))


def test_dilation_grows_each_mask_by_k_pixels():
    stack = np.zeros((1, 20, 20), bool)
    stack[0, 0:3, 8:10] = True  # touches the top border
    grown = MaskSet.from_stack(stack).dilated(2).to_stack()[0]
    expected = np.zeros((20, 20), bool)
    expected[0:5, 6:12] = True
    np.testing.assert_array_equal(grown, expected)


def test_noise_misses_confuses_and_is_seeded(text_embedder):
    cam = labelled_camera()
    missing = get_perception(PerceptionConfig.model_validate({"noise": {"miss_rate": 1.0}}), CLASSES)
    assert len(missing.perceive(cam, np.random.default_rng(0)).masks) == 0
    confused = get_perception(PerceptionConfig.model_validate({"noise": {"confusion_rate": 1.0}}), CLASSES)
    seen = confused.perceive(cam, np.random.default_rng(0))
    assert seen.masks.class_ids is not None
    assert seen.masks.class_ids.tolist() == [7, 6, 6]  # building has no look-alike; car -> truck
    # Terrain classes swap with their look-alikes (sidewalk <-> asphalt) for the whole image.
    np.testing.assert_array_equal(seen.terrain, np.where(cam.semantic == 1, 1, np.where(cam.semantic == 2, 0, -1)))
    np.testing.assert_allclose(seen.mask_embeddings[1], text_embedder.embed_text(["truck"])[0], atol=1e-6)
    realistic = get_perception(PerceptionConfig.model_validate({"noise": "realistic"}), CLASSES)
    a = realistic.perceive(cam, np.random.default_rng([0, 4, 0]))
    b = realistic.perceive(cam, np.random.default_rng([0, 4, 0]))
    np.testing.assert_array_equal(a.masks.to_stack(), b.masks.to_stack())
    # Dilation: every mask grows by 3 px in every direction (clipped to the image).
    dilated = get_perception(PerceptionConfig.model_validate({"noise": {"dilate_px": 3}}), CLASSES).perceive(
        cam, np.random.default_rng(0)
    )
    car = dilated.masks.to_stack()[1]
    expected = np.zeros_like(car)
    expected[3:12, 0:7] = True  # instance 3 spans rows 6-8, cols 1-3
    np.testing.assert_array_equal(car, expected)


def test_point_labels_give_terrain_and_instance_groups(backend, text_embedder):
    labels = np.array([2, 2, 5, 5, 5, 7, 7, 0, 1, 5], np.int32)
    instances = np.array([0, 0, 4, 4, 4, 0, 0, 0, 0, 8], np.int32)
    frame = Frame(0, 0.0, np.zeros((10, 3), np.float32), np.eye(4), point_labels=labels, point_instances=instances)
    seen = backend.perceive_points(frame, np.random.default_rng(0))
    assert seen.terrain.tolist() == [1, 1, -1, -1, -1, -1, -1, -1, 0, -1]
    groups = {int(g): sorted(seen.group_point[seen.group_index == g].tolist()) for g in np.unique(seen.group_index)}
    assert groups == {0: [5, 6], 1: [2, 3, 4], 2: [9]}  # building (stuff), car #4, car #8
    np.testing.assert_allclose(seen.group_embeddings, text_embedder.embed_text(["building", "car", "car"]), atol=1e-6)


def test_unknown_backend_and_noise_preset_are_one_line_errors():
    from pydantic import ValidationError

    from terra.errors import TerraError

    with pytest.raises(TerraError, match="perception.backend 'yolo'"):
        get_perception(PerceptionConfig(backend="yolo"), CLASSES)
    with pytest.raises(ValidationError, match="unknown noise preset"):
        PerceptionConfig.model_validate({"noise": "heavy"})
    assert PerceptionConfig.model_validate({"noise": {"preset": "realistic", "dilate_px": 1}}).noise.dilate_px == 1
