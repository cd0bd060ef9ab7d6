"""Ray casting against hand-placed shapes: hit distances, normals and labels worked out by hand."""

import numpy as np
import pytest

from terra.geometry import make_pose
from terra.sim.config import LidarConfig
from terra.sim.heightfield import Heightfield
from terra.sim.primitives import BOX, CYLINDER, ELLIPSOID, Primitives
from terra.sim.raycast import cast
from terra.sim.sensors import Lidar
from terra.sim.world import TerrainGrid, World

COLUMNS = 360  # one column per degree of azimuth
H = 1.8  # LiDAR height above the flat ground


def make_world(rows, ground=None):
    ground = ground or Heightfield(np.zeros(1), np.zeros((1, 2)), np.zeros(1), 0.0)
    terrain = TerrainGrid(np.full((4, 4), 2, np.uint8), np.array([-200.0, -200.0]), 100.0)
    return World(
        "test", 0, (-200, -200, 200, 200), ground, terrain, Primitives.from_rows(rows), [], [], np.zeros((2, 2))
    )


@pytest.fixture(scope="module")
def scene():
    rows = [
        # kind, centre, half sizes, yaw, class, instance, colour
        (BOX, (10.0, 0.0, 1.0), (0.5, 2.0, 1.0), 0.0, 20, 1, (1, 2, 3)),
        (BOX, (0.0, 10.0, 1.0), (0.5, 3.0, 1.0), np.radians(30.0), 26, 2, (1, 2, 3)),
        (CYLINDER, (-10.0, 0.0, 1.5), (0.5, 0.5, 1.5), 0.0, 24, 3, (1, 2, 3)),
        (ELLIPSOID, (0.0, -10.0, 1.8), (1.0, 2.0, 1.0), 0.0, 11, 4, (1, 2, 3)),
        (
            BOX,
            (89.5 * np.cos(np.radians(135)), 89.5 * np.sin(np.radians(135)), 2.0),
            (1.0, 1.0, 2.0),
            np.radians(135),
            10,
            5,
            (1, 2, 3),
        ),
    ]
    lidar = Lidar(LidarConfig(beams=3, columns=COLUMNS, vertical_fov_deg=(-10.0, 10.0), max_range=100.0))
    hits = cast(make_world(rows), make_pose(np.eye(3), np.array([0.0, 0.0, H])), lidar.tiles, 100.0)
    return hits


def ray(row, azimuth_deg):
    return row * COLUMNS + int(azimuth_deg) % COLUMNS


def test_box_face_range_and_normal(scene):
    r = ray(1, 0)  # horizontal, along +x
    assert scene.t[r] == pytest.approx(9.5, abs=1e-9)
    assert scene.class_id[r] == 20 and scene.instance_id[r] == 1
    np.testing.assert_allclose(scene.normal[r], [-1.0, 0.0, 0.0], atol=1e-12)
    r = ray(1, 5)  # oblique on the same face: x = 9.5 at y = 9.5 tan 5 deg < 2 m
    assert scene.t[r] == pytest.approx(9.5 / np.cos(np.radians(5.0)), abs=1e-9)


def test_yawed_box_entry_face(scene):
    # Box yawed 30 deg at (0, 10): along +y the ray meets the plane n.(p - c) = -0.5 with
    # n = (cos 30, sin 30) at y = 10 - 0.5 / sin 30 = 9; there the box-frame y is -0.87 (inside 3).
    r = ray(1, 90)
    assert scene.t[r] == pytest.approx(9.0, abs=1e-9)
    assert scene.instance_id[r] == 2
    np.testing.assert_allclose(scene.normal[r], [-np.cos(np.radians(30)), -np.sin(np.radians(30)), 0.0], atol=1e-12)


def test_cylinder_and_ellipsoid(scene):
    r = ray(1, 180)
    assert scene.t[r] == pytest.approx(9.5, abs=1e-9)
    assert scene.class_id[r] == 24
    np.testing.assert_allclose(scene.normal[r], [1.0, 0.0, 0.0], atol=1e-12)
    r = ray(1, 270)  # ellipsoid semi-axis 2 along y: surface at y = -8
    assert scene.t[r] == pytest.approx(8.0, abs=1e-9)
    np.testing.assert_allclose(scene.normal[r], [0.0, 1.0, 0.0], atol=1e-12)


def test_far_box_near_max_range(scene):
    r = ray(1, 135)  # box face 1 m before its centre at 89.5 m
    assert scene.t[r] == pytest.approx(88.5, abs=1e-9)
    assert scene.instance_id[r] == 5


