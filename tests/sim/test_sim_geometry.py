"""Curbs, curb cuts, ramps beside stairs and the steep hill of `sim.geometry`, and the per-cell
truth of steps and slopes, against hand-worked geometry."""

import numpy as np
import pytest

from terra.datasets.ground_truth import NEIGHBOURS, cell_slope, neighbour_geometry, neighbour_side_slope
from terra.sim.classes import class_id
from terra.sim.config import SimConfig
from terra.sim.presets import generate_world

RES = 0.25
GRADE = np.degrees(np.arctan(1 / 12))  # 4.76 degrees: the curb cuts' and ramps' design slope


def test_truth_of_a_curb_a_ramp_and_stairs_on_hand_rasters():
    curb = np.zeros((3, 8))
    curb[:, 4:] = 0.15
    step, slope = neighbour_geometry(curb, RES)
    assert NEIGHBOURS[0] == (0, 1) and NEIGHBOURS[2] == (0, -1)
    np.testing.assert_allclose(step[1, :, 0], [0, 0, 0, 0.15, 0, 0, 0, np.nan])  # +x: from cell 3 to 4
    np.testing.assert_allclose(step[1, :, 2], [np.nan, 0, 0, 0, 0.15, 0, 0, 0])  # -x: the same move back
    np.testing.assert_allclose(slope[1, :7, 0], 0.0)
    assert np.all(np.isnan(step[0, :, 3])) and np.all(step[1, :, 1] == 0.0)  # -y past the edge; flat along y
    ramp = np.tile(np.arange(8) * RES / 12, (3, 1)).T  # 1:12 climbing along +y (rows)
    step, slope = neighbour_geometry(ramp, RES)
    np.testing.assert_allclose(step[:7, 1, 1], 0.0, atol=1e-12)
    np.testing.assert_allclose(slope[:7, 1, 1], GRADE)
    np.testing.assert_allclose(cell_slope(ramp, RES), GRADE)
    stairs = np.array([0.0, 0.0, 0.15, 0.15, 0.30, 0.45, 0.45, 0.45])[None, :].repeat(2, axis=0)
    step, slope = neighbour_geometry(stairs, RES)
    np.testing.assert_allclose(step[0, :7, 0], [0, 0.15, 0, 0.15, 0.15, 0, 0])
    np.testing.assert_allclose(slope[0, :7, 0], 0.0)


def test_side_slope_is_the_tilt_across_each_move_and_no_curb_beside_it():
    rows, cols = np.mgrid[0:5, 0:6].astype(np.float64)
    tilt = np.radians(10.0)
    side_hill = rows * RES * np.tan(tilt)  # climbs along +y only
    side = neighbour_side_slope(neighbour_geometry(side_hill, RES)[1])
    np.testing.assert_allclose(side[:, :5, 0], 10.0)  # a contour along x tips the robot 10 degrees
    np.testing.assert_allclose(side[:, 1:, 2], 10.0)
    np.testing.assert_allclose(side[:4, :, 1], 0.0, atol=1e-9)  # straight up the hill: no tilt
    assert np.all(np.isnan(side[:, 5, 0])) and np.all(np.isnan(side[0, :, 3]))  # off the raster
    oblique = (rows + cols) * RES * np.tan(tilt) / np.sqrt(2)  # the same 10 degrees, 45 degrees off the axes
    side = neighbour_side_slope(neighbour_geometry(oblique, RES)[1])
    np.testing.assert_allclose(side[:, :5, 0], np.degrees(np.arctan(np.tan(tilt) / np.sqrt(2))))
    curb = np.where(rows >= 3, 0.15, 0.0)  # a curb along x between rows 2 and 3
    side = neighbour_side_slope(neighbour_geometry(curb, RES)[1])
    np.testing.assert_allclose(side[:, :5, 0], 0.0)  # along the curb's foot and top: level


@pytest.fixture(scope="module")
def flat_world():
    """The tiny site with every feature on and no smooth relief, so every height is hand-checkable."""
    return generate_world("tiny", 0, SimConfig.model_validate({"ground_relief_m": 0.0, "geometry": {}}))


