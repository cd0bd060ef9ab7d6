"""A simulated KITTI raw drive (`terra sim --format kitti-raw`) through map, build, find and eval:
the drive reads back as the simulator's frames in the drive's own map frame, its labels become the
simulator's objects, and an evaluation on the labels alone scores retrieval and says what it cannot."""

import hashlib
import json
import shutil

import numpy as np
import pytest

from terra.cli import run
from terra.datasets import open_dataset
from terra.datasets.ground_truth import load_ground_truth
from terra.datasets.kitti_raw import KittiRawDataset
from terra.datasets.kitti_raw_writer import kitti_rig
from tests.eval.fixtures import run_cli

pytestmark = pytest.mark.slow

FRAMES = 8


@pytest.fixture(scope="module")
def simulated():
    from terra.sim import simulate
    from terra.sim.config import SimConfig, without_distortion

    return simulate(
        "tiny",
        0,
        without_distortion(SimConfig()).model_copy(
            update={"route": SimConfig().route.model_copy(update={"max_frames": FRAMES})}
        ),
    )


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    out = tmp_path_factory.mktemp("kitti-e2e") / "drive"
    assert (
        run(["sim", "--preset", "tiny", "--max-frames", str(FRAMES), "--format", "kitti-raw", "--out", str(out), "-q"])
        == 0
    )
    return out


@pytest.fixture(scope="module")
def bundle(drive, text_embedder):
    out = drive.parent / "drive.terra"
    assert run(["map", str(drive), "--out", str(out), "-q"]) == 0
    assert run(["build", str(out), "-q"]) == 0
    return out


def shift_of(simulated) -> np.ndarray:
    """Simulator map -> drive map: the drive's origin is the first frame's IMU position."""
    _, T_velo_imu = kitti_rig()
    return -(simulated.gt_T_map_lidar(0) @ T_velo_imu)[:3, 3]


def test_the_drive_is_laid_out_as_kitti_ships_it(drive):
    date = drive / "2011_09_26"
    folder = date / "2011_09_26_drive_0001_sync"
    assert sorted(p.name for p in date.iterdir()) == [
        "2011_09_26_drive_0001_sync",
        "calib_cam_to_cam.txt",
        "calib_imu_to_velo.txt",
        "calib_velo_to_cam.txt",
    ]
    for sub, suffix in (("velodyne_points/data", ".bin"), ("image_02/data", ".png"), ("oxts/data", ".txt")):
        assert [p.name for p in sorted((folder / sub).iterdir())] == [f"{i:010d}{suffix}" for i in range(FRAMES)]
    stamps = (folder / "velodyne_points" / "timestamps.txt").read_text().splitlines()
    assert len(stamps) == FRAMES and stamps[0] == "2011-09-26 12:00:00.000000000"
    keys = [line.split(":")[0] for line in (date / "calib_cam_to_cam.txt").read_text().splitlines()]
    assert keys[:10] == [
        "calib_time",
        "corner_dist",
        "S_00",
        "K_00",
        "D_00",
        "R_00",
        "T_00",
        "S_rect_00",
        "R_rect_00",
        "P_rect_00",
    ]
    assert {"P_rect_02", "P_rect_03", "R_rect_03", "S_rect_03"} <= set(keys)
    assert [len(line.split()) for line in (folder / "oxts" / "data" / "0000000003.txt").read_text().splitlines()] == [
        30
    ]
    assert (folder / "label_02" / "0001.txt").is_file()


def test_same_seed_same_bytes(drive, tmp_path):
    again = tmp_path / "again"
    assert (
        run(
            ["sim", "--preset", "tiny", "--max-frames", str(FRAMES), "--format", "kitti-raw", "--out", str(again), "-q"]
        )
        == 0
    )

    def digest(root):
        return {
            str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*"))
            if p.is_file()
        }

    assert digest(drive) == digest(again)


