"""`terra demo --live`'s replay: answers asked during a simulated drive name the snapshot they were
answered on, and the final answer equals the same question on the batch map and graph."""

from __future__ import annotations

import pytest

from terra.live.replay import format_replay, replay
from terra.loaded import LoadedBundle
from terra.tasks.commands import find
from terra.tasks.requests import FindRequest

QUERY = "find the bicycle rack"


def test_replay_answers_on_snapshots_and_ends_with_the_batch_answer(tiny_campus, tiny_graph_bundle, tmp_path):
    gt = tiny_campus.ground_truth()
    waited: list[float] = []
    result = replay(
        tiny_campus,
        tmp_path / "live.terra",
        gt,
        QUERY,
        ask_at=[0.0, 30.0, 1e9],
        speed=100.0,
        update_every=20.0,
        sleep=waited.append,
    )
    assert result.drive_s == pytest.approx(tiny_campus[len(tiny_campus) - 1].stamp - tiny_campus[0].stamp)
    # At 100x, the replay waits (about) a hundredth of each stamp gap; never a negative wait.
    assert waited and min(waited) >= 0.0 and sum(waited) <= result.drive_s / 100.0 + 1e-6
    assert [a.at_s for a in result.answers] == [0.0, 30.0, 1e9]
    versions = [a.version or 0 for a in result.answers]
    assert versions == sorted(versions) and result.answers[0].version is not None  # snapshot at the first frame
    for answer in result.answers:
        assert answer.map_time is None or answer.map_time - tiny_campus[0].stamp <= max(answer.at_s, 0.0) + 1e-6
    final = result.final
    assert final is not None and final.version == max(versions)
    batch = find(LoadedBundle(tiny_graph_bundle.path), FindRequest(queries=[QUERY]))
    assert final.found == len(batch.objects) > 0
    best = max(batch.objects, key=lambda o: o.score)
    rack = next(o for o in gt.objects if o.class_name == "bicycle rack")
    distance = float(((best.center[0] - rack.center[0]) ** 2 + (best.center[1] - rack.center[1]) ** 2) ** 0.5)
    assert final.distance_m is not None and final.distance_m == pytest.approx(distance, abs=1e-3)
    assert final.distance_m < 2.0
    table = "\n".join(format_replay(result))
    assert "(final)" in table and f"{final.distance_m:.1f} m" in table