def test_geometry_is_off_unless_asked():
    world = generate_world("tiny", 0)
    assert world.ground.steps is None
    xs, ys = world.terrain.cell_centres()
    gx, gy = np.meshgrid(xs, ys)
    smooth = world.ground.height(np.stack([gx.ravel(), gy.ravel()], 1)).reshape(gx.shape).astype(np.float32)
    raster = world.ground_truth().terrain
    assert raster is not None
    np.testing.assert_array_equal(raster.ground_height, smooth)


def test_sidewalk_stands_a_curb_above_the_road(flat_world):
    raster = flat_world.ground_truth().terrain
    classes, height = raster.classes, raster.ground_height.astype(np.float64)
    st = flat_world.ground.steps
    road = classes == class_id("asphalt")
    walk = (classes == class_id("sidewalk")) & ~st.curb_cut & ~st.ramp & ~st.lawn & ~st.hill
    np.testing.assert_allclose(height[road], 0.0, atol=1e-6)
    np.testing.assert_allclose(height[walk], 0.15, atol=1e-6)
    # The tiny site's sidewalk (y 21-24) meets the parking lot (y < 21) at x 6-54: a 15 cm step there.
    step, _ = neighbour_geometry(height, RES)
    r = int((20.875 - raster.origin[1]) / RES)  # the lot's last row
    cols = np.flatnonzero(~st.curb_cut[r + 1] & road[r] & walk[r + 1])
    assert cols.size > 100
    np.testing.assert_allclose(step[r, cols, 1], 0.15, atol=1e-6)


def test_curb_cut_climbs_at_its_design_slope(flat_world):
    raster = flat_world.ground_truth().terrain
    st = flat_world.ground.steps
    step, slope = neighbour_geometry(raster.ground_height, RES)
    cut = st.curb_cut
    assert cut.sum() > 100
    assert np.nanmax(slope[cut]) == pytest.approx(GRADE, abs=0.05)
    # Along the cut's centre line every move is legal for a wheelchair (5 cm, 8 degrees): the walkway
    # from the lot at (7, 12) up to the sidewalk at (7, 22.5) runs along column x = 7.
    c = int((7.0 - raster.origin[0]) / RES)
    rows = np.arange(int(19.0 / RES), int(23.0 / RES))
    assert np.nanmax(step[rows, c, 1]) < 0.03 and np.nanmax(slope[rows, c, 1]) < GRADE + 0.05
    assert raster.ground_height[rows[-1], c] == pytest.approx(0.15, abs=1e-6)


def test_hill_is_steeper_than_a_wheelchair_and_lawns_are_not(flat_world):
    raster = flat_world.ground_truth().terrain
    st = flat_world.ground.steps
    slope = cell_slope(raster.ground_height, RES)
    assert st.hill.any() and st.lawn.any()
    assert 13.0 < slope[st.hill].max() <= 14.05  # the raised cosine's steepest flank: 14 degrees
    assert 3.0 < slope[st.lawn & ~st.hill].max() <= 4.05


def test_stairs_are_steps_and_the_ramp_beside_them_is_not(flat_world):
    raster = flat_world.ground_truth().terrain
    st = flat_world.ground.steps
    height = raster.ground_height.astype(np.float64)
    step, slope = neighbour_geometry(height, RES)
    xs, ys = flat_world.terrain.cell_centres()
    gx, gy = np.meshgrid(xs, ys)
    stairs = np.isfinite(flat_world.stairs_tops(gx, gy))
    assert stairs.sum() > 20
    up_flight = stairs[:-1] & stairs[1:]  # moves toward the door (+y) between two cells of the flight
    risers = step[:-1, :, 1][up_flight]
    assert np.all((np.abs(risers) < 1e-6) | (np.abs(risers - 0.15) < 1e-6)) and (risers > 0.1).sum() >= 2 * 16
    top = 0.15 + 0.45  # the plaza's curb plus three risers
    assert np.nanmax(height[stairs]) == pytest.approx(top, abs=1e-6)
    assert np.nanmax(height[st.ramp]) == pytest.approx(top, abs=RES / 12 + 1e-6)
    assert np.nanmax(slope[st.ramp]) == pytest.approx(GRADE, abs=0.05)
    stairs_box = next(o for o in flat_world.objects if o.class_name == "stairs")
    assert stairs_box.center[2] - stairs_box.size[2] / 2 == pytest.approx(0.15, abs=1e-6)  # on the raised plaza


