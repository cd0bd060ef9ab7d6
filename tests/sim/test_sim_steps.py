"""The ray caster on a ground with step offsets (terra.sim.heightfield.StepRaster): a hand-made
curb's LiDAR returns, walls and tops, against the geometry worked out by hand."""

import numpy as np
import pytest

from terra.geometry import make_pose
from terra.sim.config import LidarConfig
from terra.sim.heightfield import Heightfield, StepRaster
from terra.sim.raycast import cast
from terra.sim.sensors import Lidar
from terra.sim.world import TerrainGrid, World

SIDEWALK, ASPHALT = 1, 3
CURB = 0.15  # metres: the sidewalk east of x = 5 m stands this much above the road
H = 1.8  # LiDAR above the road


def curb_world(ground: Heightfield | None = None) -> World:
    """Road (asphalt) for x < 5 m, a raised sidewalk for x >= 5 m, on 0.25 m cells over [-20, 20) m."""
    ground = ground or Heightfield(np.zeros(1), np.zeros((1, 2)), np.zeros(1), 0.0)
    res, origin = 0.25, np.array([-20.0, -20.0])
    xs = origin[0] + (np.arange(160) + 0.5) * res
    raised = np.broadcast_to(xs >= 5.0, (160, 160))
    offsets = np.where(raised, CURB, 0.0)
    none = np.zeros((160, 160), bool)
    ground.steps = StepRaster(offsets, origin, res, none, none, none, none)
    terrain = TerrainGrid(np.where(raised, SIDEWALK, ASPHALT).astype(np.uint8), origin, res)
    from terra.sim.primitives import Primitives

    return World("curb", 0, (-20, -20, 20, 20), ground, terrain, Primitives.empty(), [], [], np.zeros((2, 2)))


@pytest.fixture(scope="module")
def curb_hits():
    # Beams (rows top-down) at -10, -14.5 and -19 degrees, one column per degree.
    lidar = Lidar(LidarConfig(beams=3, columns=360, vertical_fov_deg=(-19.0, -10.0), max_range=60.0))
    world = curb_world()
    return world, cast(world, make_pose(np.eye(3), np.array([0.0, 0.0, H])), lidar.tiles, 60.0)


def point(hits, row: int, azimuth: int) -> np.ndarray:
    r = row * 360 + azimuth % 360
    return np.array([0.0, 0.0, H]) + hits.t[r] * hits.directions[r]


def test_raised_sidewalk_returns_sit_at_the_curb_height(curb_hits):
    world, hits = curb_hits
    for row, deg in ((0, 10.0), (1, 14.5)):  # both pass over the curb's edge (above 0.15 m at x = 5)
        p = point(hits, row, 0)
        assert p[2] == pytest.approx(CURB, abs=2e-3)
        assert p[0] == pytest.approx((H - CURB) / np.tan(np.radians(deg)), abs=0.01)
        assert hits.class_id[row * 360] == SIDEWALK
        np.testing.assert_allclose(hits.normal[row * 360], [0.0, 0.0, 1.0], atol=1e-12)
    # Looking west the same beams meet the road itself at z = 0.
    p = point(hits, 0, 180)
    assert p[2] == pytest.approx(0.0, abs=2e-3) and p[0] == pytest.approx(-H / np.tan(np.radians(10.0)), abs=0.01)
    assert hits.class_id[180] == ASPHALT


def test_the_curb_face_is_a_vertical_wall(curb_hits):
    _, hits = curb_hits
    # At -19 deg the ray is 1.8 - 5 tan 19 = 0.078 m above the road at x = 5: below the curb's top.
    p = point(hits, 2, 0)
    assert p[0] == pytest.approx(5.0, abs=1e-5)
    assert p[2] == pytest.approx(H - 5.0 * np.tan(np.radians(19.0)), abs=1e-5)
    np.testing.assert_allclose(hits.normal[2 * 360], [-1.0, 0.0, 0.0], atol=1e-12)


def test_stepped_sloped_ground_hits_lie_on_a_top_or_a_wall():
    """On a sloped field with the curb, every hit is on a cell's top (height(p)) or on a wall
    between two cells, at a height between their two grounds."""
    ground = Heightfield(np.array([1.5]), np.array([[2 * np.pi / 60.0, 0.0]]), np.array([0.3]), 0.0)
    world = curb_world(ground)
    lidar = Lidar(LidarConfig(beams=24, columns=180, vertical_fov_deg=(-40.0, 5.0), max_range=60.0))
    origin = np.array([3.0, -2.0, float(ground.height(np.array([[3.0, -2.0]]))[0]) + H])
    hits = cast(world, make_pose(np.eye(3), origin), lidar.tiles, 60.0)
    p = origin + hits.t[hits.hit, None] * hits.directions[hits.hit]
    n = hits.normal[hits.hit]
    wall = np.abs(n[:, 2]) < 1e-12
    assert hits.hit.sum() > 24 * 180 * 0.5 and 0 < wall.sum() < 0.1 * len(p)
    np.testing.assert_allclose(p[~wall, 2], ground.height(p[~wall, :2]), atol=2e-3)
    np.testing.assert_allclose(p[wall, 0], 5.0, atol=1e-4)  # the only wall is the curb at x = 5 m
    lo = ground.height(p[wall, :2] - [0.01, 0.0])
    assert np.all((p[wall, 2] >= lo - 1e-3) & (p[wall, 2] <= lo + CURB + 1e-3))
