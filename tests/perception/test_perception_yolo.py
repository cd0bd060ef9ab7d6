"""The `yolo-onnx` runtime on constructed ONNX models: letterbox placement, box and class decoding,
NMS and prototype masks, checked pixel for pixel on non-square images."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from terra.errors import TerraError
from terra.perception.device import resolve_device
from terra.perception.letterbox import Letterbox
from terra.perception.onnx_yolo import OnnxSegmentationModel, parse_names
from terra.perception.yolo import DecodeSettings, decode, nms
from tests.perception.models import raw_output, save_seg_onnx

CPU = resolve_device("cpu")
NM = 2


def _protos(mh: int = 16, mw: int = 16) -> np.ndarray:
    """Channel 0: +10 everywhere; channel 1: +10 on prototype columns < 8 (input x < 32), -10 elsewhere."""
    protos = np.full((1, NM, mh, mw), 10.0, dtype=np.float32)
    protos[0, 1, :, 8:] = -10.0
    return protos


def _model(tmp_path, output0, protos, input_hw=(64, 64), names=("sidewalk", "grass"), **kw):
    path = save_seg_onnx(tmp_path / "m.onnx", output0, protos, input_hw, list(names) if names else None, **kw)
    return OnnxSegmentationModel(path, CPU, "terrain", "perception.models.terrain.model")


def test_letterbox_numbers_by_hand():
    # 48 x 64 into 64 x 64: no scaling, 8 rows of grey above and below.
    box = Letterbox.fit((48, 64), (64, 64))
    assert (box.new_shape, box.top, box.left) == ((48, 64), 8, 0)
    # 47 rows leave 17 to pad: round(8.5 - 0.1) = 8 above, 9 below (ultralytics' rounding).
    assert Letterbox.fit((47, 64), (64, 64)).top == 8
    # 30 x 80 into 64 x 64: scale 0.8 to 24 x 64, 20 rows above.
    box = Letterbox.fit((30, 80), (64, 64))
    assert (box.new_shape, box.top, box.left, box.gain_x, box.gain_y) == ((24, 64), 20, 0, 0.8, 0.8)
    # Tall image: columns padded.
    box = Letterbox.fit((80, 30), (64, 64))
    assert (box.new_shape, box.top, box.left) == ((64, 24), 0, 20)
    np.testing.assert_allclose(box.boxes_to_image(np.array([[20, 0, 44, 64]])), [[0, 0, 30, 80]])


def test_letterbox_image_matches_opencv():
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (30, 80, 3), dtype=np.uint8)
    box = Letterbox.fit(image.shape[:2], (64, 64))
    ours = box.apply(image)[0].transpose(1, 2, 0) * 255.0
    resized = cv2.resize(image, (64, 24), interpolation=cv2.INTER_LINEAR)
    expected = cv2.copyMakeBorder(resized, 20, 20, 0, 0, cv2.BORDER_CONSTANT, value=(114, 114, 114)).astype(np.float32)
    assert ours.shape == expected.shape
    assert (
        np.abs(ours - expected).max() <= 1.0 + 1e-4
    )  # OpenCV's fixed-point weights round differently by at most one level
    assert np.all(ours[:20] == 114) and np.all(ours[44:] == 114)


def test_nms_by_hand():
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [20, 20, 30, 30], [0, 0, 10, 10]], dtype=float)
    scores = np.array([0.9, 0.8, 0.7, 0.95])
    assert nms(boxes, scores, 0.7, 10).tolist() == [3, 2]  # 0 and 1 overlap 3 with IoU 1.0 and 0.82
    assert nms(boxes, scores, 0.95, 10).tolist() == [3, 1, 2]  # IoU(3, 1) = 9/11 <= 0.95 kept; 0 is a copy of 3
    assert nms(boxes, scores, 0.7, 1).tolist() == [3]


def _detections_48x64() -> np.ndarray:
    coef_all, coef_left = np.array([1.0, 0.0]), np.array([0.0, 1.0])
    return raw_output(
        [
            ((20, 28, 24, 16), 0, 0.9, coef_all),  # A: input x 8..32, y 20..36 -> image rows 12..28, cols 8..32
            ((40, 48, 32, 16), 1, 0.8, coef_left),  # B: input x 24..56, y 40..56 -> rows 32..48, only x < 32
            ((21, 28, 24, 16), 0, 0.5, coef_all),  # C: A shifted by 1 px, same class: suppressed (IoU 0.92)
            ((20, 28, 24, 16), 1, 0.6, coef_all),  # D: A's box, another class: kept by class-aware NMS
            ((50, 10, 4, 4), 0, 0.1, coef_all),  # E: below the confidence threshold
        ],
        nc=2,
        nm=NM,
        anchors=20,
    )


def test_decoding_nms_and_masks_pixel_exact_on_a_padded_image(tmp_path):
    model = _model(tmp_path, _detections_48x64(), _protos())
    assert model.names == ["sidewalk", "grass"] and model.input_shape == (64, 64)
    image = np.zeros((48, 64, 3), dtype=np.uint8)
    found = model.predict(image, DecodeSettings(conf=0.25, iou=0.7, max_det=10))
    assert found.shape == (48, 64)
    np.testing.assert_allclose(found.scores, [0.9, 0.8, 0.6], rtol=1e-6)
    assert found.classes.tolist() == [0, 1, 1]
    np.testing.assert_allclose(found.boxes, [[8, 12, 32, 28], [24, 32, 56, 48], [8, 12, 32, 28]])
    expected = np.zeros((3, 48, 64), dtype=bool)
    expected[0, 12:28, 8:32] = True
    expected[1, 32:48, 24:32] = True  # prototype sign change at input x = 32: columns 24..31
    expected[2, 12:28, 8:32] = True
    got = np.zeros_like(expected)
    for i, ((r0, c0, r1, c1), crop) in enumerate(zip(found.mask_boxes, found.mask_crops)):
        got[i, r0:r1, c0:c1] = crop
    np.testing.assert_array_equal(got, expected)
    # Class-agnostic NMS (FastSAM) also drops D, which repeats A's box.
    agnostic = model.predict(image, DecodeSettings(conf=0.25, iou=0.7, max_det=10, agnostic=True))
    np.testing.assert_allclose(agnostic.scores, [0.9, 0.8], rtol=1e-6)
    # max_det keeps the best; min_pixels drops B's 128-pixel mask.
    assert len(model.predict(image, DecodeSettings(conf=0.25, max_det=1))) == 1
    assert model.predict(image, DecodeSettings(conf=0.25, min_pixels=200)).scores.size == 2


def test_masks_land_pixel_exactly_on_a_scaled_non_square_image(tmp_path):
    # 30 x 80 image, scale 0.8, 20 rows of padding above: input box x 8..40, y 28..36 is image x 10..50, y 10..20.
    output0 = raw_output([((24, 32, 32, 8), 1, 0.7, np.array([1.0, 0.0]))], nc=2, nm=NM, anchors=8)
    model = _model(tmp_path, output0, _protos())
    found = model.predict(np.zeros((30, 80, 3), np.uint8), DecodeSettings())
    np.testing.assert_allclose(found.boxes, [[10, 10, 50, 20]])
    assert found.mask_boxes.tolist() == [[10, 10, 20, 50]] and found.mask_crops[0].all()
    # The prototype's sign change at input x = 32 is image x = 40: columns 10..39 with channel 1.
    output0 = raw_output([((24, 32, 32, 8), 1, 0.7, np.array([0.0, 1.0]))], nc=2, nm=NM, anchors=8)
    found = _model(tmp_path, output0, _protos()).predict(np.zeros((30, 80, 3), np.uint8), DecodeSettings())
    assert found.mask_boxes.tolist() == [[10, 10, 20, 40]] and found.mask_crops[0].all()


def test_bilinear_prototype_sampling_matches_scipy():
    from scipy import ndimage

    rng = np.random.default_rng(3)
    protos = rng.normal(size=(1, 3, 16, 16)).astype(np.float32)
    coeff = rng.normal(size=3).astype(np.float32)
    box = Letterbox.fit((30, 80), (64, 64))
    output0 = raw_output([((32, 32, 64, 24), 0, 0.9, coeff)], nc=1, nm=3, anchors=4)
    found = decode(output0, protos, 1, box, DecodeSettings(conf=0.5))
    logits = np.tensordot(coeff, protos[0], axes=1)
    rows, cols = np.mgrid[0:30, 0:80]
    u = (box.input_x(cols) + 0.5) / 4 - 0.5
    v = (box.input_y(rows) + 0.5) / 4 - 0.5
    reference = ndimage.map_coordinates(logits, [v.ravel(), u.ravel()], order=1, mode="nearest").reshape(30, 80) > 0
    got = np.zeros((30, 80), dtype=bool)
    (r0, c0, r1, c1), crop = found.mask_boxes[0], found.mask_crops[0]
    got[r0:r1, c0:c1] = crop
    np.testing.assert_array_equal(got, reference)


def test_end_to_end_layout(tmp_path):
    # (1, max_det, 6 + nm): x1 y1 x2 y2 score class coefficients, already suppressed by the model.
    output0 = np.zeros((1, 5, 6 + NM), dtype=np.float32)
    output0[0, 0] = [8, 20, 32, 36, 0.4, 1, 1.0, 0.0]
    output0[0, 1] = [24, 40, 56, 56, 0.9, 0, 0.0, 1.0]
    found = _model(tmp_path, output0, _protos()).predict(np.zeros((48, 64, 3), np.uint8), DecodeSettings(conf=0.25))
    assert found.classes.tolist() == [0, 1]
    np.testing.assert_allclose(found.boxes, [[24, 32, 56, 48], [8, 12, 32, 28]])
    assert found.mask_boxes.tolist() == [[32, 24, 48, 32], [12, 8, 28, 32]]


def test_no_detection_is_an_empty_result(tmp_path):
    output0 = raw_output([], nc=2, nm=NM, anchors=8)
    found = _model(tmp_path, output0, _protos()).predict(np.zeros((48, 64, 3), np.uint8), DecodeSettings())
    assert len(found) == 0 and found.mask_boxes.shape == (0, 4) and found.mask_crops == []


def test_fp16_and_dynamic_exports(tmp_path):
    output0 = raw_output([((24, 32, 32, 8), 1, 0.7, np.array([1.0, 0.0]))], nc=2, nm=NM, anchors=8)
    half = _model(tmp_path, output0, _protos(), half=True)
    assert half.half and len(half.predict(np.zeros((30, 80, 3), np.uint8), DecodeSettings())) == 1
    dynamic = save_seg_onnx(
        tmp_path / "d.onnx", output0, _protos(), (64, 64), ["a", "b"], dynamic=True, imgsz_meta=False
    )
    assert OnnxSegmentationModel(dynamic, CPU, "masks", "f").input_shape == (
        640,
        640,
    )  # no metadata: ultralytics' default
    assert OnnxSegmentationModel(dynamic, CPU, "masks", "f", imgsz=[64, 64]).input_shape == (64, 64)


def test_names_from_metadata_or_config(tmp_path):
    assert parse_names("{0: 'sidewalk', 1: 'grass'}") == ["sidewalk", "grass"]
    assert parse_names("['a', 'b']") == ["a", "b"]
    assert parse_names("{1: 'a'}") is None and parse_names("not python") is None
    output0 = raw_output([], nc=2, nm=NM, anchors=8)
    bare = _model(tmp_path, output0, _protos(), names=None)
    assert bare.names is None
    path = save_seg_onnx(tmp_path / "n.onnx", output0, _protos(), (64, 64), None)
    assert OnnxSegmentationModel(path, CPU, "terrain", "f", names=["x", "y"]).names == ["x", "y"]


def test_wrong_names_and_bad_files_are_clear_errors(tmp_path):
    output0 = raw_output([((24, 32, 32, 8), 1, 0.7, np.array([1.0, 0.0]))], nc=2, nm=NM, anchors=16)
    path = save_seg_onnx(tmp_path / "m.onnx", output0, _protos(), (64, 64), None)
    with pytest.raises(TerraError, match=r"output0 has shape \(1, 8, 16\).*3 classes.*\(1, 9, anchors\)"):
        OnnxSegmentationModel(path, CPU, "terrain", "perception.models.terrain.model", names=["a", "b", "c"])
    dynamic = save_seg_onnx(tmp_path / "d.onnx", output0, _protos(), (64, 64), None, dynamic=True)
    model = OnnxSegmentationModel(dynamic, CPU, "terrain", "perception.models.terrain.model", names=["a", "b", "c"])
    with pytest.raises(TerraError, match="configured names"):
        model.predict(np.zeros((30, 80, 3), np.uint8), DecodeSettings())
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a model")
    with pytest.raises(TerraError, match="junk.onnx is not a readable ONNX model"):
        OnnxSegmentationModel(junk, CPU, "terrain", "perception.models.terrain.model")
