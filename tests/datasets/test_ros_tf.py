"""TF lookups against analytic poses: a frame turning at a constant rate while moving on a line
(slerp and linear interpolation are exact there), chains through static mounts, and errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from terra.datasets.ros.tf import TfTree
from terra.errors import TerraError
from terra.geometry import invert_pose, make_pose, pose_to_xyz_quat

OMEGA = 0.3  # rad/s about z
VELOCITY = np.array([1.0, -0.5, 0.1])  # m/s


def analytic_T_map_base(t: float) -> np.ndarray:
    return make_pose(Rotation.from_rotvec([0.0, 0.0, OMEGA * t]).as_matrix(), VELOCITY * t)


T_BASE_LIDAR = make_pose(Rotation.from_euler("xyz", [0.01, -0.02, 0.5]).as_matrix(), np.array([0.3, 0.0, 1.2]))
T_BASE_CAM = make_pose(Rotation.from_euler("xyz", [-1.6, 0.0, -1.5]).as_matrix(), np.array([0.5, 0.1, 1.0]))


def tree() -> TfTree:
    tf = TfTree()
    for t in np.arange(0.0, 2.01, 0.2):
        tf.add("map", "base_link", pose_to_xyz_quat(analytic_T_map_base(t)), t)
    tf.add("base_link", "lidar", pose_to_xyz_quat(T_BASE_LIDAR), None)
    tf.add("/base_link", "/cam", pose_to_xyz_quat(T_BASE_CAM), None)  # leading slashes (ROS 1 style) are dropped
    tf.freeze()
    return tf


def test_interpolated_pose_equals_the_analytic_one_between_samples():
    times = np.array([0.05, 0.3, 0.77, 1.999])
    T, valid = tree().lookup("map", "lidar", times)
    assert valid.all()
    for k, t in enumerate(times):
        np.testing.assert_allclose(T[k], analytic_T_map_base(t) @ T_BASE_LIDAR, atol=1e-12)


def test_on_a_sample_the_sample_itself_and_outside_the_series_not_valid():
    tf = tree()
    T, valid = tf.lookup("map", "base_link", np.array([0.4, -0.01, 2.5]))
    np.testing.assert_allclose(T[0], analytic_T_map_base(0.4), atol=1e-15)
    assert valid.tolist() == [True, False, False]


def test_gap_between_samples_larger_than_allowed_is_not_valid():
    tf = tree()
    _, valid = tf.lookup("map", "lidar", np.array([0.1]), max_gap=0.15)
    assert not valid[0]


def test_static_chain_between_two_children_of_one_parent():
    tf = tree()
    T, valid = tf.lookup("cam", "lidar", np.array([0.0]))
    np.testing.assert_allclose(T[0], invert_pose(T_BASE_CAM) @ T_BASE_LIDAR, atol=1e-12)
    assert tf.is_static("cam", "lidar") and not tf.is_static("map", "lidar")


def test_disconnected_frames_name_both_and_list_the_frames():
    tf = tree()
    tf.add("odom", "imu", pose_to_xyz_quat(np.eye(4)), None)
    with pytest.raises(
        TerraError,
        match=r"does not connect 'odom' and 'lidar'.*frames: 'base_link', 'cam', 'imu', 'lidar', 'map', 'odom'$",
    ):
        tf.lookup("odom", "lidar", np.array([0.0]))
    with pytest.raises(TerraError, match="does not connect 'map' and 'os_lidar': no transform has frame 'os_lidar'"):
        tf.lookup("map", "os_lidar", np.array([0.0]))
