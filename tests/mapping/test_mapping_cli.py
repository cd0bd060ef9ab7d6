"""`terra map` / `terra info` on dataset folders: per-frame faults skipped and counted, structural
faults exit 2 with one line naming the file and leave the earlier bundle untouched, and a run
killed with SIGKILL resumes to the same bytes as an uninterrupted one."""

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.cli import run
from terra.sim.writer import write_dataset
from tests.mapping.fixtures import BoxScene, folder_digest


@pytest.fixture(scope="module")
def box_folder(tmp_path_factory) -> Path:
    """The box scene (6 frames, one camera, stamps 0..5 s) written as a terra-folder dataset."""
    return write_dataset(BoxScene(), tmp_path_factory.mktemp("boxdata") / "box", format="terra-folder", progress=False)


@pytest.fixture
def damaged(box_folder, tmp_path) -> Path:
    """A fresh copy of the box folder that a test may damage."""
    return Path(shutil.copytree(box_folder, tmp_path / "data"))


@pytest.fixture(scope="module")
def box_bundle(box_folder, tmp_path_factory, text_embedder) -> Path:
    out = tmp_path_factory.mktemp("boxmap") / "map.terra"
    assert run(["map", str(box_folder), "--out", str(out), "-q"]) == 0
    return out


def test_per_frame_faults_in_a_folder_are_skipped_and_counted(damaged, tmp_path, capsys, text_embedder):
    scans = sorted((damaged / "lidar_pc").glob("*.npy"))
    scans[1].write_bytes(b"\x93NUMPY garbage")  # corrupt file
    scan = np.load(scans[2])
    scan[:5, :3] = [np.nan, np.inf, -np.inf]
    np.save(scans[2], scan)  # non-finite points
    np.save(scans[3], np.zeros((0, 4), np.float32))  # empty scan
    labels = damaged / "lidar_labels" / scans[3].name.replace("lidar_pc", "lidar_labels")
    np.save(labels, np.zeros((0, 2), np.int32))
    # Frame 4's image is 0.15 s late: the folder reader still pairs it (its gap is 0.2 s), the
    # mapper's tolerance (0.1 s) rejects it.
    for folder, stem, ext in (
        ("camera1_images", "cam1_img", "jpg"),
        ("camera1_semantic", "cam1_sem", "png"),
        ("camera1_instance", "cam1_inst", "png"),
    ):
        (damaged / folder / f"{stem}_4.000000.{ext}").rename(damaged / folder / f"{stem}_4.150000.{ext}")
    out = tmp_path / "m.terra"
    assert run(["map", str(damaged), "--out", str(out)]) == 0
    stats = Bundle(out).manifest["components"]["map"]["stats"]
    assert stats["frames_skipped_unreadable"] == 1
    assert stats["points_dropped_nonfinite"] == 5
    assert stats["frames_skipped_empty"] == 1
    assert stats["images_skipped_unmatched_stamp"] == 1
    assert stats["frames_fused"] == 4 and stats["images_fused"] == 3
    printed = capsys.readouterr().out
    assert f"frames_skipped_unreadable: 1 (first: {scans[1]}:" in printed
    assert "images_skipped_unmatched_stamp: 1" in printed
    assert run(["info", str(out)]) == 0
    info = capsys.readouterr().out
    assert "skipped: frames_skipped_empty 1, frames_skipped_unreadable 1, images_skipped_unmatched_stamp 1" in info


def one_error_line(captured) -> str:
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in captured.err, captured.err
    return lines[0]


@pytest.mark.parametrize(
    "damage, names",
    [
        ("calibration", "terra_dataset.json"),
        ("all_scans", "lidar_pc_0.000000.npy"),
        ("missing", "no-such-folder"),
    ],
)
def test_structural_faults_exit_2_and_keep_the_old_bundle(damage, names, damaged, box_bundle, tmp_path, capsys):
    out = tmp_path / "m.terra"
    shutil.copytree(box_bundle, out)
    before = folder_digest(out)
    source = damaged
    if damage == "calibration":  # K of the wrong shape
        meta = json.loads((damaged / "terra_dataset.json").read_text())
        meta["cameras"][0]["K"] = [[100.0, 0.0], [0.0, 100.0]]
        (damaged / "terra_dataset.json").write_text(json.dumps(meta))
    elif damage == "all_scans":  # every scan has the wrong shape
        for scan in (damaged / "lidar_pc").glob("*.npy"):
            np.save(scan, np.zeros((10, 2), np.float32))
    else:
        source = tmp_path / "no-such-folder"
    capsys.readouterr()
    assert run(["map", str(source), "--out", str(out), "-q", "--overwrite"]) == 2  # replacing it fails: it stays
    line = one_error_line(capsys.readouterr())
    assert names in line
    assert folder_digest(out) == before
    Bundle(out).verify()


