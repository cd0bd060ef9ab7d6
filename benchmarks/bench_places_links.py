"""Places joined along their terrain, with and without grid links (issue 14's places target).

For the tiny, small (seeds 0-3) and campus presets' cached maps (`bench_regions_nav.py` makes them),
builds the scene graph twice in one process, side by side: **before** = no grid links
(`build.linking.grid_link_distance: null`), **after** = this checkout's default. Per map: the share
of same-terrain place pairs on one ground-truth terrain component joined by a path on that
terrain (over the ground the cameras labelled, the target's judgement, and over the whole raster:
terra.eval.metrics.places), unjoined pairs per terrain, places on their own terrain, how many grid
links the build made, the seconds of the grid-link step alone and of the whole build.

Usage: python benchmarks/bench_places_links.py [--cache DIR] [--maps tiny-seed0,small-seed0,...] [--out JSON]
Writes --out (default benchmarks/results/places_links.json) and prints a table.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT.parent))
from benchmarks.benchtable import report  # noqa: E402

MAPS = "tiny-seed0,small-seed0,small-seed1,small-seed2,small-seed3,campus-seed0"
CONFIGS = {"before": {"linking": {"grid_link_distance": None}}, "after": {}}


def grid_link_seconds(msm, config) -> tuple[int, float]:
    """(grid links, seconds of the grid-link step alone) on the map's places before linking."""
    from terra.graph.pipeline import (
        grid_links,
        strip_links,
        terrain_grid,
        terrain_places,
    )

    point_terrain = msm.terrain_index(config.terrain.min_share).astype(np.int16)
    grid = terrain_grid(msm.points, point_terrain, config)
    places, _, _ = terrain_places(grid, list(range(len(msm.terrain_classes))), config)
    strips, _ = strip_links(places, grid, config)
    start = time.perf_counter()
    links, _ = grid_links(places, np.vstack([places.edges, strips]), grid, config)
    return len(links), time.perf_counter() - start


def measure(folder: Path, config_overrides: dict) -> dict:
    """Every figure of one map under one build configuration."""
    from terra.bundle import Bundle
    from terra.datasets.ground_truth import load_ground_truth
    from terra.eval.metrics.places import (
        observed_cells,
        place_terrain_agreement,
        same_terrain_connectivity,
    )
    from terra.graph.config import BuildConfig
    from terra.graph.pipeline import build_scene_graph
    from terra.mapping.storage import load_map

    config = BuildConfig.model_validate(config_overrides)
    msm, gt = load_map(Bundle(folder / "map.terra")), load_ground_truth(folder / "dataset")
    start = time.perf_counter()
    build = build_scene_graph(msm, config)
    build_seconds = time.perf_counter() - start
    terrain = gt.terrain
    if terrain is None:
        raise SystemExit(f"{folder / 'dataset'}: the ground truth has no terrain raster")
    seen = observed_cells(terrain, msm.points[msm.terrain_index(0.5) >= 0])
    labelled = same_terrain_connectivity(build.graph, terrain, seen)
    links, link_seconds = grid_link_seconds(msm, config)
    return {
        "places": len(build.graph.places),
        "labelled_ground": labelled.to_json(),
        "whole_raster": same_terrain_connectivity(build.graph, terrain).to_json(),
        "unjoined_per_terrain": {k: v.pairs - v.joined for k, v in labelled.per_terrain.items() if v.pairs > v.joined},
        "terrain_agreement": place_terrain_agreement(build.graph, terrain).to_json(),
        "grid_links": links,
        "grid_link_seconds": link_seconds,
        "build_seconds": build_seconds,
        "edges": build.stats.edges.to_json(),
    }


def rows(result: dict) -> list[tuple[str, str, str]]:
    """'before -> after' of each figure, per map."""
    out = []
    for name, by_config in result["maps"].items():

        def side(get, by_config=by_config) -> str:
            return " -> ".join(get(by_config[c]) for c in CONFIGS)

        def places(m: dict) -> str:
            agreement = m["terrain_agreement"]
            return f"{m['places']} / {agreement['share']:.3f} / {agreement['farther_than_m']['1']}"

        pairs = by_config["after"]["labelled_ground"]["pairs"]
        out.append(
            (
                f"{name}: pairs joined, labelled ground (of pairs)",
                side(lambda m: f"{m['labelled_ground']['joined_share']:.4f}") + f" (of {pairs:,})",
                ">= 0.99",
            )
        )
        out.append(
            (f"{name}: unjoined pairs per terrain", side(lambda m: str(m["unjoined_per_terrain"] or "none")), "-")
        )
        out.append(
            (f"{name}: pairs joined, whole raster", side(lambda m: f"{m['whole_raster']['joined_share']:.4f}"), "-")
        )
        out.append((f"{name}: places / on own terrain / > 1 m from it", side(places), "no worse"))
        out.append(
            (
                f"{name}: grid links / their step s / build s",
                side(lambda m: f"{m['grid_links']} / {m['grid_link_seconds']:.2f} / {m['build_seconds']:.1f}"),
                "small",
            )
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument(
        "--cache", type=Path, default=Path(os.environ.get("TERRA_BENCH_CACHE", "/work/bench-cache/issue-14"))
    )
    parser.add_argument("--maps", default=MAPS, help="comma-separated PRESET-seedN folders of --cache")
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "places_links.json", help="JSON written")
    args = parser.parse_args()
    result = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "load_average_1min_at_start": os.getloadavg()[0],
        "date": time.strftime("%Y-%m-%d"),
        "configs": CONFIGS,
        "maps": {},
    }
    for name in args.maps.split(","):
        result["maps"][name] = {c: measure(args.cache / name, overrides) for c, overrides in CONFIGS.items()}
    report(rows(result), result, args.out)


if __name__ == "__main__":
    main()
