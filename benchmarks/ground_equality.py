"""Ground segmentation and layers of this tree against a ground.py of another commit, bit for bit
(issue 27: the layer made cheaper without changing its outputs).

Compares, with numpy.array_equal (NaN equal to NaN; dtypes and shapes too):
- axis_step (with and without rise), despike and plane_fit (with and without offsets and a
  reference) on random height grids with holes;
- segment_ground (through points_ground and the default build section) of each real SemanticKITTI
  scan in tests/data/semantickitti, and ground_layers of its ground points on frames of 0.4 and
  0.25 m cells, whole and in bands of a few rows, and grid_layers with random blocked cells;
- segment_ground and grid_layers of each `--map` bundle on its own terrain grid.

Usage:
  git show REV:terra/graph/ground.py > /tmp/ground_before.py
  python benchmarks/ground_equality.py --before /tmp/ground_before.py [--map BUNDLE ...]
Prints each difference and the timings, and exits 1 when any output differs.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from terra.bundle import Bundle
from terra.graph import ground as new
from terra.graph import pipeline
from terra.graph.config import BuildConfig
from terra.graph.grid import GridFrame, TerrainGrid
from terra.graph.ground import as_ground_terrain, has_terrain_votes
from terra.mapping.storage import load_map

SCANS = Path(__file__).resolve().parents[1] / "tests" / "data" / "semantickitti" / "sequences"
FIELDS = ("cells", "height", "gradient", "step", "roughness", "near_obstacle")
differences: list[str] = []


def same(name: str, a: Any, b: Any) -> None:
    """Records `name` as a difference unless arrays a and b are equal in shape, dtype and bits."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind == "f"):
        return
    differences.append(name)
    detail = f"{a.shape} {a.dtype} vs {b.shape} {b.dtype}"
    if a.shape == b.shape and a.dtype.kind == "f":
        gap = np.abs(a.astype(np.float64) - b.astype(np.float64))
        detail += f", {int(np.sum(gap > 0))} values differ, at most {np.nanmax(gap, initial=0.0):.3g}"
    print(f"DIFFERS {name}: {detail}")


def same_layers(name: str, a: Any, b: Any) -> None:
    """Every field of two GroundLayers."""
    for field in FIELDS:
        x, y = getattr(a, field), getattr(b, field)
        if x is None or y is None:
            if (x is None) != (y is None):
                differences.append(f"{name}.{field}")
                print(f"DIFFERS {name}.{field}: None on one side")
            continue
        same(f"{name}.{field}", x, y)


