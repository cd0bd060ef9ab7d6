"""A folder laid out exactly as the authors' extraction tools write it (cameras 1..3 with their
14-coefficient Nunns Park lenses looking along their cam_axis, no Terra metadata) maps with their
msmap config as it is, and every camera's images are fused.

Besides the authors' files, the folder keeps Terra's label images and class table: they stand in
for the YOLO / FastSAM / CLIP models this machine does not have (the `labels` perception backend).
"""

import shutil

import numpy as np
import pytest
import yaml

from terra.bundle import Bundle
from terra.cli import run
from terra.mapping.storage import load_map
from tests.datasets.fixtures_authors import NUNNS_PARK_YAML

pytestmark = pytest.mark.slow

FRAMES = 4


@pytest.fixture(scope="module")
def extracted(tmp_path_factory):
    from terra.sim import simulate
    from terra.sim.config import CameraConfig, RouteConfig, SimConfig
    from terra.sim.writer import write_dataset

    cfg = yaml.safe_load(NUNNS_PARK_YAML)
    yaw = {"-x": 180.0, "-y": -90.0, "+y": 90.0}
    cameras = []
    for n in (1, 2, 3):
        K = np.reshape(cfg[f"cam{n}_K"], (3, 3))
        cameras.append(
            CameraConfig(
                name=f"cam{n}",
                width=cfg["IMG_W"],
                height=cfg["IMG_H"],
                fx=K[0, 0],
                fy=K[1, 1],
                cx=K[0, 2],
                cy=K[1, 2],
                dist=cfg[f"cam{n}_dist"],
                position=(0.1 * n, 0.0, 1.5),
                yaw_deg=yaw[cfg["cam_axis"][n - 1]],
                pitch_deg=5.0,
            )
        )
    dataset = simulate("tiny", 0, SimConfig(cameras=cameras, route=RouteConfig(max_frames=FRAMES)))
    root = tmp_path_factory.mktemp("authors-e2e")
    folder = write_dataset(dataset, root / "hope_campground", progress=False)
    for name in ("terra_dataset.json", "msmap_camera_config.yaml"):
        (folder / name).unlink()
    for name in ("lidar_labels", "ground_truth"):
        shutil.rmtree(folder / name)
    config = root / "msmap_multicam.yaml"
    config.write_text(NUNNS_PARK_YAML)
    return folder, config, dataset.ground_truth()


def test_their_folder_and_config_map_with_every_camera(extracted, text_embedder, tmp_path):
    folder, config, gt = extracted
    assert sorted(p.name for p in folder.glob("camera*_images")) == [
        "camera1_images",
        "camera2_images",
        "camera3_images",
    ]
    out = tmp_path / "field.terra"
    assert run(["map", str(folder), "--camera-config", str(config), "--out", str(out), "-q"]) == 0
    bundle = Bundle(out)
    stats = bundle.manifest["components"]["map"]["stats"]
    assert stats["images_fused"] == 3 * FRAMES and stats["frames_fused"] == FRAMES
    msm = load_map(bundle)
    assert msm.images.camera_names == ["cam1", "cam2", "cam3"]
    assert np.bincount(msm.images.camera).tolist() == [FRAMES] * 3
    # Points inside the simulator's object boxes carry their object's class.
    named = sorted({o.class_name for o in gt.objects})
    entry_class = np.array(named)[(msm.bank @ text_embedder.embed_text(named).T).argmax(axis=1)]
    best = msm.ms_max_ids()
    hits = total = 0
    for obj in gt.objects:
        if obj.class_name in ("building", "tree"):
            continue
        c, s = np.cos(obj.yaw), np.sin(obj.yaw)
        local = (msm.points - obj.center) @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        inside = np.all(np.abs(local) <= obj.size / 2 + 0.1, axis=1) & (best >= 0)
        hits += int(np.sum(entry_class[best[inside]] == obj.class_name))
        total += int(inside.sum())
    assert total > 200 and hits / total >= 0.95