def test_a_wheelchair_reaches_the_sidewalk_from_the_lot_only_through_a_curb_cut(flat_world):
    """On the true raster, the shortest legal route (5 cm steps, 8 degrees) from the parking lot to
    the sidewalk leaves the asphalt only inside a curb cut; with the cuts raised back to full curb
    height no legal route is left (the lot is ringed by curbs)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    raster = flat_world.ground_truth().terrain
    st = flat_world.ground.steps
    h, w = raster.classes.shape
    road = raster.classes == class_id("asphalt")
    start = (int(12.0 / RES), int(30.0 / RES))  # (row, col) of (30, 12) in the lot
    goal = (int(22.5 / RES), int(30.0 / RES))  # (30, 22.5) on the sidewalk, 1.5 m past the curb

    def route(height: np.ndarray) -> np.ndarray | None:
        step, slope = neighbour_geometry(height, RES)
        index = np.arange(h * w).reshape(h, w)
        src, dst = [], []
        for k, (dr, dc) in enumerate(NEIGHBOURS[:2]):
            ok = (step[: h - dr, : w - dc, k] <= 0.05) & (slope[: h - dr, : w - dc, k] <= 8.0)
            src.append(index[: h - dr, : w - dc][ok])
            dst.append(index[dr:, dc:][ok])
        s, d = np.concatenate(src), np.concatenate(dst)
        graph = coo_matrix((np.ones(len(s)), (s, d)), shape=(h * w, h * w)).tocsr()
        dist, pred = dijkstra(graph, directed=False, indices=index[start], return_predecessors=True)
        if not np.isfinite(dist[index[goal]]):
            return None
        path = [index[goal]]
        while path[-1] != index[start]:
            path.append(pred[path[-1]])
        return np.array(path[::-1])

    height = raster.ground_height.astype(np.float64)
    path = route(height)
    assert path is not None
    on_road = road.ravel()[path]
    leaves = path[1:][on_road[:-1] & ~on_road[1:]]  # first raised cell after a road cell
    assert len(leaves) >= 1 and np.all(st.curb_cut.ravel()[leaves])
    assert route(np.where(st.curb_cut, height + (0.15 - height) * ~road, height)) is None


def test_terra_sim_geometry_flag_raises_the_curbs(tmp_path):
    """`terra sim --geometry` turns the geometry on with its defaults: in the written ground truth, the
    typical height jump from an asphalt cell to the cell of another terrain beside it (a verge, a
    walk) is the 15 cm curb (cuts and the smooth hills aside); without the flag there is none."""
    from terra.cli import run
    from terra.datasets import open_dataset

    def curb_jumps(folder):
        truth = open_dataset(folder).ground_truth()  # pyright: ignore[reportAttributeAccessIssue]  # a sim folder's
        raster = truth.terrain
        road = raster.classes == class_id("asphalt")
        h = raster.ground_height.astype(np.float64)
        jumps = []
        for a, b, ha, hb in ((road[:, :-1], road[:, 1:], h[:, :-1], h[:, 1:]), (road[:-1], road[1:], h[:-1], h[1:])):
            jumps += [(hb - ha)[a & ~b], (ha - hb)[~a & b]]  # up from the road onto the other side
        return np.concatenate(jumps)

    for flag, expected in ((["--geometry"], 0.15), ([], 0.0)):
        out = tmp_path / f"sim{len(flag)}"
        assert run(["sim", "--preset", "tiny", "--max-frames", "1", "--out", str(out), "-q", *flag]) == 0
        jumps = curb_jumps(out)
        assert len(jumps) > 20 and np.median(jumps) == pytest.approx(expected, abs=0.02)
