"""The viewer's changes layer (terra/viewer/changes.py): markers of a hand-made result worked by hand, and
on the tiny campus joined with its revisit, the viewer's changes equal `terra changes`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from terra.loaded import LoadedBundle
from terra.mapping.changes import ChangesResult, ObjectChange, TerrainChange
from terra.mapping.config import MappingConfig
from terra.mapping.pipeline import run_mapping
from terra.sim.config import RevisitConfig
from terra.tasks.change_report import report_changes
from terra.viewer import scene
from terra.viewer.changes import KIND_COLOURS, LIFT, change_markers, changes_markdown
from tests.mapping.test_changes import joined

viser = pytest.importorskip("viser")


def hand_made() -> ChangesResult:
    objects = [
        ObjectChange("added", 3, None, (10.0, 2.0, 1.0), None, (4.0, 2.0, 1.5), name="car", region="R1"),
        ObjectChange("removed", 5, (0.0, 0.0, 0.5), None, None, (1.5, 0.5, 1.0), name="bench"),
        ObjectChange("moved", 3, (20.0, 0.0, 1.0), (26.0, 0.0, 1.0), 6.0, (4.0, 2.0, 1.5), name="car"),
    ]
    terrain = [TerrainChange("grass", "dirt", 2.0)]
    result = ChangesResult(Path("x.terra"), 1, 2, 900.0, objects, terrain)
    result.terrain_cells = np.array([[5.5, 5.5], [6.5, 5.5]])
    result.terrain_pairs = ["grass -> dirt", "grass -> dirt"]
    return result


def test_markers_of_a_hand_made_result():
    ground = np.array([[5.4, 5.6, 0.2], [6.6, 5.4, 0.4], [50.0, 50.0, 9.0]])
    markers = change_markers(hand_made(), ground)
    assert markers.objects["added"].tolist() == [[10.0, 2.0, 1.0]]
    assert markers.objects["removed"].tolist() == [[0.0, 0.0, 0.5]]  # where it was
    assert markers.objects["moved"].tolist() == [[26.0, 0.0, 1.0]]  # where it is
    assert markers.moves.tolist() == [[[20.0, 0.0, 1.0], [26.0, 0.0, 1.0]]]
    np.testing.assert_allclose(markers.cells, [[5.5, 5.5, 0.2 + LIFT], [6.5, 5.5, 0.4 + LIFT]])
    assert markers.pairs == ["grass -> dirt"] and (markers.cell_colours[0] == markers.cell_colours[1]).all()
    text = changes_markdown(hand_made())
    assert "1 added, 1 removed, 1 moved" in text and "moved: car at (26.0, 0.0), moved 6.0 m" in text
    assert "added: car at (10.0, 2.0) (R1)" in text and "terrain grass -> dirt: 2 m²" in text


def test_blocked_ground_has_its_own_colours():
    """Ground a fence now stands on is black, ground a car left gold, whatever the other pairs are."""
    result = hand_made()
    result.terrain = [TerrainChange("sidewalk", "blocked", 1.0), TerrainChange("blocked", "asphalt", 1.0)]
    result.terrain_pairs = ["sidewalk -> blocked", "blocked -> asphalt"]
    markers = change_markers(result, np.array([[5.4, 5.6, 0.2], [6.6, 5.4, 0.4]]))
    assert markers.cell_colours.tolist() == [[0, 0, 0], [255, 214, 0]]
    text = changes_markdown(result)
    assert "terrain sidewalk -> blocked: 1 m²" in text and "terrain blocked -> asphalt: 1 m²" in text
    result.terrain_pairs = ["grass -> dirt", "blocked -> asphalt"]  # the palette's first colour stays grass's
    alone = change_markers(hand_made(), np.array([[5.4, 5.6, 0.2], [6.6, 5.4, 0.4]]))
    assert change_markers(result, alone.cells).cell_colours[0].tolist() == alone.cell_colours[0].tolist()


def test_the_viewer_draws_what_terra_changes_finds(tiny_campus, tmp_path):
    from terra.viewer.app import TerraViewer, free_port

    first = tmp_path / "first.terra"
    run_mapping(tiny_campus, MappingConfig(), first, show_progress=False)
    out, _ = joined(first, tmp_path, RevisitConfig())
    viewer = TerraViewer(LoadedBundle(out), port=free_port("127.0.0.1"))
    try:
        text = viewer.run_changes(1, 2)
        expected = report_changes(out, 1, 2)
        assert viewer.last_result.to_json() == expected.to_json()
        counts = expected.to_json()["counts"]
        assert text.startswith("**Session 1 -> 2**") and f"{counts['added']} added" in text
        markers = change_markers(expected, viewer.msm.points[viewer.rows])
        for kind in KIND_COLOURS:
            assert len(markers.objects[kind]) == counts[kind]
        assert sum(counts.values()) > 0
        # Two drives, each on its own clock: two lines, none from the first drive's end to the second's start.
        images = viewer.msm.images
        assert len(scene.trajectory_segments(viewer.msm)) == int(np.count_nonzero(images.camera == 0)) - 2
    finally:
        viewer.stop()
