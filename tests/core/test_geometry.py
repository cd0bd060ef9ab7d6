import numpy as np
import pytest

from terra.geometry import (
    CameraCalibration,
    invert_pose,
    make_pose,
    pixel_rays,
    pose_from_xyz_quat,
    pose_to_xyz_quat,
    project_points,
    voxel_centres,
    voxel_keys,
    yaw_rotation,
)


def test_pinhole_projection_hand_computed():
    cam = CameraCalibration("c", 640, 480, np.array([[500, 0, 320], [0, 500, 240], [0, 0, 1]]))
    uv, valid = project_points(np.array([[1.0, -0.5, 10.0], [0.0, 0.0, -5.0], [100.0, 0.0, 1.0]]), cam)
    # u = 500 * 1/10 + 320 = 370, v = 500 * -0.05 + 240 = 215
    np.testing.assert_allclose(uv[0], [370.0, 215.0])
    assert valid.tolist() == [True, False, False]  # behind the camera; outside the image


def test_distortion_hand_computed_and_inverse():
    dist = np.array([0.1, -0.05, 0.001, 0.002, 0.0])
    cam = CameraCalibration("c", 640, 480, np.array([[400, 0, 320], [0, 400, 240], [0, 0, 1]]), dist)
    x, y = 0.2, 0.1
    r2 = x * x + y * y
    radial = 1 + 0.1 * r2 - 0.05 * r2 * r2
    xd = x * radial + 2 * 0.001 * x * y + 0.002 * (r2 + 2 * x * x)
    yd = y * radial + 0.001 * (r2 + 2 * y * y) + 2 * 0.002 * x * y
    uv, valid = project_points(np.array([[x * 5, y * 5, 5.0]]), cam)
    np.testing.assert_allclose(uv[0], [400 * xd + 320, 400 * yd + 240], rtol=1e-12)
    # a pixel's ray projects back onto that pixel
    rays = pixel_rays(cam)
    uv_back, ok = project_points(rays * 7.0, cam)
    v, u = np.mgrid[0:480, 0:640]
    assert ok.all()
    np.testing.assert_allclose(uv_back, np.stack([u.ravel(), v.ravel()], 1), atol=1e-6)


def test_pose_roundtrip_and_inverse():
    T = make_pose(yaw_rotation(0.7), np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(invert_pose(T) @ T, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(pose_from_xyz_quat(pose_to_xyz_quat(T)), T, atol=1e-12)
    with pytest.raises(ValueError):
        pose_from_xyz_quat(np.zeros(6))


def test_voxel_keys_roundtrip():
    pts = np.array([[0.1, -0.1, 5.0], [-1000.3, 2000.7, -3.2], [0.39, 0.0, 0.0]])
    keys = voxel_keys(pts, 0.4)
    assert keys[0] != keys[2] or np.all(np.floor(pts[0] / 0.4) == np.floor(pts[2] / 0.4))
    centres = voxel_centres(keys, 0.4)
    assert np.all(np.abs(centres - pts) <= 0.2 + 1e-9)
