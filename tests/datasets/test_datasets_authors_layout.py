"""The authors' folder layout exactly: cameras numbered from 1 in file names and config keys,
their msmap configs read as they are (4- and 14-coefficient lenses, keys that are not about
cameras ignored), earlier 0-based Terra folders still read, and a calibration that contradicts
the image folders is one line naming both, never a silent LiDAR-only run."""

import json
import shutil

import numpy as np
import pytest
import yaml
from PIL import Image

from terra.cli import run
from terra.datasets import open_dataset
from terra.datasets.msmap_config import read_msmap_config
from terra.datasets.terra_folder import TerraFolderDataset
from terra.errors import TerraError
from terra.sim.writer import write_dataset
from tests.datasets.fixtures_authors import HEIGHT, NUNNS_PARK_YAML, SSP_YAML, WIDTH, AuthorsRig, rig

RIGS = {"two cameras, 4 coefficients": (SSP_YAML, 2), "three cameras, 14 coefficients": (NUNNS_PARK_YAML, 3)}


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    root = tmp_path_factory.mktemp("authors")
    out = {}
    for name, (text, count) in RIGS.items():
        folder = write_dataset(AuthorsRig(text, count), root / name.replace(" ", "_").replace(",", ""), progress=False)
        (folder.parent / f"{folder.name}.yaml").write_text(text)
        out[name] = (folder, folder.parent / f"{folder.name}.yaml")
    return out


@pytest.fixture
def copy(written, tmp_path):
    def make(name):
        folder, config = written[name]
        return shutil.copytree(folder, tmp_path / "data"), config

    return make


def test_their_configs_read_as_they_are(tmp_path):
    for text, coefficients in ((SSP_YAML, 4), (NUNNS_PARK_YAML, 14)):
        path = tmp_path / "msmap_multicam.yaml"
        path.write_text(text)
        cfg = read_msmap_config(path)
        raw = yaml.safe_load(text)
        assert cfg.numbers == [1, 2, 3] and cfg.axes == ["-x", "-y", "+y"] and cfg.unaligned_threshold == 0.05
        for n, cam in zip(cfg.numbers, cfg.cameras):
            assert (cam.width, cam.height) == (768, 480) and cam.model == "pinhole"
            assert cam.K.ravel().tolist() == raw[f"cam{n}_K"]
            assert cam.dist.tolist() == raw[f"cam{n}_dist"] and cam.dist.size == coefficients


@pytest.mark.parametrize("name", sorted(RIGS))
def test_round_trip_in_the_authors_layout(written, name):
    folder, _ = written[name]
    text, count = RIGS[name]
    expected = AuthorsRig(text, count)
    cfg = yaml.safe_load((folder / "msmap_camera_config.yaml").read_text())
    assert list(cfg) == ["num_cams", "IMG_W", "IMG_H"] + [
        f"cam{n}_{k}" for n in range(1, count + 1) for k in ("K", "dist")
    ] + ["cam_axis"]
    assert cfg["num_cams"] == count and (cfg["IMG_W"], cfg["IMG_H"]) == (WIDTH, HEIGHT)
    assert cfg["cam_axis"] == ["-x", "-y", "+y"][:count]
    for n, cam in enumerate(rig(text, count), start=1):
        assert cfg[f"cam{n}_K"] == cam.K.ravel().tolist() and cfg[f"cam{n}_dist"] == cam.dist.tolist()
        stamps = sorted(
            float(p.stem.rsplit("_", 1)[1]) for p in (folder / f"camera{n}_images").glob(f"cam{n}_img_*.jpg")
        )
        assert [f"{t:.6f}" for t in stamps] == ["100.000000", "100.250000", "100.625000"]
        assert len(list((folder / f"transformations_lidar2cam{n}").glob(f"transform_lidar_to_cam{n}_*.npy"))) == 3
    assert not (folder / "camera0_images").exists() and not (folder / f"camera{count + 1}_images").exists()
    ds = open_dataset(folder)
    assert isinstance(ds, TerraFolderDataset)
    assert ds.camera_numbers == list(range(1, count + 1))
    for i, frame in enumerate(expected.frames):
        got = ds[i]
        for cam, exp in zip(got.cameras, frame.cameras):
            assert cam.calibration.dist.tolist() == exp.calibration.dist.tolist()  # every coefficient, exactly
            np.testing.assert_array_equal(cam.calibration.K, exp.calibration.K)
            np.testing.assert_array_equal(cam.calibration.T_cam_lidar, exp.calibration.T_cam_lidar)
            np.testing.assert_array_equal(cam.semantic, exp.semantic)
            assert cam.name.startswith(f"camera{exp.calibration.name[3:]}_images/cam{exp.calibration.name[3:]}_img_")


