"""A recorded drive replayed as if live (`terra demo --live`): frames fed to a Session at their own
pace (`speed` times real time), a snapshot every `update_every` seconds of drive time, and a find
and a plan asked at fixed drive times on the latest snapshot; each answer is set beside the
answer on the final map (the same map as one batch run) and judged against the ground truth.

Drive time is the scan stamps' (seconds from the first scan). An answer names the version and map
time it was answered on; before the object has been seen it says "not yet seen", as a robot's
query would.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from terra.datasets.base import Dataset
from terra.datasets.ground_truth import GroundTruth
from terra.errors import TerraError
from terra.live.session import Session, Snapshot
from terra.mapping.config import MappingConfig


@dataclass
class LiveAnswer:
    """One question asked during the drive. at_s: drive time, seconds; version / map_time: the
    snapshot answered on (None before the first); found: objects returned; distance_m: 2-D
    metres from the best object to the nearest true object of the class (None when none found);
    plan_m: the plan's length, metres, or plan_note why there is none."""

    at_s: float
    version: int | None
    map_time: float | None
    frames: int
    found: int
    distance_m: float | None
    plan_m: float | None
    plan_note: str = ""


@dataclass
class LiveReplay:
    """What a replay asked and answered, and the final (batch-equal) answer."""

    query: str
    speed: float
    drive_s: float
    wall_s: float
    snapshots: int
    answers: list[LiveAnswer] = field(default_factory=list)
    final: LiveAnswer | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            **{k: v for k, v in asdict(self).items() if k not in ("answers", "final")},
            "answers": [asdict(a) for a in self.answers],
            "final": asdict(self.final) if self.final is not None else None,
        }


def replay(
    dataset: Dataset,
    out: Path,
    gt: GroundTruth,
    query: str,
    *,
    ask_at: list[float],
    speed: float = 1.0,
    update_every: float = 2.0,
    alpha: float | None = None,
    config: MappingConfig | None = None,
    sleep: Callable[[float], None] = time.sleep,
) -> LiveReplay:
    """Replay `dataset` into a new live bundle `out` (mapped with `config`, default MappingConfig());
    ask `query` (find, then plan to it) at the drive times `ask_at` (seconds). `speed`: times real
    time (0 = as fast as frames fuse)."""
    if len(dataset) == 0:
        raise TerraError(f"dataset {dataset.name!r} has no frames")
    prior = dataset.global_map()  # the source's own map, as `terra map` uses it
    session = Session(out, dataset.classes, config, name=dataset.name, overwrite=True, global_map=prior)
    t0: float | None = None
    wall0 = time.monotonic()
    pending = sorted(float(t) for t in ask_at)
    result = LiveReplay(query, speed, 0.0, 0.0, 0)
    last_snapshot = -np.inf
    for i in range(len(dataset)):
        frame = dataset[i]
        t0 = float(frame.stamp) if t0 is None else t0
        drive = result.drive_s = float(frame.stamp) - t0
        if speed > 0:
            sleep(max(0.0, wall0 + drive / speed - time.monotonic()))
        session.add(frame)
        if drive - last_snapshot >= update_every:
            session.snapshot()
            result.snapshots += 1
            last_snapshot = drive
        while pending and pending[0] <= drive:
            result.answers.append(ask(session.latest, pending.pop(0), gt, query, alpha))
    final = session.close()  # the last graph built in full: the batch graph of the map
    if final is None:
        raise TerraError(f"{dataset.name}: no frame was fused; nothing to answer on")
    result.snapshots += 1
    result.answers.extend(ask(final, t, gt, query, alpha) for t in pending)
    result.final = ask(final, result.drive_s, gt, query, alpha)
    result.wall_s = time.monotonic() - wall0
    return result


def ask(snapshot: Snapshot | None, at: float, gt: GroundTruth, query: str, alpha: float | None) -> LiveAnswer:
    """`query` found and planned to on `snapshot` (or "nothing mapped yet" without one)."""
    if snapshot is None:
        return LiveAnswer(at, None, None, 0, 0, None, None, "nothing mapped yet")
    found, distance = _find(snapshot, gt, query, alpha)
    plan_m, note = _plan(snapshot, query, alpha) if found else (None, "not yet seen")
    return LiveAnswer(at, snapshot.version, snapshot.map_time, snapshot.frames, found, distance, plan_m, note)


def _find(snapshot: Snapshot, gt: GroundTruth, query: str, alpha: float | None) -> tuple[int, float | None]:
    from terra.eval.judging import gt_class_of, nearest_gt_object
    from terra.tasks.commands import find
    from terra.tasks.requests import FindRequest

    result = find(snapshot.bundle, FindRequest(queries=[query], alpha=alpha))
    if not result.objects:
        return 0, None
    best = max(result.objects, key=lambda o: o.score)
    nearest = nearest_gt_object(np.asarray(best.center), gt, gt_class_of(query, gt))
    return len(result.objects), None if nearest is None else float(nearest["distance_m"])


def _plan(snapshot: Snapshot, query: str, alpha: float | None) -> tuple[float | None, str]:
    from terra.tasks.commands import plan
    from terra.tasks.requests import PlanRequest

    if snapshot.bundle.graph is None:
        return None, snapshot.graph_note or "no scene graph yet"
    try:
        result = plan(snapshot.bundle, PlanRequest(to=query, alpha=alpha))
    except TerraError as exc:
        return None, str(exc)
    return float(result.plan.to_json()["length_m"]), ""


def format_replay(result: LiveReplay) -> list[str]:
    """The replay as a table: each live answer beside the final one."""
    final = result.final
    lines = [
        f"live replay of {result.drive_s:.0f} s of drive at {result.speed:g}x ({result.wall_s:.0f} s wall, "
        f"{result.snapshots} snapshots): {result.query!r}",
        "  drive time  version  map time  found  to truth  plan",
    ]
    for a in [*result.answers, *([final] if final is not None else [])]:
        tag = "  (final)" if a is final else ""
        distance = f"{a.distance_m:.1f} m" if a.distance_m is not None else "-"
        planned = f"{a.plan_m:.1f} m" if a.plan_m is not None else (a.plan_note[:60] or "-")
        when = f"{a.map_time:.1f} s" if a.map_time is not None else "-"
        lines.append(
            f"  {a.at_s:8.1f} s  {a.version if a.version is not None else '-':>7}  {when:>8}  {a.found:5d}  "
            f"{distance:>8}  {planned}{tag}"
        )
    return lines