def test_info_reads_like_a_summary(box_bundle, capsys, text_embedder):
    capsys.readouterr()
    assert run(["info", str(box_bundle)]) == 0
    text = capsys.readouterr().out
    info = Bundle(box_bundle).manifest["components"]["map"]
    assert f"points: {info['points']} ({info['observed_points']} with object observations" in text
    assert f"bank entries: {info['bank']}   images: {info['images']}" in text
    assert f"embedder: {text_embedder.name} ({text_embedder.dim}-d)" in text
    assert "terrain points: grass " in text and "map " in text
    assert run(["info", str(box_bundle), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["map"]["points"] == info["points"]
    assert sum(summary["map"]["terrain_points"].values()) == info["points"]
    assert summary["bytes"]["map"] == Bundle(box_bundle).component_bytes()["map"]
    assert run(["info", str(box_bundle.parent / "nothing")]) == 2


def test_info_prints_the_scene_graph_as_lines(tiny_graph_bundle, capsys):
    from terra.graph.scene_graph import EDGE_BRIDGE, EDGE_CROSS_TERRAIN, EDGE_GVD
    from terra.graph.storage import load_scene_graph

    graph = load_scene_graph(tiny_graph_bundle)
    capsys.readouterr()
    assert run(["info", str(tiny_graph_bundle.path)]) == 0
    text = capsys.readouterr().out
    assert "{" not in text  # no raw JSON
    per_terrain = np.bincount(graph.places.terrain, minlength=len(graph.terrain_classes))
    expected = ", ".join(f"{name} {n}" for name, n in zip(graph.terrain_classes, per_terrain))
    assert f"graph: {len(graph.places)} places, {len(graph.place_edges)} place edges" in text
    assert f"places per terrain: {expected}" in text
    assert "regions per level" in text and ", ".join(str(len(level)) for level in graph.regions) in text
    kinds = {
        name: int(np.count_nonzero(graph.place_edge_kind == kind))
        for name, kind in (("gvd", EDGE_GVD), ("cross_terrain", EDGE_CROSS_TERRAIN), ("bridge", EDGE_BRIDGE))
    }
    edge_line = next(line for line in text.splitlines() if "edges by kind:" in line)
    assert all(f"{name} {n}" in edge_line for name, n in kinds.items())
    sources = next(line for line in text.splitlines() if "place embeddings from:" in line).split(":")[1]
    assert "images" in sources and sum(int(part.split()[1]) for part in sources.split(",")) == len(graph.places)


def test_killed_process_resumes_to_the_same_bytes(tiny_bundle, tmp_path, capsys):
    """SIGKILL a `terra map` child after its first checkpoint; rerunning finishes from there and
    every array equals the uninterrupted session map's (only the recorded config differs)."""
    config = tmp_path / "terra.yaml"
    config.write_text("mapping:\n  checkpoint_every: 8\n")
    out = tmp_path / "map.terra"
    argv = ["map", "--sim", "tiny", "--out", str(out), "--config", str(config), "-q"]
    child = subprocess.Popen(
        [sys.executable, "-m", "terra", *argv],
        cwd=Path(__file__).parents[2],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    state = tmp_path / "map.terra.partial" / "state" / "manifest.json"
    deadline = time.monotonic() + 120
    while not state.is_file() and child.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    child.send_signal(signal.SIGKILL)  # a no-op when the child has already exited
    child.wait()
    assert child.stderr is not None  # stderr=PIPE
    assert child.returncode == -signal.SIGKILL, child.stderr.read().decode()
    assert state.is_file() and not out.exists()
    capsys.readouterr()
    assert run(argv[:-1]) == 0  # not quiet: it says where it resumed
    assert "resumed after frame 8" in capsys.readouterr().out
    resumed, uninterrupted = folder_digest(out), folder_digest(tiny_bundle.path)
    assert set(resumed) == set(uninterrupted)
    assert {k for k in resumed if resumed[k] != uninterrupted[k]} <= {"manifest.json"}
    assert not state.parent.parent.exists()


def test_noise_preset_is_recorded_and_changes_the_map(box_folder, box_bundle, tmp_path, text_embedder):
    from terra.perception.config import NOISE_PRESETS

    out = tmp_path / "noisy.terra"
    assert run(["map", str(box_folder), "--out", str(out), "--noise", "realistic", "-q"]) == 0
    noisy = Bundle(out).manifest["components"]["map"]["config"]["perception"]["noise"]
    clean = Bundle(box_bundle).manifest["components"]["map"]["config"]["perception"]["noise"]
    assert {k: noisy[k] for k in NOISE_PRESETS["realistic"]} == NOISE_PRESETS["realistic"]
    assert clean["dilate_px"] == 0 and clean["miss_rate"] == 0 and clean["confusion_rate"] == 0
    # The noise reached the fusion: the observations differ from the noise-free map's.
    changed = {
        k for k, v in folder_digest(out).items() if k.startswith("map/counts") and v != folder_digest(box_bundle).get(k)
    }
    assert changed
    assert Bundle(out).manifest["embedder"] == {"name": text_embedder.name, "dim": text_embedder.dim}


def test_info_names_a_damaged_file_and_exits_2(box_bundle, tmp_path, capsys, text_embedder):
    """Same size, one byte changed: only the checksum can tell, and `terra info` checks it."""
    copy = tmp_path / "copy.terra"
    shutil.copytree(box_bundle, copy)
    capsys.readouterr()
    assert run(["info", str(copy)]) == 0
    assert (
        f"checksums: {len(Bundle(copy).files)} files checked against the manifest, all intact"
        in capsys.readouterr().out
    )
    bank = copy / "map" / "bank.npy"
    data = bytearray(bank.read_bytes())
    data[-1] ^= 0xFF
    bank.write_bytes(bytes(data))
    assert run(["info", str(copy)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert str(bank) in one_error_line(captured) and "checksum" in one_error_line(captured)
