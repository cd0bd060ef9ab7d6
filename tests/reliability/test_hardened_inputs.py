"""The representative failures of issue 13, each reproduced on a tiny bundle or dataset (3 simulated
frames, tests/reliability/fixtures.py) and each now one line with exit code 2 that names the file,
or, for per-frame faults, a skipped and counted frame. "Re-signed": the manifest's size and SHA-256
updated to match the mutated file, so only the content checks can catch it."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from tests.mapping.fixtures import folder_digest
from tests.reliability.fuzzing import cli, resign

REPO = Path(__file__).resolve().parents[2]
QUERY = "find the dumpster"


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("terra: error: "), err
    return lines[0]


def refused(argv: list, *fragments: str) -> str:
    """Run argv in process: exit 2, one line holding every fragment."""
    code, _, err = cli(argv)
    assert code == 2, err
    line = one_line(err)
    for fragment in fragments:
        assert fragment in line, line
    return line


@pytest.fixture
def bundle(reliability_seeds, tmp_path) -> Path:
    return Path(shutil.copytree(reliability_seeds.bundle, tmp_path / "B.terra"))


def save_array(bundle: Path, name: str, array: np.ndarray, sign: bool = True) -> None:
    np.save(bundle / name, array, allow_pickle=False)
    if sign:
        resign(bundle, name)


def edit_json(path: Path, change) -> None:
    value = json.loads(path.read_text())
    change(value)
    path.write_text(json.dumps(value, allow_nan=True))


# ---------------------------------------------------------------------------------- crashes
@pytest.mark.parametrize("mutation", ["negative indices", "int8 indptr"])
def test_corrupt_sparse_counts_are_refused_not_a_segfault(bundle, mutation):
    """In a subprocess: before, SciPy's compiled kernels read out of bounds (exit 139)."""
    if mutation == "negative indices":
        indices = np.load(bundle / "map/counts_indices.npy")
        indices[::7] = -(2**31)
        save_array(bundle, "map/counts_indices.npy", indices)
    else:
        save_array(bundle, "map/counts_indptr.npy", np.load(bundle / "map/counts_indptr.npy").astype(np.int8))
    done = subprocess.run(
        [sys.executable, "-m", "terra", "find", str(bundle), QUERY],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2, done.stderr
    assert "map/counts_" in one_line(done.stderr)


def test_a_non_monotonic_row_pointer_is_refused(bundle):
    indptr = np.load(bundle / "map/counts_indptr.npy")
    indptr[5], indptr[6] = indptr[6] + 3, indptr[5]
    save_array(bundle, "map/counts_indptr.npy", indptr)
    refused(["find", bundle, QUERY], "row pointer decreases")


# ---------------------------------------------------------------------------------- manifest
@pytest.mark.parametrize(
    "change,fragment",
    [
        ("null", "expected a JSON object"),
        (lambda m: m["files"].update({"map/points.npy": [1, 2]}), "field 'files.map/points.npy'"),
        (lambda m: m["files"]["map/points.npy"].pop("bytes"), "files.map/points.npy.bytes"),
        (lambda m: m["components"].update({"graph": "x"}), "field 'components.graph'"),
        (lambda m: m.update({"terrain_classes": [1, 2]}), "terrain_classes"),
        (lambda m: m.update({"embedder": {"name": "x", "dim": -3}}), "embedder.dim"),
    ],
)
def test_a_malformed_manifest_is_one_line(bundle, change, fragment):
    path = bundle / "manifest.json"
    if change == "null":
        path.write_text("null")
    else:
        edit_json(path, change)
    for argv in (["info", bundle], ["find", bundle, QUERY]):
        refused(argv, "manifest.json", fragment)


def test_map_metadata_null_and_a_scene_graph_metadata_list_are_one_line(bundle):
    (bundle / "map/meta.json").write_text("null")
    resign(bundle, "map/meta.json")
    refused(["find", bundle, QUERY], "map/meta.json")
    refused(["info", bundle], "map/meta.json")
    graph = bundle / "graph/scene_graph.json"
    edit_json(graph, lambda d: d["metadata"].update({"terra": [1, 2]}))
    resign(bundle, "graph/scene_graph.json")
    refused(["plan", bundle, "--from-node", "0", "--to-node", "3"], "scene_graph.json", "metadata.terra")


def test_a_file_entry_outside_the_bundle_is_refused_and_nothing_is_written_outside(bundle):
    edit_json(
        bundle / "manifest.json", lambda m: m["files"].update({"../escape/x.npy": {"bytes": 1, "sha256": "0" * 64}})
    )
    before = sorted(os.listdir(bundle.parent))
    refused(["build", bundle, "-q", "--overwrite"], "../escape/x.npy")
    assert sorted(os.listdir(bundle.parent)) == before and not (bundle.parent / "escape").exists()


def test_a_bundle_file_that_links_out_of_the_bundle_is_refused(bundle, tmp_path):
    outside = tmp_path / "outside.npy"
    shutil.copy(bundle / "map/points.npy", outside)
    (bundle / "map/points.npy").unlink()
    (bundle / "map/points.npy").symlink_to(outside)
    refused(["find", bundle, QUERY], "map/points.npy", "not a regular file inside the bundle")


# ---------------------------------------------------------------------------------- nesting
DEEP_JSON = "[" * 3000 + "]" * 3000
DEEP_YAML = "- " * 3000 + "x\n"


def test_deeply_nested_json_is_one_line(bundle, reliability_seeds, tmp_path):
    (bundle / "manifest.json").write_text(DEEP_JSON)
    refused(["info", bundle], "manifest.json", "nested too deeply")
    for name, fmt in (("classes.json", "semantickitti"), ("terra_dataset.json", "terra-folder")):
        data = Path(shutil.copytree(reliability_seeds.datasets[fmt], tmp_path / f"{fmt}-deep"))
        (data / name).write_text(DEEP_JSON)
        refused(["inspect", data], name, "nested too deeply")


def test_deeply_nested_yaml_is_one_line(bundle, reliability_seeds, tmp_path):
    deep = tmp_path / "deep.yaml"
    deep.write_text(DEEP_YAML)
    refused(["find", bundle, "--tasks", deep], "deep.yaml", "nested too deeply")
    refused(["find", bundle, QUERY, "--config", deep], "deep.yaml", "nested too deeply")
    data = Path(shutil.copytree(reliability_seeds.datasets["terra-folder"], tmp_path / "tf"))
    refused(["map", data, "--camera-config", deep, "--out", tmp_path / "o.terra"], "deep.yaml", "nested too deeply")
    kitti = Path(shutil.copytree(reliability_seeds.datasets["semantickitti"], tmp_path / "sk"))
    (kitti / "semantic-kitti.yaml").write_text(DEEP_YAML)
    refused(["inspect", kitti], "semantic-kitti.yaml", "nested too deeply")


def test_yaml_aliases_that_expand_to_billions_of_values_are_refused(bundle, tmp_path):
    lines = ["a: &a [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]"]
    for level in "bcdefghi":
        previous = chr(ord(level) - 1)
        lines.append(f"{level}: &{level} [" + ", ".join([f"*{previous}"] * 10) + "]")
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("\n".join(lines) + "\n")
    refused(["find", bundle, "--tasks", bomb], "aliases are expanded")


# ---------------------------------------------------------------------------------- encoding
def test_files_that_are_not_utf8_are_one_line(bundle, reliability_seeds, tmp_path):
    bad = tmp_path / "t.yaml"
    bad.write_bytes(b"\xff")
    refused(["find", bundle, QUERY, "--tasks", bad], "t.yaml", "not UTF-8")
    refused(["find", bundle, QUERY, "--config", bad], "t.yaml", "not UTF-8")
    data = Path(shutil.copytree(reliability_seeds.datasets["terra-folder"], tmp_path / "tf"))
    refused(["map", data, "--camera-config", bad, "--out", tmp_path / "o.terra"], "not UTF-8")
    kitti = Path(shutil.copytree(reliability_seeds.datasets["semantickitti"], tmp_path / "sk"))
    (kitti / "sequences/00/calib.txt").write_bytes(b"P0: 1 0 0\xff\n")
    refused(["inspect", kitti], "calib.txt", "not UTF-8")


# ---------------------------------------------------------------------------------- arrays
def test_an_empty_npy_names_the_file_instead_of_aborting(bundle):
    (bundle / "map/points.npy").write_bytes(b"")
    resign(bundle, "map/points.npy")
    refused(["build", bundle, "-q", "--overwrite"], "map/points.npy", "not a readable .npy array")


def test_a_header_claiming_a_huge_shape_is_refused_before_allocating(bundle):
    """(10^12, 3) float32 is 10.9 TiB: checked against the manifest (and the file size) first."""
    (bundle / "map/points.npy").write_bytes(_reheader((bundle / "map/points.npy").read_bytes(), "(1000000000000, 3)"))
    resign(bundle, "map/points.npy")
    refused(["find", bundle, QUERY], "map/points.npy", "1000000000000")


def _reheader(data: bytes, shape: str) -> bytes:
    """`data` (a .npy v1.0 file) with its header's shape replaced and the header re-padded."""
    length = int.from_bytes(data[8:10], "little")
    header = data[10 : 10 + length].decode("latin1")
    start = header.index("'shape': ") + len("'shape': ")
    end = header.index(")", start) + 1
    new = (header[:start] + shape + header[end:]).rstrip("\n").rstrip()
    new = new + " " * ((64 - (10 + len(new) + 1) % 64) % 64) + "\n"
    return data[:8] + len(new).to_bytes(2, "little") + new.encode("latin1") + data[10 + length :]


def test_a_flipped_header_byte_is_one_line(bundle):
    data = bytearray((bundle / "map/bank.npy").read_bytes())
    data[20] = ord("(")  # inside the header dict: numpy's literal parser (ast / tokenize) fails
    (bundle / "map/bank.npy").write_bytes(bytes(data))
    resign(bundle, "map/bank.npy")
    refused(["find", bundle, QUERY], "map/bank.npy")


@pytest.mark.parametrize(
    "name,change,fragment",
    [
        (
            "map/points.npy",
            lambda a: np.where(np.arange(a.size).reshape(a.shape) % 5 == 0, np.nan, a).astype(a.dtype),
            "NaN",
        ),
        ("map/terrain_votes.npy", lambda a: a[:, 0].copy(), "array of shape"),
        ("map/visibility/indptr.npy", lambda a: a[:-1].copy(), "visibility"),
        ("map/visibility/images.npy", lambda a: a + 10_000, "visibility"),
        ("map/images/T_map_cam.npy", lambda a: a[:0].copy(), "T_map_cam.npy"),
        ("map/points.npy", lambda a: np.zeros(a.shape, "M8[s]"), "datetime64"),
        ("map/counts_data.npy", lambda a: a.astype(np.float32), "counts_data.npy"),
        ("map/ms_max_id.npy", lambda a: a + 1000, "ms_max_id.npy"),
    ],
)
def test_malformed_map_arrays_are_one_line(bundle, name, change, fragment):
    save_array(bundle, name, change(np.load(bundle / name)))
    refused(["build", bundle, "-q", "--overwrite"], fragment)


def test_an_empty_place_embedding_is_one_line(bundle):
    save_array(bundle, "graph/place_embedding.npy", np.load(bundle / "graph/place_embedding.npy")[:0])
    refused(["find", bundle, QUERY, "--method", "3dsg"], "graph/place_embedding.npy")


# ---------------------------------------------------------------------------------- scene graph
def _graph_edit(bundle: Path, change) -> None:
    edit_json(bundle / "graph/scene_graph.json", change)
    resign(bundle, "graph/scene_graph.json")


def _first(doc: dict, char: str) -> dict:
    return next(n for n in doc["nodes"] if chr(n["id"] >> 56) == char)


@pytest.mark.parametrize(
    "change,fragment",
    [
        (lambda d: _first(d, "p").update({"id": 1.5}), "nodes.0.id"),
        (lambda d: d["metadata"]["terra"].update({"terrain_classes": []}), "terrain_classes"),
        (
            lambda d: d.update({"nodes": [n for n in d["nodes"] if chr(n["id"] >> 56) != "R"]}),
            "node ids of symbol 'R' must be those of its id array",
        ),
        (lambda d: d["edges"][0].update({"target": float("inf")}), "Infinity is not a JSON number"),
        (lambda d: d["edges"][0].update({"target": 2**70}), "edges.0.target"),
        (
            lambda d: d.update({"edges": [e for e in d["edges"] if chr(e["source"] >> 56) != "R"]}),
            "have no parent there",
        ),
        (lambda d: _first(d, "p")["attributes"].update({"position": [float("nan"), 0.0, 0.0]}), "not valid JSON"),
        (lambda d: d["edges"][0].update({"target": d["edges"][0]["source"]}), "edge 0"),
    ],
)
def test_a_malformed_scene_graph_is_one_line(bundle, change, fragment):
    _graph_edit(bundle, change)
    for argv in (["plan", bundle, "--from-node", "0", "--to-node", "3"], ["monitor", bundle, "the parking lot"]):
        refused(argv, "scene_graph.json", fragment)


def test_a_json_number_beyond_float_range_is_one_line(bundle):
    path = bundle / "graph/scene_graph.json"
    path.write_text(path.read_text().replace('"weight": ', '"weight": 1e400, "w": ', 1))
    resign(bundle, "graph/scene_graph.json")
    refused(["plan", bundle, "--from-node", "0", "--to-node", "3"], "1e400")


# ---------------------------------------------------------------------------------- datasets
def _png_declaring(width: int, height: int) -> bytes:
    import struct
    import zlib

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"\0" * 16)) + chunk(b"IEND", b"")
    )


