"""`terra render`: every figure is drawn on its own as a real picture, the path figure reports
the same plan as `terra plan`, and bad options exit 2 without writing."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from terra.cli import run
from terra.loaded import LoadedBundle
from terra.tasks.commands import plan
from terra.tasks.requests import PlanRequest


def _pixels(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"))


@pytest.mark.parametrize("what", ["terrain", "places", "regions", "objects"])
def test_each_figure_is_a_picture_not_one_colour(interop_bundle, tmp_path, what):
    out = tmp_path / f"{what}.png"
    assert run(["render", str(interop_bundle.path), "--what", what, "--out", str(out), "--dpi", "60"]) == 0
    pixels = _pixels(out)
    assert pixels.shape[0] > 200 and pixels.shape[1] > 200
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 20


def test_objects_are_drawn_in_their_labels_colours(interop_bundle, tmp_path):
    out = tmp_path / "objects.png"
    assert run(["render", str(interop_bundle.path), "--what", "objects", "--out", str(out)]) == 0
    orange = np.array([255, 127, 14])  # tab10's second colour: the second label, "trash can"
    assert (np.abs(_pixels(out).astype(int) - orange).sum(axis=2) == 0).sum() > 20


def test_path_figure_reports_the_plan_of_terra_plan(interop_bundle, tmp_path, capsys):
    out = tmp_path / "path.png"
    args = ["--from-node", "2", "--to-node", "30", "--prefer", "sidewalk"]
    assert run(["render", str(interop_bundle.path), "--what", "path", "--out", str(out), "--json", *args]) == 0
    summary = json.loads(capsys.readouterr().out)
    report = plan(
        LoadedBundle(interop_bundle.path), PlanRequest(from_node=2, to_node=30, prefer=["sidewalk"])
    ).to_json()
    assert summary["length_m"] == report["length_m"] and summary["length_by_terrain"] == report["length_by_terrain"]
    assert summary["places"] == len(report["places"]) and out.is_file()


def test_bad_options_exit_2_and_write_nothing(interop_bundle, tmp_path, capsys):
    out = tmp_path / "x.png"
    assert run(["render", str(interop_bundle.path), "--what", "mesh", "--out", str(out)]) == 2
    assert run(["render", str(interop_bundle.path), "--what", "path", "--out", str(out), "--to-node", "99999"]) == 2
    assert run(["render", str(interop_bundle.path), "--what", "places", "--out", str(tmp_path / "no" / "x.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("terra: error:") for line in err)
    assert list(tmp_path.iterdir()) == []
