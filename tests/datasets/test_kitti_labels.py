"""KITTI object and tracking labels as oriented boxes: hand-worked label lines in a hand-built
frame contain the object's LiDAR points; sightings merge into one ground-truth object per
physical object; malformed lines name the file and line."""

import math

import numpy as np
import pytest

from terra.datasets import open_dataset
from terra.datasets.kitti_labels import (
    KittiLabel,
    box_in_frame,
    ground_truth_from_labels,
    objects_from_labels,
    parse_label_line,
    read_label_file,
)
from terra.datasets.kitti_raw import KittiRawDataset
from terra.errors import TerraError
from terra.geometry import invert_pose, make_pose
from tests.datasets.test_datasets_kitti_raw import CAM_TO_CAM, VELO_TO_CAM, matrix, write_drive

# Rectified camera (x right, y down, z forward) from a Velodyne frame (x forward, y left, z up).
T_RECT_VELO = make_pose(np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]), np.zeros(3))


def parse_object_line(text: str, where: str, tracking: bool) -> KittiLabel:
    """parse_label_line for a line that is an object (not DontCare)."""
    label = parse_label_line(text, where, tracking)
    assert label is not None
    return label


def box_points(center, size, yaw, count=300, seed=0):
    """Points filling a yawed box (LiDAR frame), as a scan of the object would lie on and in it."""
    rng = np.random.default_rng(seed)
    local = rng.uniform(-0.5, 0.5, (count, 3)) * np.asarray(size)
    c, s = math.cos(yaw), math.sin(yaw)
    return np.asarray(center) + local @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


# Hand-worked: a car 4.0 long, 1.8 wide, 1.5 high centred at (10, 2, -1) in the LiDAR frame heading
# along +x has its bottom centre at (10, 2, -1.75): in camera coordinates x = -2, y = 1.75, z = 10,
# and its length axis is the camera's +z, so rotation_y = -pi/2. A 3.9 x 1.6 x 1.45 car at
# (6, -4, -0.9) heading 30 degrees left of +x: bottom (6, -4, -1.625) -> (4, 1.625, 6); its length
# axis (cos 30, sin 30, 0) -> (-0.5, 0, 0.866) = (cos ry, 0, -sin ry) with ry = -120 degrees.
HAND = [
    (
        "Car 0.00 0 -1.37 500.0 150.0 600.0 250.0 1.50 1.80 4.00 -2.00 1.75 10.00 -1.570796",
        (10.0, 2.0, -1.0),
        (4.0, 1.8, 1.5),
        0.0,
    ),
    (
        "Car 0.00 1 -2.68 700.0 160.0 900.0 240.0 1.45 1.60 3.90 4.00 1.625 6.00 -2.094395",
        (6.0, -4.0, -0.9),
        (3.9, 1.6, 1.45),
        math.radians(30),
    ),
]


@pytest.mark.parametrize("line, center, size, yaw", HAND)
def test_hand_worked_label_box_contains_the_objects_lidar_points(line, center, size, yaw):
    label = parse_object_line(line, "hand:1", tracking=False)
    box = box_in_frame(label, invert_pose(T_RECT_VELO))
    np.testing.assert_allclose(box.center, center, atol=1e-6)
    np.testing.assert_allclose(box.size, size)
    assert (box.yaw() - yaw + math.pi / 2) % math.pi - math.pi / 2 == pytest.approx(0.0, abs=1e-6)
    inside = box_points(center, size, yaw)
    assert box.contains(inside, margin=1e-6).all()
    outside = box_points(center, np.asarray(size) * 1.6, yaw, seed=1)
    beyond = np.any(np.abs((outside - center) @ box.axes) > np.asarray(size) / 2 + 1e-6, axis=1)
    assert not box.contains(outside[beyond]).any() and beyond.sum() > 100


def test_label_box_with_kittis_own_calibration():
    """KITTI 2011_09_26 (R_rect_00 and velo_to_cam are not a pure axis swap): a label written with
    the usual conversion (bottom centre through R_rect [R | T], rotation_y = -yaw - pi/2) holds the
    object's points to within the calibration's tilt of about a degree."""
    R_rect = np.eye(4)
    R_rect[:3, :3] = matrix(CAM_TO_CAM, "R_rect_00", (3, 3))
    T = make_pose(matrix(VELO_TO_CAM, "R", (3, 3)), matrix(VELO_TO_CAM, "T", (3,)))
    T_rect_velo = R_rect @ T
    center, size, yaw = np.array([14.0, -3.0, -0.8]), np.array([4.2, 1.7, 1.55]), math.radians(-40)
    bottom = T_rect_velo[:3, :3] @ (center - [0, 0, size[2] / 2]) + T_rect_velo[:3, 3]
    line = (
        f"Car 0.00 0 0.0 1.0 1.0 2.0 2.0 {size[2]} {size[1]} {size[0]} {bottom[0]} {bottom[1]} {bottom[2]} "
        f"{-yaw - math.pi / 2}"
    )
    box = box_in_frame(parse_object_line(line, "hand:1", tracking=False), np.linalg.inv(T_rect_velo))
    assert box.contains(box_points(center, size, yaw), margin=0.06).all()
    assert np.linalg.norm(box.center - center) < 0.03