@pytest.fixture
def kitti(reliability_seeds, tmp_path) -> Path:
    return Path(shutil.copytree(reliability_seeds.datasets["semantickitti"], tmp_path / "kitti"))


def _mapped_with_skips(source: Path, out: Path) -> str:
    code, stdout, err = cli(["map", source, "--out", out])
    assert code == 0, err
    from terra.bundle import Bundle

    Bundle(out).verify()
    return stdout


def test_a_png_declaring_20000_by_20000_pixels_skips_its_frame(kitti, tmp_path):
    (kitti / "sequences/00/image_2/000001.png").write_bytes(_png_declaring(20000, 20000))
    stdout = _mapped_with_skips(kitti, tmp_path / "o.terra")
    assert "frames_skipped_unreadable: 1" in stdout and "declares more pixels than" in stdout


def test_a_class_id_of_10_to_the_12_is_refused(kitti, tmp_path):
    edit_json(kitti / "classes.json", lambda c: c["classes"][1].update({"id": 10**12}))
    refused(["map", kitti, "--out", tmp_path / "o.terra"], "classes.json", "classes.1.id")


def test_a_label_png_that_is_a_32_bit_tiff_skips_its_frame(kitti, tmp_path):
    from PIL import Image

    Image.fromarray(np.full((4, 4), 2**31 - 5, np.int32), mode="I").save(
        kitti / "sequences/00/image_2_semantic/000001.png", format="TIFF"
    )
    stdout = _mapped_with_skips(kitti, tmp_path / "o.terra")
    assert "frames_skipped_unreadable: 1" in stdout and "not a PNG image" in stdout