def test_frames_read_back_in_the_drives_map_frame(drive, simulated):
    ds = open_dataset(drive)
    assert isinstance(ds, KittiRawDataset) and len(ds) == FRAMES
    shift = shift_of(simulated)
    for i in (0, 5):
        got, expected = ds[i], simulated[i]
        np.testing.assert_array_equal(got.points, expected.points)
        np.testing.assert_array_equal(got.point_labels, expected.point_labels)
        T = expected.T_map_lidar.copy()
        T[:3, 3] += shift
        np.testing.assert_allclose(got.T_map_lidar, T, atol=1e-6)
        cam, exp = got.cameras[0], expected.cameras[0]
        np.testing.assert_allclose(cam.calibration.K, exp.calibration.K, atol=1e-9)
        np.testing.assert_allclose(cam.calibration.T_cam_lidar, exp.calibration.T_cam_lidar, atol=1e-9)
        np.testing.assert_array_equal(cam.image, exp.image)
        np.testing.assert_array_equal(cam.semantic, exp.semantic)
        assert got.stamp - ds.stamps[0] == pytest.approx(expected.stamp - simulated[0].stamp, abs=1e-6)
    gt, sim_gt = load_ground_truth(drive), simulated.ground_truth()
    for obj, ref in zip(gt.objects, sim_gt.objects):
        np.testing.assert_allclose(obj.center, ref.center + shift, atol=1e-5)
    assert gt.terrain is not None and sim_gt.terrain is not None
    np.testing.assert_allclose(gt.terrain.origin, sim_gt.terrain.origin + shift[:2], atol=1e-5)


def test_labels_give_the_simulators_objects(drive, simulated, tmp_path):
    labelled = shutil.copytree(drive, tmp_path / "labels-only")
    shutil.rmtree(labelled / "ground_truth")
    labels_only = open_dataset(labelled)
    assert isinstance(labels_only, KittiRawDataset)
    gt = labels_only.ground_truth()
    assert gt.terrain is None and gt.regions == [] and "terrain and named regions are not labelled" in gt.notes[0]
    reference = {o.instance_id: o for o in load_ground_truth(drive).objects}
    assert {o.class_name for o in gt.objects} >= {"car"} and len(gt.objects) >= 10
    for obj in gt.objects:
        ref = reference[obj.instance_id]
        assert obj.class_name == ref.class_name
        np.testing.assert_allclose(obj.size, ref.size, atol=1e-5)
        # Labels turn boxes about the camera's y axis; the camera looks 5 degrees down and the robot
        # tilts with the ground, so the box's centre moves by under h / 2 sin(10 degrees).
        assert np.linalg.norm(obj.center - ref.center) < 0.02 + ref.size[2] / 2 * np.sin(np.radians(10))
        assert abs((obj.yaw - ref.yaw + np.pi / 2) % np.pi - np.pi / 2) < 0.01


def test_map_build_find_on_the_drive(bundle, drive):
    code, out, err = run_cli(["find", str(bundle), "find the car", "--json"])
    assert code == 0, err
    found = json.loads(out)
    cars = np.array([o.center for o in load_ground_truth(drive).objects if o.class_name == "car"])
    centres = np.array([o["center"] for o in found["objects"]])
    assert len(centres) >= 3
    nearest = np.linalg.norm(centres[:, None, :2] - cars[None, :, :2], axis=2).min(axis=1)
    assert np.median(nearest) < 1.5  # the boxes found sit on the simulator's cars, in the drive's frame


def test_eval_on_labels_alone_scores_retrieval_and_says_what_it_cannot(bundle, drive, tmp_path):
    labelled = shutil.copytree(drive, tmp_path / "labels-only")
    shutil.rmtree(labelled / "ground_truth")
    report = tmp_path / "report"
    code, out, err = run_cli(["eval", str(bundle), "--gt", str(labelled), "--out", str(report), "-q"])
    assert code == 0, err
    summary = json.loads((report / "summary.json").read_text())
    assert {"retrieval", "memory", "not_evaluated"} <= set(summary)
    assert not {"segmentation", "regions", "navigation"} & set(summary)
    assert set(summary["not_evaluated"]) == {"segmentation", "regions", "navigation", "notes"}
    assert "Find the car" in summary["retrieval"]["queries"] and summary["retrieval"]["num_gt"] >= 10
    assert summary["retrieval"]["methods"]["ms-avg"]["relaxed_accuracy"] > 0.3
    text = (report / "report.md").read_text()
    assert "## Not evaluated" in text and "Table III" not in text.split("## Not evaluated")[1].split("## Table II")[1]
    assert "not evaluated (segmentation, regions, navigation)" in out


