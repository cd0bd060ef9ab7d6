"""The bundle: Terra's on-disk map and scene graph, a folder with no pickle in it.

Layout: `manifest.json` plus one `.npy` file per array and `.json` files for structured data,
under component folders (`map/`, `graph/`, ...). Arrays load with `allow_pickle=False`. Every file
is listed in the manifest with its size and SHA-256. Writes are atomic: a new version is assembled
in a temporary sibling folder and swapped in by rename, so a crash leaves the old bundle intact.
No timestamps are written, so the same input gives the same bytes.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from terra import __version__
from terra.errors import TerraError

SCHEMA = "terra-bundle"
SCHEMA_VERSION = 1
MANIFEST = "manifest.json"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def process_umask() -> int:
    """The process's umask (the permission bits new files and folders must not get)."""
    try:
        with open("/proc/self/status") as f:  # read without changing it (Linux)
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def sibling_tmp_dir(path: Path) -> Path:
    """A new empty folder beside `path` to assemble its next version in, with the permissions a
    plain mkdir gives (tempfile.mkdtemp makes it 0700, which would leave the published output
    unreadable to colleagues on a shared machine)."""
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    os.chmod(tmp, 0o777 & ~process_umask())
    return tmp


def dumps_json(obj: Any) -> str:
    """Canonical JSON text (sorted keys, fixed indentation) so equal content gives equal bytes."""
    return json.dumps(obj, indent=1, sort_keys=True, allow_nan=False) + "\n"


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write a file through a temporary sibling and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~process_umask())  # mkstemp's 0600 would outlive the rename
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def array_bytes(array: np.ndarray) -> bytes:
    """The .npy encoding of an array (no pickled objects allowed)."""
    array = np.ascontiguousarray(array)
    if array.dtype.hasobject:
        raise TypeError("object arrays cannot be stored in a bundle")
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


class Bundle:
    """Read access to a bundle folder. Raises TerraError (one line) for anything malformed."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        manifest_path = self.path / MANIFEST
        if not manifest_path.is_file():
            raise TerraError(f"{self.path}: not a Terra bundle (no {MANIFEST}); build one with `terra map`")
        try:
            self.manifest: dict[str, Any] = json.loads(manifest_path.read_text())
        except (OSError, ValueError) as exc:
            raise TerraError(f"{manifest_path}: unreadable manifest ({exc})") from None
        if self.manifest.get("schema") != SCHEMA:
            raise TerraError(f"{manifest_path}: field 'schema' is {self.manifest.get('schema')!r}, expected {SCHEMA!r}")
        version = self.manifest.get("schema_version")
        if version != SCHEMA_VERSION:
            raise TerraError(
                f"{manifest_path}: schema_version {version!r} is not supported by terra {__version__} "
                f"(expected {SCHEMA_VERSION}); rebuild the bundle"
            )

    @property
    def files(self) -> dict[str, dict[str, Any]]:
        return self.manifest.get("files", {})

    def has(self, name: str) -> bool:
        """Whether an array (`map/points`) or JSON file (`graph/scene_graph.json`) is present."""
        return self._file_name(name) in self.files

    @staticmethod
    def _file_name(name: str) -> str:
        return name if name.endswith(".json") else f"{name}.npy"

    def _checked_path(self, name: str, verify: bool) -> Path:
        file_name = self._file_name(name)
        entry = self.files.get(file_name)
        if entry is None:
            raise TerraError(f"{self.path}: bundle has no '{file_name}'")
        path = self.path / file_name
        if not path.is_file():
            raise TerraError(f"{path}: listed in the manifest but missing")
        if path.stat().st_size != entry["bytes"]:
            raise TerraError(f"{path}: size {path.stat().st_size} bytes, manifest says {entry['bytes']} (corrupt bundle)")
        if verify and _sha256(path) != entry["sha256"]:
            raise TerraError(f"{path}: checksum mismatch (corrupt bundle)")
        return path

    def array(self, name: str, verify: bool = False, mmap: bool = False) -> np.ndarray:
        """Load an array by name, e.g. `map/points`."""
        path = self._checked_path(name, verify)
        try:
            return np.load(path, allow_pickle=False, mmap_mode="r" if mmap else None)
        except (OSError, ValueError) as exc:
            raise TerraError(f"{path}: unreadable array ({exc})") from None

    def json(self, name: str, verify: bool = False) -> Any:
        """Load a JSON file by name, e.g. `graph/scene_graph.json`."""
        path = self._checked_path(name, verify)
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise TerraError(f"{path}: unreadable JSON ({exc})") from None

    def verify(self) -> None:
        """Check every file's size and checksum against the manifest."""
        for file_name in self.files:
            self._checked_path(file_name[:-4] if file_name.endswith(".npy") else file_name, verify=True)

    def component_bytes(self) -> dict[str, int]:
        """Bytes on disk per component folder (manifest included under 'manifest')."""
        sizes: dict[str, int] = {"manifest": (self.path / MANIFEST).stat().st_size}
        for file_name, entry in self.files.items():
            component = file_name.split("/", 1)[0] if "/" in file_name else file_name
            sizes[component] = sizes.get(component, 0) + int(entry["bytes"])
        return sizes