@pytest.mark.parametrize("values,fragment", [("0 " * 12, "is not a camera projection"), ("nan " * 12, "non-finite")])
def test_a_singular_or_nan_projection_is_one_line(kitti, tmp_path, values, fragment):
    (kitti / "sequences/00/terra_cameras.json").unlink()  # so the cameras come from P2
    calib = kitti / "sequences/00/calib.txt"
    calib.write_text(
        "\n".join(f"P2: {values}" if line.startswith("P2") else line for line in calib.read_text().splitlines()) + "\n"
    )
    refused(["inspect", kitti], "calib.txt:3", "P2", fragment)


@pytest.mark.parametrize("kind", ["folder", "fifo", "unreadable"])
def test_a_scan_that_cannot_be_read_skips_its_frame_without_blocking(kitti, tmp_path, kind):
    scan = kitti / "sequences/00/velodyne/000000.bin"
    scan.unlink()
    if kind == "folder":
        scan.mkdir()
    elif kind == "fifo":
        os.mkfifo(scan)
    else:
        scan.write_bytes(b"\0" * 7)  # not a whole number of float32 values
    result: list = []
    run = threading.Thread(target=lambda: result.append(_mapped_with_skips(kitti, tmp_path / "o.terra")), daemon=True)
    run.start()
    run.join(120)
    assert result, "terra map blocked on the scan"
    assert "frames_skipped_unreadable: 1" in result[0]


