"""Projection of scans into images: pinhole, distortion, extrinsics, bounds and the z-buffer."""

import numpy as np

from terra.geometry import CameraCalibration, make_pose
from terra.mapping.projection import visible_points
from tests.mapping.fixtures import box_camera

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])


def test_pinhole_pixels_hand_computed():
    cam = CameraCalibration("c", 640, 480, K)
    pts = np.array(
        [
            [1.0, -0.5, 10.0],  # u = 500 * 0.1 + 320 = 370, v = 500 * -0.05 + 240 = 215
            [0.0081, 0.0, 10.0],  # u = 320.405 -> column 320
            [0.0091, 0.0, 10.0],  # u = 320.455 -> column 320; distinct v below keeps both
            [0.0, 0.0, -5.0],  # behind the camera
            [100.0, 0.0, 1.0],  # right of the image
            [-6.4, -4.81, 10.0],  # u = 0, v = -0.5 -> just outside the top edge
            [-6.4, -4.8, 10.0],  # u = 0, v = 0 -> top-left pixel
        ]
    )
    pts[2, 1] = 0.5  # v = 265
    vis = visible_points(pts, cam)
    assert vis.index.tolist() == [0, 1, 2, 6]
    assert vis.cols.tolist() == [370, 320, 320, 0]
    assert vis.rows.tolist() == [215, 240, 265, 0]
    np.testing.assert_allclose(vis.distance[0], np.sqrt(1 + 0.25 + 100))


def test_distortion_and_extrinsics_hand_computed():
    dist = np.array([0.1, -0.05, 0.001, 0.002, 0.0])
    # Camera 2 m in front of the LiDAR along its z axis, axes aligned: p_cam = p_lidar - (0, 0, 2).
    cam = CameraCalibration(
        "c",
        640,
        480,
        np.array([[400, 0, 320], [0, 400, 240], [0, 0, 1]]),
        dist,
        make_pose(np.eye(3), np.array([0, 0, -2.0])),
    )
    x, y = 0.2, 0.1
    r2 = x * x + y * y
    radial = 1 + 0.1 * r2 - 0.05 * r2 * r2
    xd = x * radial + 2 * 0.001 * x * y + 0.002 * (r2 + 2 * x * x)
    yd = y * radial + 0.001 * (r2 + 2 * y * y) + 2 * 0.002 * x * y
    vis = visible_points(np.array([[x * 5, y * 5, 7.0]]), cam)  # camera depth 5 m
    assert vis.cols.tolist() == [int(np.floor(400 * xd + 320 + 0.5))]
    assert vis.rows.tolist() == [int(np.floor(400 * yd + 240 + 0.5))]
    np.testing.assert_allclose(vis.distance, [np.sqrt(1 + 0.25 + 25)])


def test_forward_camera_axes():
    # box_camera: optical z = LiDAR +x, x = -y, y = -z; centre 0.1 m ahead and 0.2 m above.
    cam = box_camera(width=161, height=121, focal=100.0)
    vis = visible_points(np.array([[10.1, 0.0, 0.2], [10.1, -1.0, 0.2], [10.1, 0.0, 1.2], [-10.0, 0.0, 0.0]]), cam)
    assert vis.index.tolist() == [0, 1, 2]
    assert vis.cols.tolist() == [80, 90, 80]  # 1 m to the right (-y) at 10 m: +10 px
    assert vis.rows.tolist() == [60, 60, 50]  # 1 m up: -10 px


def test_zbuffer_keeps_the_nearest_point_per_pixel():
    cam = CameraCalibration("c", 640, 480, K)
    ray = np.array([0.1, 0.05, 1.0])
    pts = np.array([ray * 10, ray * 4, ray * 7, [0.3, 0.0, 5.0], ray * 4])
    vis = visible_points(pts, cam)
    # Points 0, 1, 2, 4 share a pixel: the nearest (1, and 4 at the same range) wins; ties go to the
    # lower index. Point 3 has a pixel of its own.
    assert vis.index.tolist() == [1, 3]


def test_zbuffer_cells_hide_points_behind_a_nearby_foreground_pixel():
    cam = CameraCalibration("c", 640, 480, K)
    near = np.array([0.0, 0.0, 5.0])  # pixel (240, 320)
    far = np.array([0.04, 0.0, 10.0])  # pixel (240, 322): another pixel, same 4x4 cell
    per_pixel = visible_points(np.array([near, far]), cam, zbuffer_px=1)
    cells = visible_points(np.array([near, far]), cam, zbuffer_px=4)
    assert per_pixel.index.tolist() == [0, 1]
    assert cells.index.tolist() == [0]
