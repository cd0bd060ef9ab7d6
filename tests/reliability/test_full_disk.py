"""A full disk at any write of a writing command: `map --overwrite` (with checkpoints), `build`,
`import`, `export`, `sim` and `find --save` each fail at a spread of the writes one clean run makes
(tests/reliability/diskfull.py: the n-th file or folder written raises ENOSPC). Each must say one line
naming the path and "No space left on device", exit 2, keep the old output byte for byte and leave
nothing beside it; the one thing `map` may keep is a complete checkpoint that the line names, to
resume from once there is room (and the rerun then resumes to the bytes of an uninterrupted run).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from tests.mapping.fixtures import folder_digest
from tests.reliability.diskfull import count_writes, full_disk
from tests.reliability.fuzzing import cli

CLASSES = "sidewalk,grass,asphalt,dirt,water"


@pytest.fixture(scope="module")
def old_outputs(reliability_seeds, tmp_path_factory):
    """One existing output of each kind, copied into each case: a bundle, an export, a dataset."""
    root = tmp_path_factory.mktemp("full-disk")
    (root / "every-frame.yaml").write_text("mapping:\n  checkpoint_every: 1\n")
    assert cli(["export", reliability_seeds.bundle, "-f", "terra-reference", "-o", root / "ref"])[0] == 0
    assert cli(["sim", "--preset", "tiny", "--max-frames", "1", "-q", "--seed", "1", "--out", root / "data"])[0] == 0
    return root


def _argv(command: str, seeds, old: Path, case: Path) -> list:
    out = case / "out"
    return {
        "map": [
            "map",
            seeds.datasets["terra-folder"],
            "--out",
            out,
            "-q",
            "--overwrite",
            "-c",
            old / "every-frame.yaml",
        ],
        "build": ["build", out, "-q", "--overwrite"],
        "find --save": ["find", out, "find the dumpster", "--save"],
        "import": ["import", seeds.reference, "-f", "terra-reference", "-o", out, "--overwrite"]
        + ["--terrain-classes", CLASSES],
        "export": ["export", seeds.bundle, "-f", "terra-reference", "-o", out, "--overwrite"],
        "sim": ["sim", "--preset", "tiny", "--max-frames", "1", "-q", "--seed", "2", "--out", out, "--overwrite"],
    }[command]


def _fresh_case(command: str, seeds, old: Path, case: Path) -> Path:
    shutil.rmtree(case, ignore_errors=True)
    case.mkdir()
    bundle: Path = seeds.bundle
    source = {"export": old / "ref", "sim": old / "data"}.get(command, bundle)
    shutil.copytree(source, case / "out")
    return case


def _spread(total: int, picks: int) -> list[int]:
    """The first two writes, the last two and `picks` evenly between (1-based write numbers)."""
    inner = [1 + round(k * (total - 1) / (picks + 1)) for k in range(1, picks + 1)]
    return sorted({1, 2, *inner, total - 1, total} & set(range(1, total + 1)))


@pytest.mark.parametrize(
    "command,picks", [("map", 10), ("build", 5), ("find --save", 3), ("import", 5), ("export", 4), ("sim", 3)]
)
def test_a_full_disk_at_any_write_is_one_line_and_leaves_the_old_output(
    reliability_seeds, old_outputs, tmp_path, command, picks
):
    case = tmp_path / "case"
    _fresh_case(command, reliability_seeds, old_outputs, case)
    (code, _, err), writes = count_writes(lambda: cli(_argv(command, reliability_seeds, old_outputs, case)))
    assert code == 0, err
    assert len(writes) >= 3, writes  # the simulated disk sees the command's writes
    for n in _spread(len(writes), picks):
        _fresh_case(command, reliability_seeds, old_outputs, case)
        before, entries = folder_digest(case / "out"), sorted(os.listdir(case))
        with full_disk(n) as disk:
            code, out, err = cli(_argv(command, reliability_seeds, old_outputs, case))
        where = f"{command}: write {n} of {len(writes)} ({disk.seen[-1]}): {err!r}"
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1, where
        assert lines[0].startswith(f"terra: error: {disk.seen[-1]}: ") and "No space left on device" in lines[0], where
        assert folder_digest(case / "out") == before, where
        left = sorted(set(os.listdir(case)) - set(entries))
        if left == ["out.partial"]:  # map only: a complete checkpoint, named by the line
            assert command == "map" and (case / "out.partial" / "state" / "manifest.json").is_file(), where
            assert f"resume from the checkpoint in {case / 'out.partial'}" in lines[0], where
        else:
            assert left == [], where


def test_map_resumes_after_the_disk_had_room_again(reliability_seeds, old_outputs, tmp_path):
    """A checkpoint kept by a full disk during the final write: the rerun resumes from it and writes the
    bytes of an uninterrupted run, leaving no work folder."""
    reference = tmp_path / "reference"
    _fresh_case("map", reliability_seeds, old_outputs, reference)
    (code, _, err), writes = count_writes(lambda: cli(_argv("map", reliability_seeds, old_outputs, reference)))
    assert code == 0, err
    case = tmp_path / "case"
    _fresh_case("map", reliability_seeds, old_outputs, case)
    with full_disk(len(writes)):  # the new bundle's manifest: after the last checkpoint
        code, _, err = cli(_argv("map", reliability_seeds, old_outputs, case))
    assert code == 2 and (case / "out.partial" / "state" / "manifest.json").is_file(), err
    code, _, err = cli(_argv("map", reliability_seeds, old_outputs, case))
    assert code == 0, err
    assert folder_digest(case / "out") == folder_digest(reference / "out")
    assert sorted(os.listdir(case)) == ["out"]