def test_a_bag_whose_metadata_lists_a_fifo_is_refused_without_blocking(reliability_seeds, tmp_path):
    bag = Path(shutil.copytree(reliability_seeds.datasets["rosbag2"], tmp_path / "bag"))
    storage = next(bag.glob("*.mcap"))
    storage.unlink()
    os.mkfifo(storage)
    refused(["inspect", bag], "metadata.yaml", storage.name)


# ---------------------------------------------------------------------------------- config
@pytest.mark.parametrize(
    "text,command,fragment",
    [
        ("build: [1, 2]\n", "build", "field 'build' must be a mapping"),
        ("tasks: 9223372036854775808\n", "find", "field 'tasks' must be a mapping"),
        ("tasks:\n  retrieval:\n    default_alpha: .nan\n", "find", "finite number"),
        ("1: 2\n", "find", "unknown top-level key '1'"),
    ],
)
def test_malformed_configs_are_one_line(bundle, tmp_path, text, command, fragment):
    config = tmp_path / "c.yaml"
    config.write_text(text)
    argv = ["build", bundle, "-q", "--overwrite"] if command == "build" else ["find", bundle, QUERY]
    refused(argv + ["--config", config], "c.yaml", fragment)


@pytest.mark.parametrize("constant", ["NaN", "Infinity"])
def test_nan_in_the_manifests_stored_config_is_one_line(bundle, constant):
    path = bundle / "manifest.json"
    text = path.read_text().replace('"voxel_size": 0.4', f'"voxel_size": {constant}', 1)
    assert constant in text
    path.write_text(text)
    before = folder_digest(bundle)
    refused(["build", bundle, "-q", "--overwrite"], "manifest.json", constant)
    refused(["find", bundle, QUERY, "--save"], "manifest.json", constant)
    assert folder_digest(bundle) == before


