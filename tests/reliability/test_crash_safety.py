"""Crash-safe outputs: kill -9 at named points and at random moments of `terra map`, `build`,
`find --save` and `sim` leaves the output path holding the old complete result or the new one, and
the next run completes and leaves no leftovers; an interrupted two-rename swap is recovered; a full
or read-only disk is one line with what to do; outputs get the user's umask; `terra info` names a
damaged file.

"Complete" is checked without Terra's own code where it matters: every file the manifest lists
exists with its SHA-256 (bundles), and the folder's bytes equal a reference run's (datasets).
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.mapping.fixtures import folder_digest
from tests.reliability.fuzzing import cli

REPO = Path(__file__).resolve().parents[2]


def terra(*args, point: str | None = None, n: int = 1, timeout: float = 300) -> subprocess.CompletedProcess:
    """`terra ARGS` in a subprocess, killed at kill point `point` (tests/reliability/killpoint.py) when given."""
    cmd = (
        [sys.executable, "-m", "tests.reliability.killpoint", point, str(n), "--"]
        if point
        else [sys.executable, "-m", "terra"]
    )
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}
    return subprocess.run(
        cmd + [str(a) for a in args], cwd=REPO, capture_output=True, text=True, timeout=timeout, env=env
    )


def bundle_state(path: Path) -> str:
    """'missing', 'incomplete', or the SHA-256 of a complete bundle's manifest (which lists every
    file's checksum), checked file by file without opening it through Terra (no recovery step)."""
    manifest = path / "manifest.json"
    if not path.exists():
        return "missing"
    try:
        data = manifest.read_bytes()
        files = json.loads(data)["files"]
    except (OSError, ValueError, KeyError):
        return "incomplete"
    for name, entry in files.items():
        f = path / name
        if not f.is_file() or hashlib.sha256(f.read_bytes()).hexdigest() != entry["sha256"]:
            return "incomplete"
    return hashlib.sha256(data).hexdigest()


def leftovers(folder: Path, name: str) -> list[str]:
    """Entries of `folder` an interrupted run on output `name` may leave."""
    return sorted(e for e in os.listdir(folder) if e.startswith(f".{name}.") or e == f"{name}.partial")


@pytest.fixture(scope="module")
def map_setup(reliability_seeds, tmp_path_factory):
    """A dataset, an old bundle (other voxel size) and the new bundle's state (a reference run)."""
    root = tmp_path_factory.mktemp("kill-map")
    dataset = reliability_seeds.datasets["terra-folder"]
    (root / "old.yaml").write_text("mapping:\n  fusion:\n    voxel_size: 0.5\n")
    (root / "new.yaml").write_text("mapping:\n  checkpoint_every: 1\n")
    assert cli(["map", dataset, "--out", root / "ref.terra", "-q", "-c", root / "new.yaml"])[0] == 0
    assert cli(["map", dataset, "--out", root / "old.terra", "-q", "-c", root / "old.yaml"])[0] == 0
    return dataset, root, bundle_state(root / "old.terra"), bundle_state(root / "ref.terra")


def _check_killed_then_rerun(out: Path, old: str, new: str, rerun: list, point: str) -> None:
    """The invariant after a kill, then a clean rerun. With atomic exchange the path holds the old
    or the new complete version at every instant; after the two-rename fallback ("rename") it may
    be missing until the next command's recovery step, which a `terra info` runs here."""
    if point == "rename":
        terra("info", out, "--no-verify")
    state = bundle_state(out)
    assert state in (old, new), f"after the kill {out} is {state}"
    done = terra(*rerun)
    assert done.returncode == 0, done.stderr
    assert bundle_state(out) == new
    assert leftovers(out.parent, out.name) == []


