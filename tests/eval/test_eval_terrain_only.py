"""`terra eval --terrain-only DATASET --config ...`: Table I for any terrain segmenter on labelled
images, one row per config; scores checked against scikit-learn's metrics on the same pixels, and
no frame rate for the labels lookup."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

pytest.importorskip("onnxruntime")

from terra.cli import run
from terra.datasets import open_dataset
from terra.datasets.base import Frame
from tests.perception.fixtures import models_section


@pytest.fixture(scope="module")
def box_folder(tmp_path_factory):
    from terra.sim.writer import write_dataset
    from tests.mapping.fixtures import BoxScene

    return write_dataset(BoxScene(), tmp_path_factory.mktemp("boxdata") / "box", format="terra-folder", progress=False)


def _semantic(frame: Frame) -> np.ndarray:
    """The first camera's semantic labels (every box scene frame has them)."""
    semantic = frame.cameras[0].semantic
    assert semantic is not None
    return semantic


def _expected_prediction() -> np.ndarray:
    """The tiny terrain model on a 160 x 120 image (letterbox scale 0.4, 8 rows of padding): its asphalt
    box (image x 40..120, y 80..120) is painted first, then grass (x 80..160, y 60..120) over it; its
    sidewalk class is not a terrain class of the box scene (grass = 0, asphalt = 1) and paints nothing."""
    predicted = np.full((120, 160), 2, np.int64)  # 2 = not terrain
    predicted[80:120, 40:120] = 1
    predicted[60:120, 80:160] = 0
    return predicted


def test_table_one_for_labels_and_a_model(box_folder, tiny_models, tmp_path, capsys, text_embedder):
    from sklearn.metrics import f1_score, jaccard_score

    labels_cfg, model_cfg = tmp_path / "labels.yaml", tmp_path / "yolo.yaml"
    labels_cfg.write_text(yaml.safe_dump({"mapping": {"perception": {"backend": "labels"}}}))
    model_cfg.write_text(yaml.safe_dump({"mapping": {"perception": models_section(tiny_models)}}))
    code = run(
        [
            "eval",
            "--terrain-only",
            str(box_folder),
            "--config",
            str(labels_cfg),
            "--config",
            str(model_cfg),
            "--json",
            "-q",
        ]
    )
    assert code == 0
    table = json.loads(capsys.readouterr().out)
    assert table["images"] == 6
    labels, model = table["methods"]["labels (labels)"], table["methods"]["yolo (models)"]
    assert labels["miou"] == 1.0 and labels["f1"] == 1.0 and labels["fps"] is None
    assert model["fps"] > 0 and model["classes"] == ["grass", "asphalt"]
    # The same scores from scikit-learn on the same pixels.
    dataset = open_dataset(box_folder)
    index = {c.id: {"grass": 0, "asphalt": 1}.get(c.name, 2) for c in dataset.classes}
    truth = np.concatenate([[index.get(int(v), 2) for v in _semantic(dataset[i]).ravel()] for i in range(len(dataset))])
    predicted = np.tile(_expected_prediction().ravel(), len(dataset))
    # average=None (per-class scores) is documented; scikit-learn's defaults make pyright read `average` as str.
    iou = np.asarray(jaccard_score(truth, predicted, labels=[0, 1], average=None))  # pyright: ignore[reportArgumentType]
    f1 = np.asarray(f1_score(truth, predicted, labels=[0, 1], average=None))  # pyright: ignore[reportArgumentType]
    np.testing.assert_allclose(model["iou"], iou, rtol=1e-9)
    assert model["miou"] == pytest.approx(iou.mean()) and model["f1"] == pytest.approx(f1.mean())
    share = np.array([np.count_nonzero(truth == 0), np.count_nonzero(truth == 1)], float)
    assert model["fw_miou"] == pytest.approx(float(share @ iou / share.sum()))


def test_printed_table_has_no_fps_for_the_lookup(box_folder, tmp_path, capsys, text_embedder):
    code = run(["eval", "--terrain-only", str(box_folder), "-q"])
    assert code == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.strip().startswith("defaults (labels)"))
    assert row.split()[-1] == "-" and "1.000" in row
    assert "IoU per class, defaults (labels): grass 1.000, asphalt 1.000" in out


def test_without_terrain_only_gt_and_out_are_required(box_folder, capsys):
    assert run(["eval", str(box_folder), "--out", "x"]) == 2
    assert "--gt is required" in capsys.readouterr().err