def test_malformed_label_lines_name_file_and_line(tmp_path):
    path = tmp_path / "000042.txt"
    path.write_text(
        "Car 0.00 0 -1.37 500 150 600 250 1.5 1.8 4.0 -2.0 1.75 10.0 -1.57\n"
        "Pedestrian 0.00 0 0.2 1 2 3 4 1.7 0.6 0.8 1 1.6 8\n"
    )
    with pytest.raises(
        TerraError, match=rf"^{path}:2: a KITTI object label has 15 fields \(16 with a score\), got 14$"
    ):
        read_label_file(path, tracking=False)
    path.write_text("3 7 Car 0 0 -1.37 500 150 600 250 1.5 1.8 4.0 -2.0 1.75 10.0\n")
    with pytest.raises(TerraError, match=r":1: a KITTI tracking label has 17 fields \(18 with a score\), got 16$"):
        read_label_file(path, tracking=True)
    path.write_text("Car 0.00 0 -1.37 500 150 600 250 1.5 -1.8 4.0 -2.0 1.75 10.0 -1.57\n")
    with pytest.raises(TerraError, match=r":1: dimensions h w l must be positive, got 1.5 -1.8 4.0"):
        read_label_file(path, tracking=False)
    path.write_text("Car 0.00 0 -1.37 500 150 600 250 1.5 1.8 four -2.0 1.75 10.0 -1.57\n")
    with pytest.raises(TerraError, match=r":1: expected numbers after the type 'Car'"):
        read_label_file(path, tracking=False)
    # DontCare regions are skipped; a trailing score (detector output) is accepted.
    path.write_text(
        "DontCare -1 -1 -10 503.89 169.71 590.61 190.13 -1 -1 -1 -1000 -1000 -1000 -10\n"
        "Person_sitting 0.00 0 0.2 1 2 3 4 1.2 0.6 0.8 1 1.6 8 0.1 0.93\n"
    )
    labels = read_label_file(path, tracking=False, frame=42)
    assert len(labels) == 1 and labels[0].class_name == "person sitting" and labels[0].frame == 42


def test_sightings_merge_and_moving_tracks_are_left_out():
    car = "Car 0.00 0 0.0 1 1 2 2 1.5 1.8 4.0 {x} 1.75 {z} -1.570796"
    # A parked car seen from two ego poses 5 m apart: the same map position.
    T_map_rect = {
        0: invert_pose(T_RECT_VELO),
        1: make_pose(np.eye(3), np.array([5.0, 0.0, 0.0])) @ invert_pose(T_RECT_VELO),
    }
    parked = [
        parse_object_line(car.format(x=-2.0, z=10.0), "a:1", False),
        parse_object_line(car.format(x=-2.0, z=5.0), "b:1", False),
    ]
    parked = [p.__class__(**{**p.__dict__, "frame": f}) for p, f in zip(parked, (0, 1))]
    moving = [
        parse_object_line(f"{f} 9 Van 0 0 0 1 1 2 2 2.0 1.9 5.0 3.0 1.9 {12.0 + 3 * f} -1.570796", "t:1", True)
        for f in (0, 1)
    ]
    static = [
        parse_object_line(f"{f} 4 Cyclist 0 0 0 1 1 2 2 1.7 0.6 1.8 1.0 1.6 {20.0 - 5 * f} 0.0", "t:2", True)
        for f in (0, 1)
    ]
    boxes = [(label, box_in_frame(label, T_map_rect[label.frame])) for label in parked + moving + static]
    objects, left_out = objects_from_labels(boxes)
    assert left_out == {"moving": 1} and [o.class_name for o in objects] == ["car", "cyclist"]
    np.testing.assert_allclose(objects[0].center, [10.0, 2.0, -1.0], atol=1e-9)
    assert objects[1].instance_id == 4
    gt = ground_truth_from_labels([label for label, _ in boxes], {0: T_map_rect[0]}, "drive")
    assert gt.terrain is None and gt.regions == [] and "1 objects moved" not in " ".join(gt.notes)
    assert any("3 labels belong to frames without a pose" in n for n in gt.notes)


def test_drive_labels_become_map_frame_ground_truth(tmp_path):
    """Tracking labels in a drive: the label of a car at a fixed map position, written per frame
    with plain numpy from the calibration text and the drive's poses, reads back at that position."""
    drive = write_drive(tmp_path)
    ds = open_dataset(drive)
    assert isinstance(ds, KittiRawDataset)
    R_rect = np.eye(4)
    R_rect[:3, :3] = matrix(CAM_TO_CAM, "R_rect_00", (3, 3))
    T_rect_velo = R_rect @ make_pose(matrix(VELO_TO_CAM, "R", (3, 3)), matrix(VELO_TO_CAM, "T", (3,)))
    car = np.array([30.0, 40.0, 2.0])  # map frame, box centre; 1.5 m high, heading east
    lines = []
    for i in range(len(ds)):
        T_rect_map = T_rect_velo @ np.linalg.inv(ds[i].T_map_lidar)
        bottom = T_rect_map[:3, :3] @ (car - [0, 0, 0.75]) + T_rect_map[:3, 3]
        east = T_rect_map[:3, :3] @ np.array([1.0, 0.0, 0.0])
        ry = math.atan2(-east[2], east[0])
        lines.append(f"{i} 12 Car 0 0 0 1 1 2 2 1.5 1.8 4.0 " + " ".join(repr(float(v)) for v in (*bottom, ry)))
    (drive / "label_02").mkdir()
    (drive / "label_02" / "0005.txt").write_text("\n".join(lines) + "\n")
    gt = ds.ground_truth()
    assert len(gt.objects) == 1 and gt.objects[0].class_name == "car" and gt.objects[0].instance_id == 12
    # The label frame is tilted against the map (R_rect, the Velodyne's mount, the vehicle's roll
    # and pitch), so the centre moves by at most h / 2 sin(tilt).
    assert np.linalg.norm(gt.objects[0].center - car) < 0.75 * math.sin(math.radians(13))
    assert ds.info().details["labels"] == ["label_02/0005.txt"]
    (drive / "label_2").mkdir()
    (drive / "label_2" / "0000000000.txt").write_text("")
    with pytest.raises(TerraError, match="has both label_02/ .* and label_2/"):
        ds.ground_truth()