# Swaps of an existing target during `terra map` with checkpoint_every 1 on 3 frames: the second
# checkpoint replaces the first (swap 1), the bundle replaces the old bundle (swap 2).
@pytest.mark.slow
@pytest.mark.parametrize(
    "point,n", [("write", 3), ("write", 30), ("exchange", 2), ("rmtree", 2), ("rename", 1), ("rename", 2)]
)
def test_kill_during_map_leaves_old_or_new_and_the_rerun_cleans_up(map_setup, tmp_path, point, n):
    dataset, root, old, new = map_setup
    out = tmp_path / "campus.terra"
    shutil.copytree(root / "old.terra", out)
    args = ["map", dataset, "--out", out, "-q", "-c", root / "new.yaml", "--overwrite"]
    killed = terra(*args, point=point, n=n)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    if (point, n) == ("rename", 2):
        assert bundle_state(out) == "missing"  # killed between the fallback's two renames
    _check_killed_then_rerun(out, old, new, args, point)


@pytest.mark.slow
@pytest.mark.parametrize("fraction", [0.5, 0.9])
def test_kill_map_at_a_random_moment(map_setup, tmp_path, fraction):
    """SIGKILL from outside after a share of a full run's duration: old or new, then a clean rerun."""
    dataset, root, old, new = map_setup
    out = tmp_path / "campus.terra"
    shutil.copytree(root / "old.terra", out)
    args = [
        sys.executable,
        "-m",
        "terra",
        "map",
        str(dataset),
        "--out",
        str(out),
        "-q",
        "-c",
        str(root / "new.yaml"),
        "--overwrite",
    ]
    start = time.perf_counter()
    subprocess.run(args, cwd=REPO, capture_output=True, check=True)
    full = time.perf_counter() - start
    shutil.rmtree(out)
    shutil.copytree(root / "old.terra", out)
    proc = subprocess.Popen(args, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(full * fraction)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    _check_killed_then_rerun(out, old, new, args[3:], "delay")


# Kills during `terra map` onto a new path after a checkpoint was written (3 frames, one checkpoint
# after each of frames 1 and 2): before the second checkpoint replaces the first ("exchange" 1), and
# after it did, before the replaced checkpoint is deleted ("remove" 1).
@pytest.mark.slow
@pytest.mark.parametrize("point,resumed", [("exchange", 1), ("remove", 2)])
def test_a_killed_map_resumes_to_the_bytes_of_an_uninterrupted_run(map_setup, tmp_path, point, resumed):
    dataset, root, _, _ = map_setup
    out = tmp_path / "campus.terra"
    args = ["map", dataset, "--out", out, "-c", root / "new.yaml"]
    assert terra(*args, point=point, n=1).returncode == -signal.SIGKILL
    assert not out.exists() and (tmp_path / "campus.terra.partial" / "state" / "manifest.json").is_file()
    done = terra(*args)
    assert done.returncode == 0, done.stderr
    assert f"resumed after frame {resumed}" in done.stdout
    assert folder_digest(out) == folder_digest(root / "ref.terra")  # every file, byte for byte
    assert leftovers(tmp_path, "campus.terra") == []


@pytest.fixture(scope="module")
def build_setup(reliability_seeds, tmp_path_factory):
    """A bundle with a graph (old) and the state of the same bundle rebuilt with spectral regions (new)."""
    root = tmp_path_factory.mktemp("kill-build")
    shutil.copytree(reliability_seeds.bundle, root / "ref.terra")
    assert cli(["build", root / "ref.terra", "-q", "--regions", "spectral", "--overwrite"])[0] == 0
    return root, bundle_state(reliability_seeds.bundle), bundle_state(root / "ref.terra")


@pytest.mark.slow
@pytest.mark.parametrize("point,n", [("write", 2), ("exchange", 1), ("rename", 1)])
def test_kill_during_build(reliability_seeds, build_setup, tmp_path, point, n):
    _, old, new = build_setup
    out = tmp_path / "campus.terra"
    shutil.copytree(reliability_seeds.bundle, out)
    args = ["build", out, "-q", "--regions", "spectral", "--overwrite"]
    assert terra(*args, point=point, n=n).returncode == -signal.SIGKILL
    _check_killed_then_rerun(out, old, new, args, point)


@pytest.mark.slow
@pytest.mark.parametrize("point", ["remove", "rename"])
def test_kill_during_find_save(reliability_seeds, tmp_path, point):
    out, ref = tmp_path / "campus.terra", tmp_path / "ref.terra"
    shutil.copytree(reliability_seeds.bundle, out)
    shutil.copytree(reliability_seeds.bundle, ref)
    queries = ["a tree", "a car", "--save", "--alpha", "0.2"]
    assert cli(["find", ref, *queries])[0] == 0
    old, new = bundle_state(out), bundle_state(ref)
    assert old != new
    args = ["find", out, *queries]
    assert terra(*args, point=point, n=1).returncode == -signal.SIGKILL
    _check_killed_then_rerun(out, old, new, args, point)


@pytest.mark.slow
@pytest.mark.parametrize("point", ["exchange", "rmtree", "rename"])
def test_kill_during_sim_overwrite(tmp_path, point):
    """`terra sim --overwrite` onto an existing dataset: killed mid-swap, the folder is the old
    dataset or the new one, byte for byte (after the two-rename fallback, once a command opened
    it: here `terra inspect`); the rerun leaves nothing else."""
    out, ref = tmp_path / "data", tmp_path / "ref"
    common = ["sim", "--preset", "tiny", "--max-frames", "2", "-q", "--overwrite"]
    assert terra(*common, "--seed", "1", "--out", out).returncode == 0
    assert terra(*common, "--seed", "2", "--out", ref).returncode == 0
    old, new = folder_digest(out), folder_digest(ref)
    assert terra(*common, "--seed", "2", "--out", out, point=point, n=1).returncode == -signal.SIGKILL
    if point == "rename":
        assert not out.exists()  # killed between the fallback's two renames
        assert terra("inspect", out).returncode == 0
    assert folder_digest(out) in (old, new)
    assert terra(*common, "--seed", "2", "--out", out).returncode == 0
    assert folder_digest(out) == new
    assert leftovers(tmp_path, "data") == []


# ------------------------------------------------------------------------- recovery, in process
def test_recovery_restores_a_version_moved_aside_and_removes_dead_leftovers(reliability_seeds, tmp_path):
    from terra.bundle import Bundle

    out = tmp_path / "b.terra"
    shutil.copytree(reliability_seeds.bundle, tmp_path / ".b.terra.old-0123abcd")  # the fallback's first rename
    shutil.copytree(reliability_seeds.bundle, tmp_path / ".b.terra.5e1f00aa.tmp")  # a killed writer's staging
    (tmp_path / ".b.terra.tmp-4242").mkdir()  # an older writer's name for its staging folder
    assert Bundle(out).has("map/points")
    assert bundle_state(out) == bundle_state(reliability_seeds.bundle)
    assert sorted(os.listdir(tmp_path)) == ["b.terra"]


def test_recovery_leaves_a_live_writers_staging_alone(reliability_seeds, tmp_path):
    from terra.bundle import Bundle, BundleWriter, recover

    out = tmp_path / "b.terra"
    shutil.copytree(reliability_seeds.bundle, out)
    writer = BundleWriter(out, base=Bundle(out))
    staging = writer._tmp
    recover(out)  # as another command would, while this writer works
    assert staging.is_dir()
    writer.commit()
    assert not staging.exists() and sorted(os.listdir(tmp_path)) == ["b.terra"]


# ------------------------------------------------------------------------------- full, read-only
def _enospc_at(monkeypatch, calls: int, code: int = errno.ENOSPC):
    import terra.bundle as bundle

    real = bundle._write_new_file
    seen = []

    def failing(path, data, mode=0o666, **options):
        seen.append(path)
        if len(seen) == calls:
            raise OSError(code, os.strerror(code), str(path))
        return real(path, data, mode, **options)

    monkeypatch.setattr(bundle, "_write_new_file", failing)


@pytest.mark.parametrize("command", ["map", "build", "find --save"])
def test_a_full_disk_is_one_line_and_the_old_bundle_stays(reliability_seeds, tmp_path, monkeypatch, capsys, command):
    out = tmp_path / "campus.terra"
    shutil.copytree(reliability_seeds.bundle, out)
    before = folder_digest(out)
    argv = {
        "map": ["map", reliability_seeds.datasets["terra-folder"], "--out", out, "-q", "--overwrite"],
        "build": ["build", out, "-q", "--overwrite"],
        "find --save": ["find", out, "find the dumpster", "--save"],
    }[command]
    _enospc_at(monkeypatch, 3)
    code, _, err = cli(argv)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "No space left on device" in lines[0] and "free some space" in lines[0], err
    assert folder_digest(out) == before
    assert leftovers(tmp_path, "campus.terra") == []


def test_a_read_only_folder_is_one_line(reliability_seeds, tmp_path, monkeypatch):
    import terra.bundle as bundle

    real_mkdir = bundle.os.mkdir

    def read_only(path, mode=0o777):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))

    monkeypatch.setattr(bundle.os, "mkdir", read_only)
    code, _, err = cli(["map", reliability_seeds.datasets["terra-folder"], "--out", tmp_path / "x.terra", "-q"])
    monkeypatch.setattr(bundle.os, "mkdir", real_mkdir)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "Read-only file system" in err and "write to another folder" in err


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_real_read_only_folder(reliability_seeds, tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        code, _, err = cli(["map", reliability_seeds.datasets["terra-folder"], "--out", folder / "x.terra", "-q"])
    finally:
        folder.chmod(0o755)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Permission denied" in err


def test_a_file_size_limit_during_map_is_one_line(reliability_seeds, tmp_path):
    """RLIMIT_FSIZE (a real kernel refusal, EFBIG) in the middle of writing the bundle."""
    out = tmp_path / "campus.terra"
    shutil.copytree(reliability_seeds.bundle, out)
    before = folder_digest(out)
    done = terra(
        "map", reliability_seeds.datasets["terra-folder"], "--out", out, "-q", "--overwrite", point="fsize", n=100_000
    )
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "File too large" in done.stderr
    assert folder_digest(out) == before and leftovers(tmp_path, "campus.terra") == []


@pytest.mark.slow
def test_a_file_size_limit_during_sim_overwrite_is_one_line(tmp_path):
    """`terra sim --overwrite` onto an existing dataset with RLIMIT_FSIZE below one scan's size: one
    line, the old dataset byte for byte, nothing left beside it."""
    out = tmp_path / "data"
    common = ["sim", "--preset", "tiny", "--max-frames", "2", "-q", "--overwrite", "--out", out]
    assert terra(*common, "--seed", "1").returncode == 0
    before = folder_digest(out)
    done = terra(*common, "--seed", "2", point="fsize", n=20_000)
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "File too large" in done.stderr, done.stderr
    assert folder_digest(out) == before and leftovers(tmp_path, "data") == []


@pytest.mark.skipif(os.geteuid() != 0 or not shutil.which("mount"), reason="mounting a small tmpfs needs root")
def test_a_really_full_disk(reliability_seeds, tmp_path):
    """A tmpfs 1.4 times the bundle's size, holding the bundle: the new version does not fit beside it."""
    disk = tmp_path / "disk"
    disk.mkdir()
    size = int(1.4 * sum(p.stat().st_size for p in reliability_seeds.bundle.rglob("*") if p.is_file())) + 65536
    if subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(disk)], capture_output=True
    ).returncode:
        pytest.skip("tmpfs cannot be mounted here")
    try:
        out = disk / "campus.terra"
        shutil.copytree(reliability_seeds.bundle, out)
        before = folder_digest(out)
        code, _, err = cli(["map", reliability_seeds.datasets["terra-folder"], "--out", out, "-q", "--overwrite"])
        assert code == 2 and len(err.strip().splitlines()) == 1 and "the disk is full" in err, err
        assert folder_digest(out) == before and leftovers(disk, "campus.terra") == []
    finally:
        subprocess.run(["umount", str(disk)], check=True)


