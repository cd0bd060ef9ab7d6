"""Aligning a second visit to a map (issue 26): every way the alignment can start, side by side.

Inputs: `--map`, a bundle of the first visit mapped with voxel geometry (`terra sim --preset P --out s1`,
`terra map s1 --out map.terra` with `mapping.fusion.use_global_map: false`), and `--revisit`, the second
visit's folder (`terra sim --preset P --revisit --out s2`; same preset and seed). The session's cloud is
read once from the revisit's scans; each case then runs the join's alignment (terra.mapping.sessions.
find_alignment) from its start:
- no guess: the footprint search (and the shared frame where it overlaps);
- a guess 3 m and 8 degrees off the truth;
- GNSS: both visits carry the simulator's receiver (terra.sim.config.GnssConfig) with white noise and a
  per-drive bias of the given sizes; each visit's anchor is fitted to its fixes as `terra map` does
  (no frame is rendered: the anchors need only poses and fixes), the prior is the pose between them.
Reported per case: the prior's error, the alignment's error against the simulator's T_world_session,
how it was found, fitness, and seconds.

Usage: python benchmarks/bench_align.py --map map.terra --revisit s2 [--preset small --seed 0]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.benchtable import report  # noqa: E402

GNSS_CASES = ((2.0, 0.0), (2.0, 2.0), (5.0, 5.0))  # (white noise, bias) metres per horizontal axis


def _gnss_prior(preset: str, seed: int, noise: float, bias: float) -> np.ndarray:
    """T_map_session between the two visits' anchors fitted to the simulator's fixes."""
    from terra.schemas import Wgs84Anchor
    from terra.sim.config import GnssConfig, RevisitConfig, SimConfig
    from terra.sim.dataset import simulate
    from terra.wgs84 import pose_between

    receiver = GnssConfig(noise_m=noise, bias_m=bias)
    anchors = []
    for revisit in (None, RevisitConfig()):
        visit = simulate(preset, seed, SimConfig(gnss=receiver, revisit=revisit))
        anchors.append(Wgs84Anchor.model_validate(visit.wgs84_anchor()))
    return pose_between(anchors[0], anchors[1])


def _case(name: str, map_cloud, cloud, truth, prior=None, gnss=None) -> dict:
    from terra.errors import TerraError
    from terra.mapping.align import AlignSettings
    from terra.mapping.sessions import find_alignment, relative_error

    start = time.perf_counter()
    result: dict = {"case": name}
    start_pose = prior if prior is not None else gnss
    if start_pose is not None:
        result["prior_error_m"], result["prior_error_deg"] = relative_error(truth, start_pose)
    try:
        alignment = find_alignment(map_cloud, cloud, prior, AlignSettings(), "session", gnss)
    except TerraError as exc:
        return {**result, "refused": str(exc), "seconds": time.perf_counter() - start}
    metres, degrees = relative_error(truth, alignment.T_map_session)
    return {
        **result,
        "how": alignment.how,
        "error_m": metres,
        "error_deg": degrees,
        "fitness": alignment.fitness,
        "overlap": alignment.overlap,
        "seconds": time.perf_counter() - start,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description="Aligning a second visit to a map, every way it can start.")
    parser.add_argument("--map", type=Path, required=True)
    parser.add_argument("--revisit", type=Path, required=True)
    parser.add_argument("--preset", default="small")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "align.json")
    args = parser.parse_args()

    from terra.bundle import Bundle
    from terra.datasets.registry import open_dataset
    from terra.mapping.align import AlignSettings, pose_from_guess, session_cloud
    from terra.mapping.sessions import map_points

    truth = np.asarray(json.loads((args.revisit / "revisit.json").read_text())["T_world_session"])
    settings = AlignSettings()
    started = time.perf_counter()
    cloud = session_cloud(open_dataset(args.revisit), settings.voxel, settings.max_frames)
    cloud_seconds = time.perf_counter() - started
    map_cloud = map_points(Bundle(args.map))
    yaw = np.degrees(np.arctan2(truth[1, 0], truth[0, 0]))
    guess = pose_from_guess(truth[0, 3] + 3.0 * np.cos(0.6), truth[1, 3] + 3.0 * np.sin(0.6), yaw + 8.0)
    cases = [_case("no guess", map_cloud, cloud, truth), _case("guess 3 m, 8 deg off", map_cloud, cloud, truth, guess)]
    for noise, bias in GNSS_CASES:
        gnss = _gnss_prior(args.preset, args.seed, noise, bias)
        cases.append(_case(f"GNSS noise {noise:g} m, bias {bias:g} m", map_cloud, cloud, truth, gnss=gnss))
    rows = [("session cloud (read once)", f"{cloud_seconds:.1f} s, {len(cloud):,} points", "")]
    for c in cases:
        prior = f"prior {c['prior_error_m']:.2f} m / {c['prior_error_deg']:.2f} deg; " if "prior_error_m" in c else ""
        found = (
            f"{c['error_m']:.4f} m / {c['error_deg']:.3f} deg ({c['how']}, fitness {c['fitness']:.3f})"
            if "error_m" in c
            else f"refused: {c['refused'][:80]}"
        )
        rows.append((c["case"], f"{prior}{found}, {c['seconds']:.1f} s", "<= 0.2 m, 0.5 deg"))
    result = {
        "cases": cases,
        "session_cloud_seconds": cloud_seconds,
        "session_points": len(cloud),
        "map_points": len(map_cloud),
        "load_average_1min_at_start": os.getloadavg()[0],
        "cpus": os.cpu_count(),
    }
    report(rows, result, args.out)


if __name__ == "__main__":
    main()