# ---------------------------------------------------------------------------------- disks, resume
def test_a_full_disk_during_map_keeps_the_checkpoint_and_the_rerun_resumes(reliability_seeds, tmp_path, monkeypatch):
    import errno

    import terra.bundle as bundle_module

    config = tmp_path / "c.yaml"
    config.write_text("mapping:\n  checkpoint_every: 1\n")
    out = tmp_path / "o.terra"
    argv = ["map", reliability_seeds.datasets["terra-folder"], "--out", out, "-q", "-c", config]
    real = bundle_module._write_new_file

    def full(path, data, mode=0o666, **options):
        if ".o.terra." in str(path):  # the final bundle, not the checkpoints
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real(path, data, mode, **options)

    monkeypatch.setattr(bundle_module, "_write_new_file", full)
    line = refused(argv, "No space left on device", "free some space", "resume from the checkpoint")
    assert "o.terra.partial" in line and not out.exists()
    monkeypatch.setattr(bundle_module, "_write_new_file", real)
    code, _, err = cli(argv[:-3] + ["-c", config])
    assert code == 0, err
    assert sorted(os.listdir(tmp_path)) == ["c.yaml", "o.terra"]


# ---------------------------------------------------------------------------------- noise, defects
def test_an_error_after_a_progress_bar_is_on_its_own_line(bundle):
    import io

    from tqdm import tqdm

    stream = io.StringIO()
    bar = tqdm(total=10, file=stream, leave=False, desc="loading weights")
    bar.update(3)
    (bundle / "manifest.json").write_text("null")
    code, _, err = cli(["info", bundle])
    assert code == 2 and bar.disable  # closed, and with leave=False its line erased
    assert stream.getvalue().endswith("\r") or stream.getvalue().endswith("\x1b[A")
    one_line(err)


