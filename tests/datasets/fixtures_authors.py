"""The authors' msmap camera configs as their repository has them (BYU-FROST-Lab/Terra,
terra/config/field_tests/msmap_multicam.yaml: the 4-coefficient "SSP" rig at commit 3ad947d and
the 14-coefficient "Nunns Park" rig at commit 88d53c2; their paths, YOLO and DBSCAN keys
included, since `terra map --camera-config` must take the file as it is), and a hand-built
dataset with their three cameras for the layout tests.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from terra.datasets.base import CameraFrame, Frame
from terra.geometry import CameraCalibration, make_pose
from tests.datasets.fixtures import CLASSES, HandDataset, hand_ground_truth

SSP_YAML = """\
## Processing parameters
data_folder: /ros2_bags/metric_data_0.5s/synced/provo_river_p1_11_3_25_new_org
output_folder: /ros2_bags/metric_data_0.5s/synced/provo_river_p1_11_3_25_new_org/output/3_cam
num_cams: 3
debug: false
continue_processing: true
save_step_size: 500
unaligned_threshold: 0.05 # seconds

## Camera intrinsics
IMG_W: 768
IMG_H: 480

cam1_K:  [458.17091039, 0.0, 388.71610935,
        0.0, 457.99950521, 230.87195191,
        0.0, 0.0, 1.0] # 768 x 480
cam1_dist: [0.03738764, -0.07371669, -0.00024887, 0.00058859] # forward

cam2_K:  [455.47078158, 0.0, 386.00515232,
        0.0, 455.32530496, 244.20159992,
        0.0, 0.0, 1.0] # 768 x 480
cam2_dist: [0.04187796, -0.0808205, -0.0001623, -0.00039214] # left

cam3_K:  [456.77801458, 0.0, 378.49188005,
        0.0, 456.3905806,  240.8612888,
        0.0, 0.0, 1.0] # 768 x 480
cam3_dist: [0.02182443, -0.04749719, 0.00062508, 0.00044833] # right

## YOLO Model
use_yoloe: false
yolo_model_path: /goose_7cls_ground.pt
yolo_conf_threshold: 0.05

## MS Map parameters
match_threshold: 0.9
use_dbscan: true
dbscan_eps: 2.0
dbscan_min_samples: 5
cam2point_dist_threshold: 20.0 # [m]
cam_axis: ['-x', '-y', '+y']  # ['+x', '-x', '+y', '-y']
"""

NUNNS_PARK_YAML = """\
## Processing parameters
data_folder: /ros2_bags/metric_data_0.5s/synced/nunns_park_p2_10_15_25
output_folder: /ros2_bags/metric_data_0.5s/synced/nunns_park_p2_10_15_25/output/3_cam
num_cams: 3
debug: false
continue_processing: false
save_step_size: 500
unaligned_threshold: 0.05 # seconds

## Camera intrinsics
IMG_W: 768
IMG_H: 480

cam1_K: [453.9425964355469, 0.0, 388.0409851074219,
        0.0, 453.8470764160156, 247.8123321533203,
        0.0, 0.0, 1.0]  # 768 x 480
cam1_dist: [4.479070663452148, 0.39237383008003235, -4.801498289452866e-05,
        0.0002160959702450782, 2.7756459712982178, 4.403016090393066,
        0.37853071093559265, 2.9023659229278564, 0.0,
        0.0, 0.0, 0.0, -0.003902334487065673, 0.0001621022674953565] # forward

cam2_K:  [454.3408203125, 0.0, 380.1490173339844,
        0.0, 454.3426818847656, 250.3977813720703,
        0.0, 0.0, 1.0] # 768 x 480
cam2_dist: [3.7520368099212646, -0.33402150869369507, 0.00011741014895960689,
        0.00026635383255779743, 1.911475419998169, 3.676846504211426,
        -0.29829320311546326, 1.9814714193344116, 0.0,
        0.0, 0.0, 0.0, -0.0008460935787297785, 0.004733051639050245] # left

cam3_K:  [457.978759765625, 0.0, 387.35205078125,
        0.0, 457.719482421875, 240.11021423339844,
        0.0, 0.0, 1.0] # 768 x 480
cam3_dist: [16.120267868041992, 31.638051986694336, 0.00022723490837961435,
        0.0006202104850672185, 0.887903094291687, 16.1851806640625,
        30.912010192871094, 2.398867130279541, 0.0,
        0.0, 0.0, 0.0, 0.0006207168917171657, 0.003685013158246875] # right

## YOLO Model
use_yoloe: false
yolo_model_path: /goose_7cls_ground.pt
yolo_conf_threshold: 0.05

## MS Map parameters
match_threshold: 0.9
use_dbscan: true
dbscan_eps: 2.0
dbscan_min_samples: 5
cam2point_dist_threshold: 20.0 # [m]
cam_axis: ['-x', '-y', '+y']  # ['+x', '-x', '+y', '-y']
"""

WIDTH, HEIGHT = 768, 480
AXES = ("-x", "-y", "+y")
# Optical frame (z forward, x right, y down) from a LiDAR frame (x forward, y left, z up).
_LIDAR_TO_OPTICAL = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
_YAW_OF_AXIS = {"+x": 0.0, "-x": 180.0, "+y": 90.0, "-y": -90.0}


def rig(config_text: str, count: int = 3) -> list[CameraCalibration]:
    """The first `count` cameras of a config text, mounted looking along their cam_axis."""
    import yaml

    cfg = yaml.safe_load(config_text)
    cams = []
    for n in range(1, count + 1):
        yaw = _YAW_OF_AXIS[cfg["cam_axis"][n - 1]]
        R = _LIDAR_TO_OPTICAL @ Rotation.from_euler("z", -yaw, degrees=True).as_matrix()
        cams.append(
            CameraCalibration(
                f"cam{n}",
                WIDTH,
                HEIGHT,
                np.reshape(cfg[f"cam{n}_K"], (3, 3)),
                cfg[f"cam{n}_dist"],
                make_pose(R, np.array([0.05 * n, -0.1, 0.2])),
            )
        )
    return cams


class AuthorsRig(HandDataset):
    """Three frames with the cameras of an authors' config (768 x 480 images)."""

    def __init__(self, config_text: str, count: int) -> None:
        super().__init__()
        rng = np.random.default_rng(11)
        cameras = rig(config_text, count)
        ids = np.array([c.id for c in CLASSES])
        frames = []
        for frame in self.frames:
            cams = []
            for cal in cameras:
                semantic = np.repeat(np.repeat(rng.choice(ids, size=(6, 8)), 80, 0), 96, 1).astype(np.int32)
                image = (rng.integers(30, 220, size=(ids.max() + 1, 3))[semantic]).astype(np.uint8)
                cams.append(CameraFrame(cal, frame.stamp, image, semantic, np.zeros_like(semantic)))
            frames.append(
                Frame(
                    frame.index,
                    frame.stamp,
                    frame.points,
                    frame.T_map_lidar,
                    cams,
                    frame.intensity,
                    frame.point_labels,
                    frame.point_instances,
                )
            )
        self.frames = frames
        self.gt = hand_ground_truth()
