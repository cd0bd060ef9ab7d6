import json
import os
import stat

import numpy as np
import pytest

from terra.bundle import Bundle, BundleWriter
from terra.errors import TerraError


def _write(path, points):
    with BundleWriter(path) as w:
        w.set_component("map", {"points": len(points)})
        w.put_array("map/points", points)
        w.put_json("map/meta.json", {"voxel_size": 0.4})
    return Bundle(path)


def test_roundtrip_and_manifest(tmp_path):
    pts = np.arange(12, dtype=np.float32).reshape(4, 3)
    b = _write(tmp_path / "b", pts)
    np.testing.assert_array_equal(b.array("map/points"), pts)
    assert b.json("map/meta.json") == {"voxel_size": 0.4}
    assert b.has("map/points") and not b.has("graph/nodes")
    b.verify()
    sizes = b.component_bytes()
    assert sizes["map"] == sum(e.bytes for e in b.files.values())


def test_same_content_same_bytes(tmp_path):
    pts = np.random.default_rng(0).normal(size=(100, 3)).astype(np.float32)
    a, b = _write(tmp_path / "a", pts), _write(tmp_path / "b", pts)
    for name in ["manifest.json", "map/points.npy", "map/meta.json"]:
        assert (a.path / name).read_bytes() == (b.path / name).read_bytes()


def test_failed_write_leaves_previous_bundle_untouched(tmp_path):
    pts = np.ones((3, 3), dtype=np.float32)
    _write(tmp_path / "b", pts)
    before = (tmp_path / "b" / "manifest.json").read_bytes()
    with pytest.raises(RuntimeError), BundleWriter(tmp_path / "b", base=Bundle(tmp_path / "b")) as w:
        w.put_array("graph/x", np.zeros(3))
        raise RuntimeError("crash mid-write")
    assert (tmp_path / "b" / "manifest.json").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b"]  # no temporary folder left behind


def test_add_component_keeps_base_and_drop_removes(tmp_path):
    b = _write(tmp_path / "b", np.ones((3, 3), dtype=np.float32))
    with BundleWriter(b.path, base=b) as w:
        w.set_component("graph", {"places": 2})
        w.put_array("graph/x", np.arange(2))
    b2 = Bundle(tmp_path / "b")
    assert b2.has("map/points") and b2.has("graph/x")
    with BundleWriter(b2.path, base=b2, drop_components=("graph",)):
        pass
    b3 = Bundle(tmp_path / "b")
    assert not b3.has("graph/x") and "graph" not in b3.manifest["components"]
    b3.verify()


