"""LiDAR odometry: trajectory formats, error metrics by hand, deskewing against analytic motion,
KISS-ICP recovering a drive, and `terra map --poses odometry` writing the trajectory."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from terra.datasets.base import ClassTable, Frame, SemanticClass
from terra.geometry import invert_pose, make_pose, transform_points
from terra.odometry.config import OdometryConfig
from terra.odometry.kiss import deskew, run_odometry
from terra.odometry.metrics import trajectory_errors
from terra.odometry.trajectory import kitti_text, read_kitti, tum_text


def _poses(n=6):
    return np.stack(
        [
            make_pose(Rotation.from_euler("zyx", [0.1 * k, 0.01, -0.02 * k]).as_matrix(), np.array([k, 0.5 * k, 0.1]))
            for k in range(n)
        ]
    )


def test_kitti_and_tum_text():
    poses = _poses()
    np.testing.assert_allclose(read_kitti(kitti_text(poses)), poses, atol=1e-8)
    lines = tum_text(np.arange(6) * 0.1, poses).splitlines()
    first = [float(v) for v in lines[1].split()]
    assert len(lines) == 6 and first[0] == pytest.approx(0.1) and first[1:4] == pytest.approx([1.0, 0.5, 0.1])
    q = Rotation.from_matrix(poses[1, :3, :3]).as_quat()
    assert np.allclose(first[4:], q, atol=1e-8) or np.allclose(first[4:], -q, atol=1e-8)


def test_errors_by_hand():
    ref = np.stack([make_pose(np.eye(3), np.array([k, 0.0, 0.0])) for k in range(11)])  # 10 m straight
    est = ref.copy()
    est[:, 1, 3] = np.linspace(0.0, 0.1, 11)  # drifts sideways to 0.1 m at the end
    e = trajectory_errors(est, ref)
    assert e["distance_m"] == pytest.approx(10.0) and e["final_error_m"] == pytest.approx(0.1)
    assert e["drift_percent"] == pytest.approx(1.0)
    moved = np.stack([make_pose(Rotation.from_euler("z", 0.3).as_matrix(), np.array([4, -2, 1])) @ T for T in ref])
    assert trajectory_errors(moved, ref)["ate_rmse_m"] == pytest.approx(0.0, abs=1e-9)  # ATE aligns rigidly


@pytest.mark.parametrize("velocity", [[0, 0, 0, 2.0, -1.0, 0.2], [0, 0, 0.8, 0, 0, 0]])
def test_deskew_undoes_constant_velocity(velocity):
    """A static scene seen by a sensor moving at constant `velocity` (pure translation, or pure
    yaw, where the decoupled form is exact): deskewing gives the scene in the frame at the stamp."""
    rng = np.random.default_rng(0)
    scene = rng.normal(0, 10, (500, 3))
    times = rng.uniform(0.0, 0.1, 500)
    v = np.asarray(velocity, float)
    seen = np.empty_like(scene)
    for i, tau in enumerate(times):
        T_stamp_sensor = make_pose(Rotation.from_rotvec(tau * v[:3]).as_matrix(), tau * v[3:])
        seen[i] = transform_points(invert_pose(T_stamp_sensor), scene[i : i + 1])[0]
    np.testing.assert_allclose(deskew(seen, times, v), scene, atol=1e-9)
    np.testing.assert_array_equal(deskew(seen, None, v), seen)


class _Frames:
    def __init__(self, frames):
        self.frames, self.name, self.classes = frames, "drive", ClassTable([SemanticClass(0, "unlabeled")])

    def __len__(self):
        return len(self.frames)

    def __getitem__(self, index):
        return self.frames[index]

    def global_map(self):
        return None


def _motion(t: float) -> tuple[np.ndarray, np.ndarray]:
    """Pose (4x4) and body-frame velocity [yaw rate, forward speed] of a drive that starts at rest,
    speeds up over one second to 1.5 m/s while turning at up to 0.1 rad/s, then holds that."""
    ramp = min(t, 1.0)
    s = 0.75 * t * t if t <= 1.0 else 0.75 + 1.5 * (t - 1.0)  # distance, metres
    yaw = 0.05 * t * t if t <= 1.0 else 0.05 + 0.1 * (t - 1.0)
    x = s  # heading changes slowly: integrate it numerically for the position
    ts = np.linspace(0.0, t, 200)
    speed = np.minimum(ts, 1.0) * 1.5
    heading = np.where(ts <= 1.0, 0.05 * ts * ts, 0.05 + 0.1 * (ts - 1.0))
    if t > 0:
        x = np.trapezoid(speed * np.cos(heading), ts)
        y = np.trapezoid(speed * np.sin(heading), ts)
    else:
        y = 0.0
    pose = make_pose(Rotation.from_rotvec([0, 0, yaw]).as_matrix(), np.array([x, y, 0.0]))
    return pose, np.array([0, 0, 0.1 * ramp, 1.5 * ramp, 0, 0])


def _drive(skew: bool):
    """A 10 Hz drive (see _motion) through the simulator's world, seen from the simulator's first
    scan re-observed at each pose: the scene stays the same static geometry, so the true trajectory
    is known exactly. With `skew`, every point is measured at its column's time within a 0.1 s
    sweep (as a spinning LiDAR does) and carries that time."""
    from terra.sim import simulate

    world = simulate("tiny", 0)[0].points.astype(np.float64)  # the scene, in the frame of the drive's start
    azimuth = np.arctan2(world[:, 1], world[:, 0]) % (2 * np.pi)
    times = azimuth / (2 * np.pi) * 0.1 if skew else None
    frames = []
    for k in range(60):
        T, velocity = _motion(0.1 * k)
        local = transform_points(invert_pose(T), world)
        if times is not None:  # skew: the sensor at stamp + tau is at [R(tau w), tau v] in the stamp's frame
            tau = times[:, None]
            local = Rotation.from_rotvec(tau * velocity[:3]).inv().apply(local - tau * velocity[3:])
        frames.append(Frame(k, 0.1 * k, local.astype(np.float32), T, point_times=times))
    return frames


def test_kiss_icp_recovers_a_simulated_drive_within_one_percent():
    run = run_odometry(_Frames(_drive(skew=False)), OdometryConfig(), show_progress=False)
    assert run.errors is not None and run.reference is not None
    assert run.errors["distance_m"] > 7.0
    assert run.errors["drift_percent"] < 1.0, run.errors
    np.testing.assert_allclose(run.poses[0], run.reference[0])  # the map frame is the source's first pose


def test_deskewed_drive_within_one_percent_and_its_scans_straightened():
    from terra.odometry.kiss import OdometryDataset

    skewed, straight = _drive(skew=True), _drive(skew=False)
    dataset = OdometryDataset(_Frames(skewed), OdometryConfig(), show_progress=False)
    assert dataset.run.deskewed == len(skewed) - 1
    assert dataset.run.errors is not None
    assert dataset.run.errors["drift_percent"] < 1.0, dataset.run.errors
    k = 40
    before = np.linalg.norm(skewed[k].points - straight[k].points, axis=1).max()
    after = np.linalg.norm(dataset[k].points - straight[k].points, axis=1).max()
    assert before > 0.3 and after < 0.1 * before, (before, after)


def test_map_with_poses_odometry_writes_the_trajectory(capsys, sim_sources, tmp_path):
    from terra.cli import run
    from terra.odometry.trajectory import read_kitti

    out = tmp_path / "drive.terra"
    assert run(["map", str(sim_sources["rosbag2"]), "--out", str(out), "--poses", "odometry"]) == 0
    text = capsys.readouterr().out
    assert "odometry: KISS-ICP over 5 scans" in text and "ATE" in text and "% of" in text
    kitti = read_kitti((tmp_path / "drive_poses_kitti.txt").read_text())
    assert kitti.shape == (5, 4, 4)
    assert len((tmp_path / "drive_poses_tum.txt").read_text().splitlines()) == 5
    np.testing.assert_allclose(kitti[0], sim_sources["dataset"][0].T_map_lidar, atol=1e-6)


@pytest.mark.slow
def test_kiss_icp_on_a_rendered_simulated_drive_with_a_wobbling_lidar():
    """80 scans at 10 Hz rendered by the simulator on the small campus. Its beam pattern repeats
    exactly from scan to scan unless the LiDAR wobbles (vibration, suspension); with 2 degrees of
    per-scan wobble KISS-ICP ends within 1 % of the distance travelled."""
    from terra.sim import simulate
    from terra.sim.config import SimConfig

    config = {"cameras": [], "lidar": {"wobble_deg": 2.0}, "route": {"frame_spacing": 0.15, "max_frames": 80}}
    run = run_odometry(simulate("small", 0, SimConfig.model_validate(config)), OdometryConfig(), show_progress=False)
    assert run.errors is not None
    assert run.errors["distance_m"] > 11.0
    assert run.errors["drift_percent"] < 1.0, run.errors