def load_before(path: Path) -> ModuleType:
    """The ground module at `path`, imported under its own name beside terra.graph.ground."""
    spec = importlib.util.spec_from_file_location("ground_before", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["ground_before"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def small_grids(old: ModuleType, rng: np.random.Generator, trials: int = 20) -> None:
    """axis_step, despike and plane_fit on random grids, heights in metres, up to 60 % holes."""
    for trial in range(trials):
        H, W = (int(v) for v in rng.integers(1, 40, 2))
        h = rng.normal(0, 0.1, (H, W)) + np.where(rng.random((H, W)) < 0.3, 0.15, 0.0)
        h[rng.random((H, W)) < rng.random() * 0.6] = np.nan
        rise = rng.normal(0, 0.05, (H, W))
        rise[rng.random((H, W)) < 0.2] = np.nan
        for axis in (0, 1):
            same(f"axis_step {trial} {axis}", old.axis_step(h, axis), new.axis_step(h, axis))
            same(f"axis_step rise {trial} {axis}", old.axis_step(h, axis, rise), new.axis_step(h, axis, rise))
        same(f"despike {trial}", old.despike(h), new.despike(h))
        offset = (rng.uniform(-0.2, 0.2, (H, W)), rng.uniform(-0.2, 0.2, (H, W)))
        for centres in (None, offset):
            for reference in (None, 0.05):
                a, b = old.plane_fit(h, 0.4, centres, reference), new.plane_fit(h, 0.4, centres, reference)
                same(f"plane_fit height {trial}", a[0], b[0])
                same(f"plane_fit gradient {trial}", a[1], b[1])


def frame_of(points: np.ndarray, cell: float) -> GridFrame:
    """A frame around the points (n, 3+) (metres) with two empty cells on each side."""
    lo = np.floor(points[:, :2].min(axis=0) / cell) * cell - 2 * cell
    cols, rows = (int(v) + 4 for v in np.ceil((points[:, :2].max(axis=0) - lo) / cell))
    return GridFrame((float(lo[0]), float(lo[1])), (rows, cols), cell)


def blocked_grid(frame: GridFrame, rng: np.random.Generator) -> TerrainGrid:
    """A terrain grid on `frame` with random blocked rectangles of 1-4 cells a side."""
    H, W = frame.shape
    blocked = np.zeros(frame.shape, dtype=bool)
    for _ in range(max(3, H * W // 400)):
        r, c = int(rng.integers(0, H)), int(rng.integers(0, W))
        blocked[r : r + int(rng.integers(1, 5)), c : c + int(rng.integers(1, 5))] = True
    label, height = np.zeros(frame.shape, np.int16), np.zeros(frame.shape, np.float32)
    return TerrainGrid(label, height, blocked, np.asarray(frame.origin), frame.cell_size, frame.offset)


def real_scans(old: ModuleType, rng: np.random.Generator) -> None:
    """Segmentation and layers of the SemanticKITTI scans kept under tests/data."""
    section = BuildConfig().ground
    for scan in sorted(SCANS.glob("*/velodyne/*.bin")):
        name = f"{scan.parent.parent.name}/{scan.stem}"
        points = np.fromfile(scan, dtype=np.float32).reshape(-1, 4)[:, :3]
        ground = old.points_ground(points, section)
        same(f"segment {name}", ground, new.points_ground(points, section))
        for cell in (0.4, 0.25):
            frame = frame_of(points, cell)
            for band in (new.BAND_CELLS, 2000):
                a, b = old.ground_layers(points[ground], frame, band), new.ground_layers(points[ground], frame, band)
                same_layers(f"ground_layers {name} {cell} m band {band}", a, b)
            grid = blocked_grid(frame, rng)
            same_layers(
                f"grid_layers {name} {cell} m",
                old.grid_layers(points, ground, grid),
                new.grid_layers(points, ground, grid),
            )


def timed(function: Any, *args: Any) -> tuple[Any, float]:
    """function(*args) and its CPU seconds."""
    start = time.process_time()
    out = function(*args)
    return out, time.process_time() - start


def map_bundle(old: ModuleType, path: Path) -> None:
    """Segmentation and layers of a map bundle on its terrain grid (the build's defaults)."""
    msm = load_map(Bundle(path))
    config = BuildConfig()
    ground, t_old = timed(old.points_ground, msm.points, config.ground)
    mine, t_new = timed(new.points_ground, msm.points, config.ground)
    same(f"segment {path}", ground, mine)
    if not has_terrain_votes(msm):  # a LiDAR-only map: its grid is built on its ground (as terra build)
        msm = as_ground_terrain(msm, mine)
    names, terrains = pipeline.terrains_to_build(msm, config)
    point_terrain = pipeline._point_terrain(msm, names, terrains, config)  # pyright: ignore[reportPrivateUsage]
    grid = pipeline.terrain_grid(msm.points, point_terrain, config)
    a, l_old = timed(old.grid_layers, msm.points, ground, grid)
    b, l_new = timed(new.grid_layers, msm.points, ground, grid)
    same_layers(f"grid_layers {path}", a, b)
    print(
        f"{path}: {len(msm.points)} points, grid {grid.shape}, {len(b.cells)} observed cells; CPU s before / "
        f"now: segmentation {t_old:.3f} / {t_new:.3f}, layers {l_old:.3f} / {l_new:.3f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--before", type=Path, required=True, help="terra/graph/ground.py of another commit")
    parser.add_argument("--map", type=Path, action="append", default=[], help="a map bundle (repeatable)")
    args = parser.parse_args()
    old, rng = load_before(args.before), np.random.default_rng(0)
    small_grids(old, rng)
    real_scans(old, rng)
    for path in args.map:
        map_bundle(old, path)
    print("all outputs equal" if not differences else f"{len(differences)} outputs differ")
    sys.exit(1 if differences else 0)


if __name__ == "__main__":
    main()