@pytest.mark.parametrize("name", sorted(RIGS))
def test_folder_as_their_tools_write_it_reads_with_their_config(copy, name, tmp_path):
    """No Terra metadata: intrinsics from their YAML as it is, extrinsics from the per-scan files,
    scans paired within their unaligned_threshold (0.05 s)."""
    folder, config = copy(name)
    text, count = RIGS[name]
    for extra in ("terra_dataset.json", "msmap_camera_config.yaml"):
        (folder / extra).unlink()
    with pytest.raises(
        TerraError, match=r"has images \(camera1_images/, .*\) but no camera calibration .* --camera-config"
    ):
        open_dataset(folder)  # images and no calibration: never a LiDAR-only run
    if count == 2:  # their file describes three cameras; this rig has two
        with pytest.raises(
            TerraError,
            match=r"yaml: calibrates cameras 1, 2, 3 but .* has image folders camera1_images/, "
            r"camera2_images/: no images for camera 3$",
        ):
            open_dataset(folder, options={"camera_config": config})
        trimmed = tmp_path / "two.yaml"
        trimmed.write_text(text.replace("num_cams: 3", "num_cams: 2").replace("['-x', '-y', '+y']", "['-x', '-y']"))
        config = trimmed
    ds = open_dataset(folder, options={"camera_config": config})
    assert isinstance(ds, TerraFolderDataset)
    assert ds.max_gap == 0.05 and ds.camera_source == str(config) and len(ds) == 3
    for got, exp in zip(ds[1].cameras, rig(text, count)):
        assert got.calibration.name == exp.name and got.calibration.dist.tolist() == exp.dist.tolist()
        np.testing.assert_array_equal(got.calibration.K, exp.K)
        np.testing.assert_allclose(got.calibration.T_cam_lidar, exp.T_cam_lidar, atol=1e-12)


def test_earlier_zero_based_terra_folders_still_read(copy):
    folder, _ = copy("three cameras, 14 coefficients")
    expected = open_dataset(folder)[2]
    for n in (1, 2, 3):  # rename camera n to camera n-1, in folders and in file names
        for (
            kind,
            stem,
        ) in (("images", "img"), ("semantic", "sem"), ("instance", "inst")):
            target = folder / f"camera{n - 1}_{kind}"
            (folder / f"camera{n}_{kind}").rename(target)
            for p in target.iterdir():
                p.rename(p.with_name(p.name.replace(f"cam{n}_{stem}_", f"cam{n - 1}_{stem}_")))
        target = folder / f"transformations_lidar2cam{n - 1}"
        (folder / f"transformations_lidar2cam{n}").rename(target)
        for p in target.iterdir():
            p.rename(p.with_name(p.name.replace(f"to_cam{n}_", f"to_cam{n - 1}_")))
    meta = json.loads((folder / "terra_dataset.json").read_text())
    del meta["first_camera"]
    meta["version"] = 1
    (folder / "terra_dataset.json").write_text(json.dumps(meta))
    cfg = yaml.safe_load((folder / "msmap_camera_config.yaml").read_text())
    old = {"IMG_W": cfg["IMG_W"], "IMG_H": cfg["IMG_H"]}
    for n in (1, 2, 3):
        old[f"cam{n - 1}_K"], old[f"cam{n - 1}_dist"] = cfg[f"cam{n}_K"], cfg[f"cam{n}_dist"]
    (folder / "msmap_camera_config.yaml").write_text(yaml.safe_dump(old))
    for without_meta in (False, True):
        if without_meta:
            (folder / "terra_dataset.json").unlink()
        ds = open_dataset(folder)
        assert isinstance(ds, TerraFolderDataset)
        assert ds.camera_numbers == [0, 1, 2]
        got = ds[2]
        for cam, exp in zip(got.cameras, expected.cameras):
            assert cam.calibration.dist.tolist() == exp.calibration.dist.tolist()
            np.testing.assert_allclose(cam.calibration.T_cam_lidar, exp.calibration.T_cam_lidar, atol=1e-12)
            np.testing.assert_array_equal(cam.semantic, exp.semantic)


def test_image_folder_without_calibration_is_named(copy):
    folder, config = copy("three cameras, 14 coefficients")
    extra = folder / "camera4_images"
    extra.mkdir()
    shutil.copy(next((folder / "camera1_images").iterdir()), extra / "cam4_img_100.000000.jpg")
    with pytest.raises(
        TerraError,
        match=r"calibrates cameras 1, 2, 3 but .* has image folders camera1_images/, camera2_images/, "
        r"camera3_images/, camera4_images/: no calibration for camera4_images/$",
    ):
        open_dataset(folder, options={"camera_config": config})