def test_eval_with_a_bad_label_line_is_one_line_and_writes_nothing(bundle, drive, tmp_path):
    labelled = shutil.copytree(drive, tmp_path / "labels-only")
    shutil.rmtree(labelled / "ground_truth")
    path = labelled / "2011_09_26" / "2011_09_26_drive_0001_sync" / "label_02" / "0001.txt"
    lines = path.read_text().splitlines()
    lines[2] = " ".join(lines[2].split()[:-1])  # rotation_y dropped: 16 fields
    path.write_text("\n".join(lines) + "\n")
    report = tmp_path / "report"
    code, _, err = run_cli(["eval", str(bundle), "--gt", str(labelled), "--out", str(report), "-q"])
    assert code == 2 and err.strip().count("\n") == 0
    assert f"{path}:3: a KITTI tracking label has 17 fields (18 with a score), got 16" in err
    assert not report.exists()


def test_the_map_records_its_wgs84_anchor_and_exports_geojson_with_it(bundle, drive, tmp_path):
    from terra.bundle import Bundle
    from terra.datasets.kitti_raw_writer import GEODETIC_ORIGIN
    from terra.wgs84 import MapToWgs84

    anchor = Bundle(bundle).model.components.map.wgs84_anchor  # pyright: ignore[reportOptionalMemberAccess]
    assert anchor is not None and anchor.projection == "kitti-mercator" and anchor.yaw_deg == 0.0
    # The simulated world's origin lies at GEODETIC_ORIGIN: the map's (the first IMU position) lies
    # where the world puts it, through pyproj's Mercator (not the writer's own formulas).
    from terra.schemas import Wgs84Anchor
    from terra.sim import simulate

    world = Wgs84Anchor(
        lat=GEODETIC_ORIGIN[0], lon=GEODETIC_ORIGIN[1], alt=GEODETIC_ORIGIN[2], projection="kitti-mercator"
    )
    first_imu = (simulate("tiny", seed=0).gt_T_map_lidar(0) @ kitti_rig()[1])[:3, 3]
    lon, lat, alt = MapToWgs84(world).lon_lat_height(first_imu[None])[0]
    assert (anchor.lat, anchor.lon, anchor.alt) == pytest.approx((lat, lon, alt), abs=1e-8)
    # Each frame's IMU position in the map, turned into WGS84 under the anchor, is its OXTS packet.
    ds = open_dataset(drive)
    assert isinstance(ds, KittiRawDataset)
    _, T_velo_imu = kitti_rig()
    to_wgs84 = MapToWgs84(anchor)
    for i in (0, FRAMES - 1):
        packet = np.loadtxt(ds.drive / "oxts" / "data" / f"{ds.indices[i]:010d}.txt")
        lon, lat, alt = to_wgs84.lon_lat_height((ds.poses[i] @ T_velo_imu)[None, :3, 3])[0]
        assert (lat, lon) == pytest.approx((packet[0], packet[1]), abs=1e-9)  # 0.1 mm
        assert alt == pytest.approx(packet[2], abs=1e-6)
    out = tmp_path / "drive.geojson"
    assert run(["export", str(bundle), "-f", "geojson", "-o", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["terra"]["wgs84_anchor"]["source"].startswith("kitti-raw OXTS")
    lon, lat, _ = doc["features"][0]["geometry"]["coordinates"]
    assert abs(lat - GEODETIC_ORIGIN[0]) < 0.01 and abs(lon - GEODETIC_ORIGIN[1]) < 0.01
