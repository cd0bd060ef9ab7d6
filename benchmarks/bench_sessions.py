"""Sessions (issue 26): a second visit joined to a map, and what changed between the visits.

The simulator drives `--preset` once (the map) and twice more as revisits (`terra sim --revisit`): the
route reversed from 30 % of its length, poses in a frame 50 m and 90 degrees from the map's, one revisit
with the default changes (2 cars moved, 2 removed, 2 added, a bench gone, a lawn turned to dirt, a fence put
up across a sidewalk) and one with none. Each revisit is joined from an initial guess off the truth by
(`--guess-error`) metres and degrees, and once from the identity (a shared frame that is not shared: expected
to be refused).

Reported: alignment error against the simulator's T_world_session, fitness and overlap, the join's time
(its stages; `load` is the simulator rendering the frames, which a recorded log would not pay), points of
the joined map over the first map's, object changes against the simulator's list (locations where an
object was or is, matched within 1.5 m: precision and recall), false object changes per 10,000 m^2 of
area both visits observed on the revisit without changes, and terrain area changed there; blocked ground
(the fence's) found against the simulator's: its area at the raster's cells and at change detection's 1 m
cells (the cells its strip lies in).

Usage: python benchmarks/bench_sessions.py --preset small [--work DIR]

With `--work DIR` the maps are kept in DIR with what each step measured (DIR/steps.json), and a later run
with the same DIR reuses every map already there (delete one to make it again), so that change detection
can be measured again in seconds.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _join(first: Path, out: Path, visit, prior) -> dict:
    """Join `visit` into a copy of the map `first` at `out`; what it took and found."""
    from terra.errors import TerraError
    from terra.mapping.config import MappingConfig
    from terra.mapping.pipeline import run_mapping
    from terra.mapping.sessions import plan_join, relative_error
    from terra.progress import StageTimer
    from terra.sim.revisit import session_pose

    shutil.copytree(first, out)
    timer = StageTimer()
    start = time.perf_counter()
    try:
        with timer.stage("align"):
            plan = plan_join(visit, out, prior)
    except TerraError as exc:
        return {"refused": str(exc), "seconds": time.perf_counter() - start}
    run = run_mapping(
        plan.frames, MappingConfig(), out, show_progress=False, timer=timer, join=plan.alignment.to_json()
    )
    metres, degrees = relative_error(session_pose(visit.config.revisit), plan.alignment.T_map_session)
    return {
        "error_m": metres,
        "error_deg": degrees,
        "fitness": plan.alignment.fitness,
        "overlap": plan.alignment.overlap,
        "seconds": time.perf_counter() - start,
        "stages": timer.to_json(),
        "points": run.counts.points,
    }


def _step(work: Path, name: str, make) -> dict:
    """What `make()` measured, or what it measured in an earlier run with the same `--work` folder (the
    bundle `name` and its record both there)."""
    record_file = work / "steps.json"
    records = json.loads(record_file.read_text()) if record_file.exists() else {}
    if name in records and (work / f"{name}.terra").exists():
        return records[name]
    shutil.rmtree(work / f"{name}.terra", ignore_errors=True)  # a run stopped half way
    records[name] = make()
    record_file.write_text(json.dumps(records, indent=1, sort_keys=True) + "\n")
    return records[name]


def _changes(out: Path, truth: dict) -> dict:
    """Object changes found against the simulator's, as locations matched within 1.5 m."""
    from terra.tasks.change_report import report_changes

    found = report_changes(out, 1, 2).to_json()
    seen = [c[k][:2] for c in found["objects"] for k in ("before", "after") if c[k] is not None]
    true = [c[k][:2] for c in truth["objects"] for k in ("from", "to") if c[k] is not None]
    result = {"observed_area_m2": found["observed_area_m2"], "counts": found["counts"], "terrain": found["terrain"]}
    result["found_locations"], result["true_locations"] = len(seen), len(true)
    if seen and true:
        distance = np.linalg.norm(np.asarray(seen)[:, None] - np.asarray(true)[None], axis=2)
        result["precision"] = float(np.mean(distance.min(axis=1) < 1.5))
        result["recall"] = float(np.mean(distance.min(axis=0) < 1.5))
    result["changes_per_10000_m2"] = len(found["objects"]) / max(found["observed_area_m2"], 1.0) * 1e4
    result["moves"] = _moves(found["objects"], truth["objects"])
    result["blocked"] = _blocked(found["terrain"], truth["terrain"])
    result["named"] = sorted({str(c["name"]) for c in found["objects"]})
    return result