def bad_config(path, text):
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            ("0.0, 0.0, 0.0, -0.0008460935787297785, 0.004733051639050245]", "0.0, 0.0, 0.0, -0.0008460935787297785]"),
            r":25: cam2_dist: pinhole lens: 13 distortion coefficients; supported lengths: 0, 4, 5, 8, 12, 14$",
        ),
        (
            (
                "-0.29829320311546326, 1.9814714193344116, 0.0,\n"
                "        0.0, 0.0, 0.0, -0.0008460935787297785, 0.004733051639050245]",
                "-0.29829320311546326]",
            ),
            r":25: cam2_dist: pinhole lens: 7 distortion coefficients; supported lengths: 0, 4, 5, 8, 12, 14$",
        ),
        (
            ("cam1_K: [453.9425964355469, 0.0, 388.0409851074219,", "cam1_K: [453.9425964355469, 0.0,"),
            r":14: cam1_K has 8 numbers, expected 9",
        ),
        (("IMG_W: 768\n", ""), r"yaml: no IMG_W \(image width in pixels"),
        (("cam_axis: ['-x', '-y', '+y']", "cam_axis: ['-x', '-y']"), r":49: cam_axis has 2 entries for 3 cameras"),
        (("num_cams: 3", "num_cams: 4"), r":4: num_cams is 4 but there is no cam4_K"),
        (
            ("cam3_dist:", "cam3_distortion:"),
            r"yaml: no cam3_dist \(OpenCV distortion coefficients; write cam3_dist: \[\] for none\)",
        ),
        (
            ("cam1_K: [453.9425964355469,", "cam1_K: [-453.9425964355469,"),
            r":14: cam1_K: K must be finite with positive focal lengths",
        ),
    ],
)
def test_bad_camera_config_names_file_line_and_key(copy, tmp_path, edit, message):
    folder, _ = copy("three cameras, 14 coefficients")
    assert edit[0] in NUNNS_PARK_YAML
    config = bad_config(tmp_path / "msmap.yaml", NUNNS_PARK_YAML.replace(*edit))
    with pytest.raises(TerraError, match=message) as info:
        open_dataset(folder, options={"camera_config": config})
    assert str(info.value).startswith(str(config)) and "\n" not in str(info.value)


def test_image_size_contradicting_img_w_img_h(copy, tmp_path):
    folder, _ = copy("three cameras, 14 coefficients")
    config = bad_config(tmp_path / "msmap.yaml", NUNNS_PARK_YAML.replace("IMG_H: 480", "IMG_H: 512"))
    first = sorted((folder / "camera1_images").iterdir())[0]
    with pytest.raises(TerraError, match=rf"^{first}: image is 768x480, but {config} says 768x512 \(IMG_W x IMG_H\)$"):
        open_dataset(folder, options={"camera_config": config})
    with Image.open(first) as im:
        im.resize((640, 480)).save(first)
    with pytest.raises(TerraError, match=r"image is 640x480, but .*terra_dataset.json says 768x480"):
        open_dataset(folder)


def test_map_with_a_bad_camera_config_is_one_line_and_writes_nothing(copy, tmp_path, capsys):
    folder, _ = copy("three cameras, 14 coefficients")
    config = bad_config(
        tmp_path / "msmap.yaml",
        NUNNS_PARK_YAML.replace("num_cams: 3", "num_cams: 2").replace("['-x', '-y', '+y']  #", "['-x', '-y']  #"),
    )
    out = tmp_path / "map.terra"
    assert run(["map", str(folder), "--camera-config", str(config), "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no calibration for camera3_images/" in err[0]
    assert not out.exists() and not (tmp_path / "map.terra.partial").exists()
    assert (
        run(["map", str(folder), "--camera-config", str(config), "--format", "semantickitti", "--out", str(out), "-q"])
        == 2
    )
    assert "--camera-config is for terra-folder datasets" in capsys.readouterr().err


def test_cameras_of_different_sizes_are_refused_by_the_authors_layout(tmp_path):
    from dataclasses import replace

    ds = AuthorsRig(SSP_YAML, 2)
    for frame in ds.frames:
        cam = frame.cameras[1]
        small = replace(cam.calibration, width=384, height=240)
        frame.cameras[1] = replace(
            cam,
            calibration=small,
            image=cam.image[::2, ::2],
            semantic=cam.semantic[::2, ::2],
            instance=cam.instance[::2, ::2],
        )
    with pytest.raises(
        TerraError, match=r"one image size \(IMG_W x IMG_H\) for all cameras, got \[\(384, 240\), \(768, 480\)\]"
    ):
        write_dataset(ds, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_folder_dataset_class_is_the_reader(written):
    assert isinstance(open_dataset(written["two cameras, 4 coefficients"][0]), TerraFolderDataset)


def test_fisheye_lenses_keep_their_model_in_the_authors_config(tmp_path):
    """Their keys cannot name a lens model: Terra adds cam<n>_model (ignored by their scripts), so a
    folder read from its YAML alone keeps the equidistant model and its four coefficients."""
    from dataclasses import replace

    ds = AuthorsRig(SSP_YAML, 2)
    fisheye = [0.0215, -0.0087, 0.0031, -0.0008]
    for frame in ds.frames:
        frame.cameras[1] = replace(
            frame.cameras[1], calibration=replace(frame.cameras[1].calibration, model="fisheye", dist=fisheye)
        )
    folder = write_dataset(ds, tmp_path / "fish", progress=False)
    cfg = yaml.safe_load((folder / "msmap_camera_config.yaml").read_text())
    assert cfg["cam2_model"] == "fisheye" and "cam1_model" not in cfg and cfg["cam2_dist"] == fisheye
    (folder / "terra_dataset.json").unlink()
    cams = open_dataset(folder)[0].cameras
    assert [c.calibration.model for c in cams] == ["pinhole", "fisheye"] and cams[
        1
    ].calibration.dist.tolist() == fisheye
