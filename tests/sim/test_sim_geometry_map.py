"""One map of a simulated world with curbs (`sim.geometry`), built at small scale: the ground
layers read the curb and the curb cut as the simulator built them, and no wheelchair plan crosses
a true step or slope beyond the profile's limits where the map observed the ground."""

from pathlib import Path

import numpy as np
import pytest

FRAMES = 20  # the tiny site's first 80 m: along the parking lot, up its curb cut onto the sidewalk


@pytest.fixture(scope="module")
def curb_map(tmp_path_factory) -> tuple[Path, Path]:
    from terra.cli import run

    root = tmp_path_factory.mktemp("curbs")
    config = root / "curbs.yaml"
    config.write_text(f"sim:\n  ground_relief_m: 0.3\n  route: {{max_frames: {FRAMES}}}\n  geometry: {{}}\n")
    assert run(["sim", "--preset", "tiny", "-c", str(config), "--out", str(root / "drive")]) == 0
    assert run(["map", str(root / "drive"), "-o", str(root / "curbs.terra")]) == 0
    assert run(["build", str(root / "curbs.terra")]) == 0
    return config, root / "curbs.terra"


def test_ground_layers_read_the_curb_and_the_cut(curb_map):
    from terra.bundle import Bundle
    from terra.graph.pipeline import build_scene_graph
    from terra.mapping.storage import load_map

    layers = build_scene_graph(load_map(Bundle(curb_map[1]), max_ids=False)).ground
    assert layers is not None

    def steps(points: list[list[float]]) -> np.ndarray:
        k = layers.lookup(np.array(points))
        return layers.step[k[k >= 0]].astype(np.float64)

    # The lot's west curb (x = 6 m, no car beside it): 15 cm; the curb cut it meets at (7, 21): ramps.
    curb = steps([[6.0, y] for y in np.arange(6.0, 18.0, 0.4)])
    cut = steps([[7.0, y] for y in np.arange(19.6, 22.8, 0.4)])
    assert len(curb) >= 20 and np.nanmedian(curb) == pytest.approx(0.15, abs=0.03)
    assert len(cut) >= 4 and np.nanmax(cut) < 0.05


def test_wheelchair_plans_stay_within_its_limits_on_the_true_ground(curb_map):
    """Every plan keeps to 8 degrees on the true ground, along and across its moves; a true step
    above 5 cm is crossed only where the map holds no ground one cell beyond it on a side (the
    lot's south curb, which the parked cars hide from the drive: a step is unknown there and constrains nothing,
    terra.graph.ground)."""
    from terra.bundle import Bundle
    from terra.config import TerraConfig
    from terra.datasets.ground_truth import neighbour_side_slope, path_geometry
    from terra.errors import NoPathError
    from terra.graph.pipeline import build_scene_graph
    from terra.graph.storage import load_scene_graph
    from terra.mapping.storage import load_map
    from terra.sim.presets import generate_world
    from terra.tasks.planning import CostGraph, TerrainCosts, plan_on
    from terra.tasks.robot import ROBOTS

    chair = ROBOTS["wheelchair"]
    raster = generate_world("tiny", 0, TerraConfig.read(curb_map[0]).sim).ground_truth().terrain
    assert raster is not None
    step, slope = raster.neighbour_geometry()
    side = neighbour_side_slope(slope)
    graph = load_scene_graph(Bundle(curb_map[1]))
    layers = build_scene_graph(load_map(Bundle(curb_map[1]), max_ids=False)).ground
    assert layers is not None
    cost_graph = CostGraph.build(graph, TerrainCosts.from_preferences(graph.terrain_classes), chair)
    n = len(graph.places)
    planned = unobserved = 0
    for a, b in np.random.default_rng(0).integers(0, n, size=(60, 2)):
        if a == b:
            continue
        try:
            plan = plan_on(graph, cost_graph, int(a), int(b))
        except NoPathError:
            continue
        planned += 1
        found = path_geometry(raster, step, slope, plan.waypoints, side)
        assert found.slope <= chair.max_slope_up and found.side_slope <= chair.cross_limit
        if found.step > chair.max_step:
            cells = np.array(found.step_cells, dtype=np.float64)[:, ::-1]  # (col, row) of both cells
            low, high = raster.origin + (cells + 0.5) * raster.resolution
            across = (high - low) / np.linalg.norm(high - low) * layers.cell_size  # one map cell on
            sides = np.array([low - across, high + across])
            assert np.any(layers.lookup(sides) < 0), (found.step, low, high)
            unobserved += 1
    assert planned >= 20 and unobserved < planned / 2