class BundleWriter:
    """Assembles a new bundle version and swaps it in atomically on `commit()`.

    With `base`, the new version starts as a copy (hard links where possible) of that bundle, so a
    later stage (e.g. `terra build`) adds or replaces components without touching the others.
    `drop_components` removes stale components (e.g. `graph` when the map is rebuilt).
    """

    def __init__(self, path: str | Path, base: Bundle | None = None, drop_components: tuple[str, ...] = ()):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = sibling_tmp_dir(self.path)
        self.manifest: dict[str, Any] = {"schema": SCHEMA, "schema_version": SCHEMA_VERSION, "files": {}}
        if base is not None:
            self.manifest = json.loads(json.dumps(base.manifest))
            self.manifest["files"] = {}
            for file_name, entry in base.files.items():
                if file_name.split("/", 1)[0] in drop_components:
                    continue
                dst = self._tmp / file_name
                dst.parent.mkdir(parents=True, exist_ok=True)
                try:
                    os.link(base.path / file_name, dst)
                except OSError:
                    shutil.copy2(base.path / file_name, dst)
                self.manifest["files"][file_name] = entry
            for component in drop_components:
                self.manifest.get("components", {}).pop(component, None)
        self.manifest["written_by"] = f"terra {__version__}"
        self._done = False

    def _put(self, file_name: str, data: bytes) -> None:
        dst = self._tmp / file_name
        dst.parent.mkdir(parents=True, exist_ok=True)
        if dst.exists():
            dst.unlink()  # may be a hard link into the base bundle: never write through it
        dst.write_bytes(data)
        self.manifest["files"][file_name] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}

    def put_array(self, name: str, array: np.ndarray) -> None:
        """Store an array as `<name>.npy`, e.g. `map/points`."""
        self._put(f"{name}.npy", array_bytes(array))

    def put_json(self, name: str, obj: Any) -> None:
        """Store canonical JSON as `name` (which ends in .json)."""
        if not name.endswith(".json"):
            raise ValueError(f"JSON names end in .json, got {name!r}")
        self._put(name, dumps_json(obj).encode())

    def remove(self, name: str) -> None:
        file_name = Bundle._file_name(name)
        self.manifest["files"].pop(file_name, None)
        (self._tmp / file_name).unlink(missing_ok=True)

    def commit(self) -> Bundle:
        """Write the manifest and swap the new version into place."""
        self.manifest["files"] = dict(sorted(self.manifest["files"].items()))
        (self._tmp / MANIFEST).write_text(dumps_json(self.manifest))
        old = None
        if self.path.exists():
            old = self.path.with_name(f".{self.path.name}.old-{os.getpid()}")
            if old.exists():
                shutil.rmtree(old)
            os.replace(self.path, old)
        os.replace(self._tmp, self.path)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        self._done = True
        return Bundle(self.path)

    def abort(self) -> None:
        if not self._done:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._done = True

    def __enter__(self) -> "BundleWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.abort()
        elif not self._done:
            self.commit()