# ---------------------------------------------------------------------------------- permissions
def _modes(path: Path) -> set[int]:
    return {p.stat().st_mode & 0o777 for p in [path, *path.rglob("*")]}


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_outputs_get_the_users_umask(reliability_seeds, tmp_path, umask):
    old = os.umask(umask)
    try:
        assert cli(["map", reliability_seeds.datasets["terra-folder"], "--out", tmp_path / "b.terra", "-q"])[0] == 0
        assert cli(["export", tmp_path / "b.terra", "-f", "ply", "-o", tmp_path / "b.ply"])[0] == 0
        assert cli(["export", tmp_path / "b.terra", "-f", "terra-reference", "-o", tmp_path / "ref"])[0] == 0
    finally:
        os.umask(old)
    folders, files = 0o777 & ~umask, 0o666 & ~umask
    bundle = tmp_path / "b.terra"
    assert {p.stat().st_mode & 0o777 for p in [bundle, *bundle.rglob("*")] if p.is_dir()} == {folders}
    assert {p.stat().st_mode & 0o777 for p in bundle.rglob("*") if p.is_file()} == {files}
    assert (tmp_path / "b.ply").stat().st_mode & 0o777 == files
    assert (tmp_path / "ref").stat().st_mode & 0o777 == folders


def test_a_replaced_bundle_keeps_its_permissions(reliability_seeds, tmp_path):
    out = tmp_path / "b.terra"
    shutil.copytree(reliability_seeds.bundle, out)
    out.chmod(0o750)
    assert cli(["build", out, "-q", "--overwrite"])[0] == 0
    assert out.stat().st_mode & 0o777 == 0o750


