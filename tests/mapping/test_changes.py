"""`terra changes` (terra/mapping/changes.py) on the simulated tiny campus and its revisits: the changes found
against the simulator's list of changes, nothing found on a revisit without changes, and per-session terrain
votes that add up to the map's."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.cli import run
from terra.mapping.align import pose_from_guess
from terra.mapping.changes import ChangeSettings, detect_changes
from terra.mapping.config import MappingConfig
from terra.mapping.pipeline import run_mapping
from terra.mapping.sessions import plan_join
from terra.sim.config import RevisitConfig, SimConfig
from terra.sim.dataset import simulate

GUESS = pose_from_guess(47.0, -3.0, 85.0)  # the revisit's frame lies at (50, 0, 90 degrees)
NO_CHANGE = RevisitConfig(
    cars_moved=0, cars_removed=0, cars_added=0, benches_removed=0, lawns_to_dirt=0, fences_added=0
)


@pytest.fixture(scope="module")
def first_map(tiny_campus, tmp_path_factory):
    out = tmp_path_factory.mktemp("changes") / "first.terra"
    run_mapping(tiny_campus, MappingConfig(), out, show_progress=False)
    return out


def joined(first_map, tmp_path, revisit: RevisitConfig):
    """The first map with the revisit joined; the revisit's dataset."""
    out = tmp_path / "joined.terra"
    shutil.copytree(first_map, out)
    visit = simulate("tiny", 0, SimConfig(revisit=revisit))
    plan = plan_join(visit, out, GUESS)
    run_mapping(plan.frames, MappingConfig(), out, show_progress=False, join=plan.alignment.to_json())
    return out, visit


def locations(changes: list[dict], before: str, after: str) -> np.ndarray:
    """(M, 2) x-y metres where something changed: where an object was and where it is."""
    points = [c[key][:2] for c in changes for key in (before, after) if c[key] is not None]
    return np.asarray(points, dtype=np.float64).reshape(-1, 2)


def test_the_changes_found_are_the_simulators(first_map, tmp_path, capsys):
    out, visit = joined(first_map, tmp_path, RevisitConfig())
    assert visit.revisit is not None
    truth = visit.revisit.to_json()
    assert run(["changes", str(out), "--between", "1", "2", "--json"]) == 0
    found = json.loads(capsys.readouterr().out)
    assert found["between"] == [1, 2] and found["objects"]
    seen, true = locations(found["objects"], "before", "after"), locations(truth["objects"], "from", "to")
    distance = np.linalg.norm(seen[:, None] - true[None], axis=2)
    precision = float(np.mean(distance.min(axis=1) < 1.5))
    recall = float(np.mean(distance.min(axis=0) < 1.5))
    assert precision == 1.0 and recall >= 0.8, (precision, recall)
    for change in found["objects"]:  # a move found where the simulator moved a car: the distance it moved
        if change["change"] != "moved":
            continue
        for moved in (c for c in truth["objects"] if c["change"] == "moved"):
            if np.linalg.norm(np.subtract(moved["from"][:2], change["before"][:2])) < 1.5:
                assert abs(change["distance"] - moved["distance"]) < 1.0
    (patch,) = [t for t in truth["terrain"] if t["to"] == "dirt"]
    to_dirt = [t for t in found["terrain"] if (t["before"], t["after"]) == ("grass", "dirt")]
    assert to_dirt and 0 < to_dirt[0]["area_m2"] <= patch["area_m2"] + 12.0  # the patch's cells, ~1 m each side
    _the_fence_is_found(truth, found)
    # Its voxels spread it 0.3 to 0.4 m wide here; as a sliver too (0.5 m), it is judged, as a wall of its own
    (fence,) = [c["to"][:2] for c in truth["objects"] if c["class"] == "fence"]
    slivers = [o.to_json() for o in detect_changes(out, 1, 2, ChangeSettings(min_width=0.5)).objects]
    near = [c["change"] for c in slivers if np.linalg.norm(np.subtract((c["after"] or c["before"])[:2], fence)) < 1.5]
    assert near == ["added"]
    truth_classes = {(c["change"], c["class"]) for c in truth["objects"]}
    named = {(c["change"], c["name"]) for c in found["objects"] if c["name"] is not None}  # None: LiDAR only
    assert named and named <= truth_classes  # named by class, not by bank entry
    assert found["regions"] is None  # no scene graph yet
    assert run(["changes", str(out)]) == 0
    text = capsys.readouterr().out
    assert f"objects: {found['counts']['added']} added, {found['counts']['removed']} removed" in text
    assert "grass -> dirt" in text and "sidewalk -> blocked" in text and "car (bank entry" in text


