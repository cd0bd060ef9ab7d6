"""A folder Terra did not write is never replaced, with or without --overwrite: every writing command
refuses it with one line that names what it found and does not suggest --overwrite, and leaves it
as it was. An output of the command's own kind (recognised by its marker file and schema) is
refused without --overwrite and replaced with it."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.reliability.fuzzing import cli


def foreign_folder(root: Path) -> Path:
    folder = root / "docs"
    folder.mkdir()
    (folder / "thesis.txt").write_text("precious\n")
    return folder


def assert_refused_untouched(folder: Path, code: int, err: str) -> None:
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "thesis.txt" in lines[0] and "never replaces" in lines[0], err
    assert "pass --overwrite" not in err
    assert sorted(p.name for p in folder.iterdir()) == ["thesis.txt"]
    assert (folder / "thesis.txt").read_text() == "precious\n"


@pytest.fixture(scope="module")
def two_frames(tmp_path_factory) -> Path:
    """A 2-frame tiny campus written by `terra sim` (its own kind of output)."""
    out = tmp_path_factory.mktemp("sim") / "data"
    code, _, err = cli(["sim", "--preset", "tiny", "--max-frames", "2", "--out", out, "-q"])
    assert code == 0, err
    return out


@pytest.mark.parametrize("overwrite", [False, True])
def test_sim_refuses_a_foreign_folder(tmp_path, overwrite):
    docs = foreign_folder(tmp_path)
    args = ["sim", "--preset", "tiny", "--max-frames", "2", "--out", docs, "-q"]
    code, _, err = cli([*args, "--overwrite"] if overwrite else args)
    assert_refused_untouched(docs, code, err)


def test_sim_replaces_its_own_dataset_only_with_overwrite(two_frames, tmp_path):
    import shutil

    data = shutil.copytree(two_frames, tmp_path / "data")
    (data / "stale.txt").write_text("from an earlier run\n")
    args = ["sim", "--preset", "tiny", "--max-frames", "2", "--out", data, "-q"]
    code, _, err = cli(args)
    assert code == 2 and "pass --overwrite" in err
    code, _, err = cli([*args, "--overwrite"])
    assert code == 0, err
    assert not (data / "stale.txt").exists() and (data / "classes.json").is_file()


@pytest.mark.parametrize("overwrite", [False, True])
def test_export_refuses_a_foreign_folder(tiny_bundle, tmp_path, overwrite):
    docs = foreign_folder(tmp_path)
    args = ["export", tiny_bundle.path, "--format", "terra-reference", "--out", docs]
    code, _, err = cli([*args, "--overwrite"] if overwrite else args)
    assert_refused_untouched(docs, code, err)


def test_export_replaces_its_own_export_with_overwrite(tiny_bundle, tmp_path):
    out = tmp_path / "reference"
    args = ["export", tiny_bundle.path, "--format", "terra-reference", "--out", out]
    assert cli(args)[0] == 0
    code, _, err = cli(args)
    assert code == 2 and "pass --overwrite" in err
    assert cli([*args, "--overwrite"])[0] == 0


@pytest.mark.parametrize("overwrite", [False, True])
def test_import_refuses_a_foreign_folder(tiny_bundle, tmp_path, overwrite):
    reference = tmp_path / "reference"
    assert cli(["export", tiny_bundle.path, "--format", "terra-reference", "--out", reference])[0] == 0
    docs = foreign_folder(tmp_path)
    args = ["import", reference, "--format", "terra-reference", "--out", docs]
    code, _, err = cli([*args, "--overwrite"] if overwrite else args)
    assert_refused_untouched(docs, code, err)
    # its own kind, a bundle, is replaced with --overwrite
    bundle = tmp_path / "again.terra"
    assert cli(args[:-1] + [bundle])[0] == 0
    assert cli([*args[:-1], bundle, "--overwrite"])[0] == 0


@pytest.mark.parametrize("overwrite", [False, True])
def test_map_refuses_a_foreign_folder(two_frames, tmp_path, overwrite):
    docs = foreign_folder(tmp_path)
    args = ["map", two_frames, "--out", docs, "-q"]
    code, _, err = cli([*args, "--overwrite"] if overwrite else args)
    assert code == 2 and "is not a Terra bundle" in err, err
    assert sorted(p.name for p in docs.iterdir()) == ["thesis.txt"]


@pytest.mark.parametrize(
    ("option", "field"),
    [
        (["--terrain-classes", "sidewalk,sidewalk,grass,asphalt,dirt,water"], "terrain_classes"),
        (["--embedder", "x" * 5000], "embedder.name"),
    ],
)
def test_import_overwrite_with_a_bad_value_keeps_the_old_bundle(tiny_bundle, tmp_path, option, field):
    from terra.bundle import Bundle
    from tests.mapping.fixtures import folder_digest

    reference = tmp_path / "reference"
    assert cli(["export", tiny_bundle.path, "--format", "terra-reference", "--out", reference])[0] == 0
    bundle = tmp_path / "out.terra"
    assert cli(["import", reference, "--format", "terra-reference", "--out", bundle])[0] == 0
    before = folder_digest(bundle)
    code, _, err = cli(["import", reference, "--format", "terra-reference", "--out", bundle, "--overwrite", *option])
    assert code == 2 and len(err.strip().splitlines()) == 1 and f"field '{field}'" in err, err
    assert len(err) < 300  # the 5,000-character name is not echoed
    assert folder_digest(bundle) == before
    assert Bundle(bundle).model is not None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.terra", "reference"]  # no staging left