def _moves(found: list[dict], true: list[dict]) -> list[dict]:
    """Each true move and the move found from within 1.5 m of where it was to within 1.5 m of where it is
    (its distance, metres), if any."""
    out = []
    for move in (c for c in true if c["change"] == "moved"):
        match = [
            c["distance"]
            for c in found
            if c["change"] == "moved"
            and np.linalg.norm(np.subtract(c["before"][:2], move["from"][:2])) < 1.5
            and np.linalg.norm(np.subtract(c["after"][:2], move["to"][:2])) < 1.5
        ]
        out.append({"true_m": move["distance"], "found_m": match[0] if match else None})
    return out


def _blocked(found: list[dict], truth: list[dict], cell: float = 1.0) -> list[dict]:
    """Each true blocked strip (a fence's footprint, in raster cells) against the area found for its pair
    ("sidewalk -> blocked"): its true area, the area of the `cell` metre cells (change detection's terrain
    cell) its polygon lies in, and the area found (m^2)."""
    out = []
    for strip in (t for t in truth if t["to"] == "blocked"):
        (x0, y0), (x1, y1) = strip["polygon"][0], strip["polygon"][2]
        cells = (np.ceil(x1 / cell) - np.floor(x0 / cell)) * (np.ceil(y1 / cell) - np.floor(y0 / cell)) * cell**2
        pair = (strip["from"], "blocked")
        found_m2 = sum(t["area_m2"] for t in found if (t["before"], t["after"]) == pair)
        out.append(
            {"pair": " -> ".join(pair), "true_m2": strip["area_m2"], "true_cells_m2": cells, "found_m2": found_m2}
        )
    return out


def _truth(visit) -> dict:
    """The simulator's list of changes of a revisit."""
    if visit.revisit is None:
        raise ValueError("not a revisit")
    return visit.revisit.to_json()


def main() -> None:
    parser = argparse.ArgumentParser(description="Sessions (issue 26): a second visit joined, what changed.")
    parser.add_argument("--preset", default="small")
    parser.add_argument("--guess-error", type=float, nargs=2, default=(3.0, 8.0), metavar=("METRES", "DEGREES"))
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "sessions.json")
    parser.add_argument("--work", type=Path, help="keep the maps here and reuse those already made")
    parser.add_argument("--skip-identity", action="store_true", help="no join from the identity (the slowest)")
    args = parser.parse_args()

    from terra.mapping.align import pose_from_guess
    from terra.mapping.config import MappingConfig
    from terra.mapping.pipeline import run_mapping
    from terra.sim import simulate
    from terra.sim.config import RevisitConfig, SimConfig

    none = RevisitConfig(cars_moved=0, cars_removed=0, cars_added=0, benches_removed=0, lawns_to_dirt=0, fences_added=0)
    x, y, yaw = RevisitConfig().frame
    metres, degrees = args.guess_error
    guess = pose_from_guess(x + metres * 0.8, y - metres * 0.6, yaw + degrees)
    report: dict = {"preset": args.preset, "guess": [x + metres * 0.8, y - metres * 0.6, yaw + degrees]}
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        first = work / "first.terra"

        def first_map() -> dict:
            start = time.perf_counter()
            run = run_mapping(simulate(args.preset, 0), MappingConfig(), first, show_progress=False)
            return {"seconds": time.perf_counter() - start, "points": run.counts.points}

        report["first"] = _step(work, "first", first_map)
        changed = simulate(args.preset, 0, SimConfig(revisit=RevisitConfig()))
        same = simulate(args.preset, 0, SimConfig(revisit=none))
        report["join_unchanged"] = _step(work, "same", lambda: _join(first, work / "same.terra", same, guess))
        report["join_unchanged"]["changes"] = _changes(work / "same.terra", _truth(same))
        report["join"] = _step(work, "changed", lambda: _join(first, work / "changed.terra", changed, guess))
        report["join"]["changes"] = _changes(work / "changed.terra", _truth(changed))
        if not args.skip_identity:
            report["join_identity"] = _step(
                work, "identity", lambda: _join(first, work / "identity.terra", changed, None)
            )
    for key in ("join", "join_unchanged"):
        report[key]["points_ratio"] = report[key]["points"] / report["first"]["points"]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1, sort_keys=True) + "\n")
    print(json.dumps(report, indent=1, sort_keys=True))


if __name__ == "__main__":
    main()