def test_corruption_and_bad_schema_are_one_line_errors(tmp_path):
    b = _write(tmp_path / "b", np.ones((3, 3), dtype=np.float32))
    with open(b.path / "map/points.npy", "ab") as f:
        f.write(b"x")
    with pytest.raises(TerraError, match="points.npy: size"):
        b.array("map/points")
    manifest = json.loads((b.path / "manifest.json").read_text())
    manifest["schema_version"] = 99
    (b.path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(TerraError, match="schema_version 99"):
        Bundle(b.path)
    with pytest.raises(TerraError, match="not a Terra bundle"):
        Bundle(tmp_path)


def test_a_version_shares_the_files_whose_bytes_did_not_change(tmp_path):
    """Shared arrays whose bytes equal the base's file are a hard link to it, even in a dropped
    component; changed bytes are a new file; a damaged base file is written again, never linked."""
    b = _write(tmp_path / "b", np.ones((3, 3), dtype=np.float32))
    inode = (b.path / "map/points.npy").stat().st_ino
    with BundleWriter(b.path, base=b, drop_components=("map",)) as w:
        w.set_component("map", {"points": 3})
        w.put_array("map/points", np.ones((3, 3), dtype=np.float32), share=True)
        w.put_json("map/meta.json", {"voxel_size": 0.5})
    b2 = Bundle(b.path)
    assert (b2.path / "map/points.npy").stat().st_ino == inode
    assert b2.json("map/meta.json") == {"voxel_size": 0.5}
    b2.verify()
    damaged = b2.path / "map/points.npy"
    data = bytearray(damaged.read_bytes())
    data[-1] ^= 1
    damaged.write_bytes(bytes(data))
    with BundleWriter(b.path, base=Bundle(b.path), drop_components=("map",)) as w:
        w.set_component("map", {"points": 3})
        w.put_array("map/points", np.ones((3, 3), dtype=np.float32), share=True)
    b3 = Bundle(b.path)
    b3.verify()
    np.testing.assert_array_equal(b3.array("map/points"), np.ones((3, 3), dtype=np.float32))


def test_an_array_handed_over_is_read_from_memory_once_and_never_once_its_file_changed(tmp_path, monkeypatch):
    """put_array(hand_over=True): once committed, the next read of the file in this process takes the
    writer's copy (the caller's array may change after the put) checked against the spec, the read
    after it reads the file; a file changed since it was written is read and its damage found; an
    aborted version hands nothing over."""
    import terra.bundle as bundle_module
    from terra.npy import ArraySpec

    reads: list[str] = []
    real_read = bundle_module.read_npy
    monkeypatch.setattr(
        bundle_module, "read_npy", lambda path, *a, **k: reads.append(str(path)) or real_read(path, *a, **k)
    )
    monkeypatch.setattr(bundle_module, "_HANDED", type(bundle_module._HANDED)())
    points = np.arange(12, dtype=np.float32).reshape(4, 3)
    with BundleWriter(tmp_path / "b") as w:
        w.put_array("map/points", points, hand_over=True)
        w.put_array("map/other", points)
    points[0, 0] = 99.0  # after the put: not what was written
    spec = ArraySpec(("float32",), (4, 3), finite=True)
    b = Bundle(tmp_path / "b")
    first = b.array("map/points", spec)
    assert first[0, 0] == 0.0 and reads == []
    np.testing.assert_array_equal(b.array("map/points", spec), first)
    assert len(reads) == 1 and reads[0].endswith("map/points.npy")

    with BundleWriter(b.path, base=b) as w:
        w.put_array("map/points", np.ones((4, 3), dtype=np.float32), hand_over=True)
    with pytest.raises(TerraError, match=r"points.npy: array of dtype float32, expected int64"):
        Bundle(b.path).array("map/points", ArraySpec(("int64",), (4, 3)))  # the spec holds for a handed array

    with BundleWriter(b.path, base=Bundle(b.path)) as w:
        w.put_array("map/points", np.full((4, 3), 2.0, dtype=np.float32), hand_over=True)
    damaged = b.path / "map/points.npy"
    data = bytearray(damaged.read_bytes())
    data[-1] ^= 1
    damaged.write_bytes(bytes(data))  # same size, another modification time
    with pytest.raises(TerraError, match="points.npy: checksum mismatch"):
        Bundle(b.path).array("map/points", spec)

    bundle_module._HANDED.clear()  # the damaged file's array waits for a file that is gone: pushed out by size
    w = BundleWriter(tmp_path / "c")
    w.put_array("map/points", np.zeros((4, 3), dtype=np.float32), hand_over=True)
    w.abort()
    assert len(bundle_module._HANDED) == 0


def test_object_arrays_are_refused(tmp_path):
    w = BundleWriter(tmp_path / "b")
    with pytest.raises(TypeError):
        w.put_array("map/bad", np.array([{"a": 1}], dtype=object))
    w.abort()


@pytest.mark.parametrize("umask", [0o022, 0o002, 0o077])
def test_outputs_get_the_users_normal_permissions(tmp_path, umask):
    """What a plain mkdir / open gives under the umask, not tempfile's private 0700 / 0600, so a
    colleague on a shared lab machine can read the bundle when the user's umask allows it."""
    from terra.bundle import atomic_write_bytes, process_umask

    old = os.umask(umask)
    try:
        assert process_umask() == umask
        b = _write(tmp_path / "b", np.zeros((2, 3), np.float32))
        atomic_write_bytes(tmp_path / "tuned.json", b"{}")
    finally:
        os.umask(old)
    assert stat.S_IMODE(b.path.stat().st_mode) == 0o777 & ~umask
    assert stat.S_IMODE((b.path / "map").stat().st_mode) == 0o777 & ~umask
    for path in [b.path / "manifest.json", b.path / "map" / "points.npy", tmp_path / "tuned.json"]:
        assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask, path


@pytest.mark.filterwarnings("ignore:Stored array in format 2.0")  # np.save's own note on the long header
def test_arrays_are_written_as_np_save_writes_them(tmp_path):
    """put_array streams the header and the array's own memory: the files and their checksums are
    those of np.save, whatever the dtype, layout, byte order or header size."""
    import hashlib
    import io

    from terra.bundle import array_bytes

    rng = np.random.default_rng(0)
    arrays = {
        "empty": np.zeros((0, 3)),
        "scalar": np.array(3.5),
        "points": rng.random((100, 3)).astype(np.float32),
        "strided": np.arange(10)[::2],
        "fortran": rng.random((4, 3)).T,
        "flags": np.array([True, False]),
        "half": rng.random(5).astype(np.float16),
        "big_endian": rng.random((3, 3)).astype(">f8"),
        "many_axes": np.zeros((1,) * 32, np.int8),
        "long_header": np.zeros(2, dtype=[(f"field{i}", "<u1") for i in range(5000)]),  # past format 1.0's 64 KiB
        "record": np.zeros(3, dtype=[("a", "<f4"), ("b", "<i8")]),
    }
    with BundleWriter(tmp_path / "b.terra") as writer:
        for name, array in arrays.items():
            writer.put_array(f"a/{name}", array)
    bundle = Bundle(tmp_path / "b.terra")
    for name, array in arrays.items():
        expected = io.BytesIO()
        np.save(expected, np.ascontiguousarray(array), allow_pickle=False)
        data = (tmp_path / "b.terra" / "a" / f"{name}.npy").read_bytes()
        assert data == expected.getvalue() == array_bytes(array), name
        entry = bundle.files[f"a/{name}.npy"]
        assert entry.bytes == len(data) and entry.sha256 == hashlib.sha256(data).hexdigest()