# ------------------------------------------------------------------------------------ terra info
def test_info_names_a_damaged_file(reliability_seeds, tmp_path):
    out = tmp_path / "b.terra"
    shutil.copytree(reliability_seeds.bundle, out)
    data = bytearray((out / "map" / "bank.npy").read_bytes())
    data[-1] ^= 0xFF  # same size: only the checksum tells
    (out / "map" / "bank.npy").write_bytes(bytes(data))
    code, _, err = cli(["info", out])
    assert code == 2
    assert (
        err.strip()
        == f"terra: error: {out}/map/bank.npy: checksum mismatch: the file is damaged (corrupt bundle; rebuild it)"
    )
    assert cli(["info", out, "--no-verify"])[0] == 0


def test_every_file_and_folder_of_a_version_is_synced_before_it_is_swapped_in(tmp_path, monkeypatch):
    """A power cut right after the swap must find the new version whole: every file (the manifest
    and the arrays written without a sync of their own) and every folder of the staged version is
    fsynced before `replace_folder` puts it in place, in the one round BundleWriter.commit makes."""
    import numpy as np

    import terra.bundle as bundle_module
    from terra.bundle import Bundle, BundleWriter

    synced: set[tuple[int, int]] = set()
    real_fsync, real_replace = os.fsync, bundle_module.replace_folder
    seen_at_swap: list[set[tuple[int, int]]] = []

    def recording_fsync(fd: int) -> None:
        info = os.fstat(fd)
        synced.add((info.st_dev, info.st_ino))
        real_fsync(fd)

    def recording_replace(new: Path, target: Path):
        inodes = {(os.lstat(p).st_dev, os.lstat(p).st_ino) for p in [new, *new.rglob("*")]}
        seen_at_swap.append(inodes - synced)  # what would be lost: on disk only in the page cache
        return real_replace(new, target)

    monkeypatch.setattr(os, "fsync", recording_fsync)
    monkeypatch.setattr(bundle_module, "replace_folder", recording_replace)
    out = tmp_path / "b.terra"
    writer = BundleWriter(out)
    writer.put_array("map/chunks/00000/points", np.arange(12, dtype=np.float32).reshape(4, 3))
    writer.put_array("map/chunks/00001/points", np.ones((2, 3), dtype=np.float32))
    writer.put_json("graph/scene_graph.json", {"places": []})
    writer.commit()
    second = BundleWriter(out, base=Bundle(out))  # a version that links most files from the one before
    second.put_array("map/chunks/00001/points", np.zeros((2, 3), dtype=np.float32))
    second.commit(reclaim_in_background=True)
    assert len(seen_at_swap) == 2 and seen_at_swap == [set(), set()]
    assert Bundle(out).version == 2