def _the_fence_is_found(truth: dict, found: dict) -> None:
    """The fence the revisit put up across a sidewalk: found as an added fence where it stands, and the ground
    under it as sidewalk -> blocked over the 1 m cells (change detection's `terrain_cell`) that the truth's
    blocked cells (0.25 m raster cells under its footprint) lie in, give or take a cell at each end."""
    (fence,) = [c for c in truth["objects"] if c["class"] == "fence"]
    (added,) = [
        c for c in found["objects"] if c["after"] and np.linalg.norm(np.subtract(c["after"][:2], fence["to"][:2])) < 1.5
    ]
    assert added["change"] == "added" and added["name"] == "fence"
    (blocked,) = [t for t in truth["terrain"] if t["to"] == "blocked"]
    (x0, y0), (x1, y1) = blocked["polygon"][0], blocked["polygon"][2]
    cells = (np.ceil(x1) - np.floor(x0)) * (np.ceil(y1) - np.floor(y0))  # 1 m cells the strip lies in
    area = sum(t["area_m2"] for t in found["terrain"] if (t["before"], t["after"]) == ("sidewalk", "blocked"))
    assert abs(area - cells) <= 2.0, (area, cells)


def test_changes_per_region_and_figure(first_map, tmp_path, capsys):
    out, _ = joined(first_map, tmp_path, RevisitConfig())
    assert run(["build", str(out)]) == 0
    capsys.readouterr()
    figure = tmp_path / "changes.png"
    assert run(["changes", str(out), "--json", "--figure", str(figure)]) == 0
    found = json.loads(capsys.readouterr().out)
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    regions = found["regions"]
    assert regions and all(o["region"] for o in found["objects"])
    for kind in ("added", "removed", "moved"):  # every change counted once, in the region of its object
        assert sum(r[kind] for r in regions) == found["counts"][kind]
    terrain = sum(t["area_m2"] for t in found["terrain"])
    assert sum(sum(r["terrain_m2"].values()) for r in regions) == pytest.approx(terrain)
    assert run(["changes", str(out)]) == 0
    assert "per region:" in capsys.readouterr().out
    mine = tmp_path / "mine.png"  # a picture Terra did not draw is kept unless --overwrite
    mine.write_bytes(b"not ours")
    assert run(["changes", str(out), "--figure", str(mine)]) == 2
    assert "exists (pass --overwrite to replace it)" in capsys.readouterr().err and mine.read_bytes() == b"not ours"
    assert run(["changes", str(out), "--figure", str(mine), "--overwrite"]) == 0
    assert mine.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for bad in (tmp_path / "changes.txt", tmp_path / "missing" / "changes.png", tmp_path):
        assert run(["changes", str(out), "--figure", str(bad)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "expected a PNG file name" in err
    _served_blocked_ground(out, found)


def _served_blocked_ground(out, found: dict) -> None:
    """GET /changes of `terra serve` answers as `terra changes --json` (`found`), the fence's blocked
    sidewalk and each region's share of it included."""
    pytest.importorskip("fastapi")
    from fastapi.testclient import TestClient

    from terra.loaded import LoadedBundle
    from terra.serve.app import create_app
    from terra.serve.config import ServeConfig

    answer = TestClient(create_app(LoadedBundle(out), settings=ServeConfig())).get(
        "/changes", params={"first": 1, "second": 2}
    )
    assert answer.status_code == 200 and answer.json() == found
    blocked = [t["area_m2"] for t in found["terrain"] if (t["before"], t["after"]) == ("sidewalk", "blocked")]
    assert blocked and sum(r["terrain_m2"].get("sidewalk -> blocked", 0.0) for r in found["regions"]) == pytest.approx(
        blocked[0]
    )


def test_a_revisit_without_changes_has_none(first_map, tmp_path):
    out, visit = joined(first_map, tmp_path, NO_CHANGE)
    assert visit.revisit is not None
    assert visit.revisit.objects == [] and visit.revisit.terrain == []
    result = detect_changes(out, 1, 2)
    assert result.observed_area_m2 > 1000.0
    assert result.objects == []
    assert not [t for t in result.terrain if "blocked" in (t.before, t.after)]  # no object changed, none blocked
    false_area = sum(t.area_m2 for t in result.terrain)
    assert false_area <= 0.005 * result.observed_area_m2  # boundary cells between two terrains, at most 0.5 %
    bundle = Bundle(out)
    votes = np.asarray(bundle.array("map/state/session_votes"), dtype=np.int64)
    np.testing.assert_array_equal(votes.sum(axis=0), np.asarray(bundle.array("map/terrain_votes"), np.int64))


def test_changes_need_two_sessions(first_map, capsys):
    assert run(["changes", str(first_map)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "the map has one session" in err