def test_flat_ground_and_sky(scene):
    r = ray(2, 45)  # 10 deg down, nothing in the way
    assert scene.t[r] == pytest.approx(H / np.sin(np.radians(10.0)), abs=2e-3)
    assert scene.class_id[r] == 2 and scene.instance_id[r] == 0  # terrain: grass, no instance
    np.testing.assert_allclose(scene.normal[r], [0.0, 0.0, 1.0], atol=1e-12)
    up = np.arange(COLUMNS)  # 10 deg up: every shape is too low to be hit
    assert np.all(np.isinf(scene.t[up])) and np.all(scene.class_id[up] == 0)


def test_sloped_ground_hits_lie_on_the_surface():
    ground = Heightfield(np.array([1.5]), np.array([[2 * np.pi / 60.0, 0.0]]), np.array([0.3]), 0.0)
    lidar = Lidar(LidarConfig(beams=16, columns=180, vertical_fov_deg=(-30.0, 5.0), max_range=80.0))
    origin = np.array([3.0, -2.0, float(ground.height(np.array([[3.0, -2.0]]))[0]) + H])
    hits = cast(make_world([], ground), make_pose(np.eye(3), origin), lidar.tiles, 80.0)
    p = origin + hits.t[hits.hit, None] * hits.directions[hits.hit]
    assert hits.hit.sum() > 16 * 180 * 0.5
    np.testing.assert_allclose(p[:, 2], ground.height(p[:, :2]), atol=2e-3)
    np.testing.assert_allclose(hits.normal[hits.hit], ground.normal(p[:, :2]), atol=1e-6)


def test_range_noise_statistics():
    rows = [(BOX, (20.0, 0.0, 5.0), (0.5, 50.0, 10.0), 0.0, 10, 1, (1, 2, 3))]  # a wall across +x
    cfg = LidarConfig(beams=8, columns=720, vertical_fov_deg=(-5.0, 5.0), range_noise_m=0.05)
    lidar = Lidar(cfg)
    T = make_pose(np.eye(3), np.array([0.0, 0.0, H]))
    exact = Lidar(cfg.model_copy(update={"range_noise_m": 0.0})).render(make_world(rows), T)
    noisy = lidar.render(make_world(rows), T, np.random.default_rng(0))
    assert noisy["points"].shape == exact["points"].shape
    wall = exact["labels"] == 10
    err = np.linalg.norm(noisy["points"][wall], axis=1) - np.linalg.norm(exact["points"][wall], axis=1)
    assert wall.sum() > 500
    assert abs(err.mean()) < 0.01 and err.std() == pytest.approx(0.05, rel=0.15)


def test_tile_culling_keeps_every_shape_a_ray_of_the_tile_can_hit():
    """The compiled culling against brute force: every (tile, shape) pair where some ray of the tile
    passes within the shape's bounding sphere (its cone, worked out directly) is a candidate, and
    the candidates are the pairs of the cone-meets-cone test written with arccos, in tile-major order."""
    from terra.sim.kernels import cull_kernel
    from terra.sim.raycast import RayTiles

    rng = np.random.default_rng(4)
    lidar = Lidar(LidarConfig(beams=8, columns=64, vertical_fov_deg=(-20.0, 20.0)))
    tiles = lidar.tiles
    centre = rng.uniform(-40, 40, (300, 3))
    radius = rng.uniform(0.2, 6.0, 300)
    dist = np.linalg.norm(centre, axis=1)
    u = centre / dist[:, None]
    ang = np.where(dist <= radius, np.pi, np.arcsin(np.clip(radius / dist, 0, 1)))
    ptr, shapes = cull_kernel(
        tiles.axis, tiles.cos_half, tiles.sin_half, tiles.half_angle, u, np.cos(ang), np.sin(ang), ang
    )
    pairs = {(g, int(p)) for g in range(len(ptr) - 1) for p in shapes[ptr[g] : ptr[g + 1]]}
    assert all(np.all(np.diff(shapes[ptr[g] : ptr[g + 1]]) > 0) for g in range(len(ptr) - 1))
    # Reference 1: the cone test with explicit angles.
    angle = np.arccos(np.clip(tiles.axis @ u.T, -1, 1))
    g_ref, p_ref = np.nonzero(angle <= tiles.half_angle[:, None] + ang[None, :])
    assert pairs == set(zip(g_ref.tolist(), p_ref.tolist()))
    # Reference 2: rays that pass within a shape's bounding sphere belong to candidate tiles.
    ray_angle = np.arccos(np.clip(tiles.directions @ u.T, -1, 1))  # (N, P)
    for g, rays in enumerate(tiles.rays):
        seen = np.flatnonzero((ray_angle[rays] <= ang[None, :]).any(axis=0))
        assert {(g, int(p)) for p in seen} <= pairs
    assert isinstance(tiles, RayTiles) and len(pairs) < len(tiles.rays) * len(u)  # culling culls