def test_the_text_model_loads_without_a_progress_bar():
    from transformers.utils import logging as hf_logging

    from terra.perception.text import SentenceTransformerEmbedder

    class Model:
        def get_sentence_embedding_dimension(self):
            return 4

    bar_while_loading = []

    def load(device):
        bar_while_loading.append(hf_logging.is_progress_bar_enabled())
        return Model()

    hf_logging.enable_progress_bar()
    SentenceTransformerEmbedder("toy", load, device="cpu")
    assert bar_while_loading == [False]


def test_an_unexpected_exception_shows_its_traceback_and_asks_for_a_report(bundle, monkeypatch, capsys):
    import terra.cli.info as info

    def broken(path, verify=True):
        raise RuntimeError("a defect")

    monkeypatch.setattr(info, "bundle_summary", broken)
    from terra.cli import main

    with pytest.raises(SystemExit) as stop:
        main(["info", str(bundle)])
    err = capsys.readouterr().err
    assert stop.value.code == 1
    assert "Traceback" in err and "RuntimeError: a defect" in err
    assert err.strip().splitlines()[-1].startswith("terra: internal error: this is a bug in terra")


@pytest.mark.parametrize("argv", [["build", "-q", "--overwrite"], ["find", QUERY, "--save"]])
def test_a_damaged_file_is_not_carried_into_a_new_version(bundle, argv):
    """A same-size change to a file the command does not rewrite (found by the fuzz suite: the new
    bundle's manifest vouched for the damaged map/meta.json). Refused, the bundle left as it was."""
    path = bundle / "map/meta.json"
    data = bytearray(path.read_bytes())
    i = next(k for k, c in enumerate(data) if chr(c) in "123456789")
    data[i] = ord("1") if data[i] != ord("1") else ord("2")  # still valid JSON, same size
    path.write_bytes(bytes(data))
    before = folder_digest(bundle)
    refused([argv[0], bundle, *argv[1:]], "map/meta.json", "checksum mismatch")
    assert folder_digest(bundle) == before


def test_a_huge_camera_count_in_the_msmap_yaml_is_one_line(reliability_seeds, tmp_path):
    """num_cams 10^12 (found by the fuzz benchmark: a list of 10^12 camera numbers, MemoryError)."""
    data = Path(shutil.copytree(reliability_seeds.datasets["terra-folder"], tmp_path / "data"))
    config = data / "msmap_camera_config.yaml"
    config.write_text(config.read_text().replace("num_cams: 1", "num_cams: 1000000000000"))
    refused(
        ["map", data, "--camera-config", config, "--out", tmp_path / "out", "-q"],
        "msmap_camera_config.yaml",
        "num_cams is 1000000000000 but there is no cam2_K",
    )
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("data", [b"\x80\x02q\x00.", b"\x80\x02R."])
def test_a_garbled_reference_torch_file_is_one_line(reliability_seeds, tmp_path, data):
    """Pickle opcodes that make torch's weights-only unpickler index an empty stack (found by the
    fuzz benchmark: an IndexError traceback from `terra import`)."""
    ref = Path(shutil.copytree(reliability_seeds.reference, tmp_path / "reference"))
    victim = next(ref.glob("clip_imgs_itr*.pt"))
    victim.write_bytes(data)
    refused(
        [
            "import",
            ref,
            "-f",
            "terra-reference",
            "-o",
            tmp_path / "out",
            "--terrain-classes",
            "sidewalk,grass,asphalt,dirt,water",
        ],
        victim.name,
        "unreadable torch file",
    )
    assert not (tmp_path / "out").exists()
