"""The bundle: Terra's on-disk map and scene graph, a folder with no pickle in it; and the one way
Terra replaces a folder it writes (bundles, datasets, reports, exports).

Layout: `manifest.json` plus one `.npy` file per array and `.json` files for structured data,
under component folders (`map/`, `graph/`, ...). Every file is listed in the manifest with its size
and SHA-256; the manifest is validated on open (terra.schemas.BundleManifest: types, ranges, and
file names that cannot leave the bundle), arrays are checked header first (terra.npy) and JSON is
read with one-line errors (terra.fileio). No timestamps are written: the same input gives the same
bytes.

Versions share files. A version written on a base (`BundleWriter(base=...)`) starts from hard links
of the base's files (`keep_from_base` carries single files of a dropped component); a file is never
written through a link (a changed file is a new file under its name), so the base stays as it was
for readers holding it. A live map version stores its per-point arrays in row chunks
(`map/chunks/NNNNN/*.npy`, terra/mapping/chunks.py) so that the next version rewrites only the
chunks in which a point changed and links the rest: a version costs what changed, not the map.

Replacing a folder (`Staging`, `replace_folder`, `recover`, `atomic_folder`). A new version is
assembled in a hidden sibling `.NAME.<token>.tmp` (created with the user's umask, like any folder
the user makes) and then takes the place of NAME in one step:
- where the OS can exchange two paths atomically (Linux renameat2 RENAME_EXCHANGE, macOS
  renamex_np RENAME_SWAP), the staging folder and NAME swap places, and the old version, now in
  the staging name, is deleted. At no instant is NAME missing or partly written: a reader or a
  kill -9 sees the old complete version or the new one.
- elsewhere (file systems without the exchange), NAME is renamed to `.NAME.old-<token>` and the
  staging folder to NAME. A kill between the two renames leaves NAME missing for an instant;
  `recover(NAME)`, which every bundle open, every writer and every dataset write runs first,
  puts the old version back.
Chosen over a symlink to versioned folders because a bundle stays a plain folder (copied, synced,
archived and opened by other tools as one) and a first replacement of an existing folder needs no
migration. A writer holds an exclusive lock (flock) on its staging folder while it lives, and the
lock dies with the process: `recover` removes only unlocked leftovers (`.NAME.*.tmp`,
`.NAME.tmp-*`, `.NAME.old-*` of killed runs), never the work of a process still running.
"""

from __future__ import annotations

import ctypes
import errno
import hashlib
import io
import json
import os
import secrets
import shutil
import stat
import sys
import tempfile
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from terra import __version__
from terra.errors import TerraError
from terra.fileio import read_error, read_json, writing
from terra.npy import ArraySpec, check_array, read_npy

if TYPE_CHECKING:
    from pydantic import BaseModel

    from terra.schemas import BundleManifest, FileEntry

try:  # POSIX: writers lock their staging folder; recovery leaves locked ones alone
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

SCHEMA = "terra-bundle"
SCHEMA_VERSION = 1
MANIFEST = "manifest.json"
MAX_MANIFEST_BYTES = 64 << 20
M = TypeVar("M", bound="BaseModel")


def _sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


# Files whose digest this process has checked, by identity (device, inode, size, mtime): a long-lived
# reader (the service, the viewer) or a second load hashes a file once, and a file replaced or
# rewritten since has another identity, so it is checked again. A file this process wrote is entered
# with the digest of the bytes it wrote (reading it back would hash the same bytes from the page
# cache): a live session loads each version it commits.
_VERIFIED: dict[tuple[int, int, int, int], str] = {}


def _verified_digest(path: str | Path, info: os.stat_result) -> str:
    """The SHA-256 of file `path` (with stat `info`), computed once per file identity."""
    identity = (info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns)
    digest = _VERIFIED.get(identity)
    if digest is None:
        digest = _sha256(path)
        _VERIFIED[identity] = digest
    return digest


# Arrays this process wrote and handed over to the next reader of their file (BundleWriter.put_array
# with hand_over=True), by file identity as above: a live session reads back the chunks of each
# version it commits (terra/mapping/chunk_views.py), and parsing and checking some 20 .npy files
# costs more than the bytes in them. Each is the writer's own copy, taken once (the next read of
# the file reads it), and the oldest go first beyond HAND_OVER_BYTES: a version that nobody reads
# costs memory only until later ones push it out.
_HANDED: OrderedDict[tuple[int, int, int, int], np.ndarray] = OrderedDict()
_HANDED_LOCK = threading.Lock()
HAND_OVER_BYTES = 256 << 20


def _hand_over(identity: tuple[int, int, int, int], array: np.ndarray) -> None:
    """Keep `array` (the writer's own copy), written as the file with `identity`, for its next reader."""
    with _HANDED_LOCK:
        _HANDED[identity] = array
        total = sum(a.nbytes for a in _HANDED.values())
        while total > HAND_OVER_BYTES:
            total -= _HANDED.popitem(last=False)[1].nbytes


def _handed(info: os.stat_result) -> np.ndarray | None:
    """The array handed over for the file with stat `info`, once (None when there is none)."""
    with _HANDED_LOCK:
        return _HANDED.pop((info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns), None)


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


def _write_new_file(
    path: Path, data: bytes | Sequence[bytes | memoryview], mode: int = 0o666, sync: bool = True
) -> tuple[int, int, int, int]:
    """Create file `path` (it must not exist) with `data` (or its parts, one after the other), synced
    to disk unless `sync` is False (the caller syncs it later: `sync_paths`); `mode` before the
    umask. Returns its identity (device, inode, size, mtime)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), mode)
    with os.fdopen(fd, "wb") as f:
        for part in [data] if isinstance(data, bytes) else data:
            f.write(part)
        f.flush()
        if sync:
            os.fsync(f.fileno())
        info = os.fstat(f.fileno())
    return info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns


_SYNC_THREADS = 16


def sync_paths(files: Sequence[Path], folders: Sequence[Path] = ()) -> None:
    """fsync `files` and `folders`, all in one round of threads: the file system then writes them
    back in one journal commit instead of one each (a live snapshot syncs some 60 files and 25
    folders: 0.15-0.25 s one after the other on this project's machine, 0.03 s at once; files, then
    folders, in two rounds, 0.05-0.06 s). A folder that cannot be synced is skipped (some file systems refuse; the
    rename still orders the data); an error syncing a file is raised."""
    from concurrent.futures import ThreadPoolExecutor

    def sync(path: Path, folder: bool) -> None:
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        except OSError:
            if not folder:
                raise
        finally:
            os.close(fd)

    tasks = [(path, False) for path in files] + [(path, True) for path in folders]
    if len(tasks) < 2:
        for path, folder in tasks:
            sync(path, folder)
        return
    with ThreadPoolExecutor(min(_SYNC_THREADS, len(tasks)), thread_name_prefix="terra-sync") as pool:
        list(pool.map(lambda task: sync(*task), tasks))


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write a file through a locked temporary sibling and a rename (TerraError with what to do when
    the disk is full or read-only). A replaced file keeps its permissions; a new one gets the umask's."""
    path = Path(path)
    with writing(path, "file"):
        path.parent.mkdir(parents=True, exist_ok=True)
        recover(path)
        mode = stat.S_IMODE(os.stat(path).st_mode) if path.is_file() else None
        tmp, fd = _locked_sibling(path, lambda p: os.close(os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)))
        try:
            with open(tmp, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            if mode is not None:
                os.chmod(tmp, mode)
            os.replace(tmp, path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        finally:
            if fd is not None:
                os.close(fd)


def npy_parts(array: np.ndarray) -> tuple[bytes, memoryview]:
    """The .npy encoding of an array as its header and a view of its data, bytes for bytes what
    np.save writes, without copying the data (a map commit writes about 70 MB at a million points;
    no pickled objects allowed)."""
    array = np.ascontiguousarray(array)
    if array.dtype.hasobject:
        raise TypeError("object arrays cannot be stored in a bundle")
    header = io.BytesIO()
    fields = np.lib.format.header_data_from_array_1_0(array)
    try:  # the version np.save picks: 1.0 unless the header outgrows it
        np.lib.format.write_array_header_1_0(header, fields)
    except ValueError:
        header = io.BytesIO()
        np.lib.format.write_array_header_2_0(header, fields)
    return header.getvalue(), array.reshape(-1).view(np.uint8).data


def array_bytes(array: np.ndarray) -> bytes:
    """The .npy encoding of an array (no pickled objects allowed)."""
    header, data = npy_parts(array)
    return header + data.tobytes()


# ----------------------------------------------------------------------------- folder replacement
_RENAME_EXCHANGE = 2  # linux/fs.h
_RENAME_SWAP = 2  # macOS stdio.h (renamex_np)
_EXCHANGE_UNSUPPORTED = {errno.ENOSYS, errno.EINVAL, getattr(errno, "ENOTSUP", -1), getattr(errno, "EOPNOTSUPP", -1)}


def _libc() -> Any:
    try:
        return ctypes.CDLL(None, use_errno=True)
    except OSError:  # pragma: no cover - no C library to call
        return None


def exchange_paths(a: Path, b: Path) -> bool:
    """Swap what paths `a` and `b` name in one atomic step. False when this OS or file system
    cannot (the caller then renames twice); OSError for a real failure."""
    libc = _libc()
    if sys.platform.startswith("linux") and libc is not None and hasattr(libc, "renameat2"):
        at_fdcwd = -100
        result = libc.renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE)
    elif sys.platform == "darwin" and libc is not None and hasattr(libc, "renamex_np"):
        result = libc.renamex_np(os.fsencode(a), os.fsencode(b), _RENAME_SWAP)
    else:
        return False
    if result == 0:
        return True
    code = ctypes.get_errno()
    if code in _EXCHANGE_UNSUPPORTED:
        return False
    raise OSError(code, os.strerror(code), str(b))


def _try_lock(path: Path) -> int | None:
    """A descriptor holding an exclusive lock on `path`; None when a live process holds it."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
    except OSError:
        return None
    if fcntl is None:
        return fd
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return fd


def _leftover_kind(path: Path, entry: str) -> str | None:
    """'old' (a version moved aside), 'tmp' (a staging folder or file) or None (not a leftover of `path`)."""
    prefix = f".{path.name}."
    if not entry.startswith(prefix):
        return None
    rest = entry[len(prefix) :]
    if rest.startswith("old-") and "." not in rest:
        return "old"
    if (rest.endswith(".tmp") and rest.count(".") == 1) or (rest.startswith("tmp-") and "." not in rest):
        return "tmp"
    return None


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def recover(path: str | Path) -> list[str]:
    """Clean up after interrupted replacements of `path`: when `path` is missing and an old version
    was moved aside (`.NAME.old-*`), it is put back; unlocked staging leftovers (`.NAME.*.tmp`,
    `.NAME.tmp-*`) and surplus old versions are removed. Leftovers locked by a running writer are
    left alone. Best effort (a read-only folder is left as it is). Returns what it did, in words."""
    path = Path(path)
    try:
        entries = sorted(os.listdir(path.parent or "."))
    except OSError:
        return []
    done = []
    for entry in entries:
        kind = _leftover_kind(path, entry)
        if kind is None:
            continue
        leftover = path.parent / entry
        fd = _try_lock(leftover)
        if fd is None:
            continue
        try:
            if kind == "old" and not os.path.lexists(path):
                os.rename(leftover, path)
                done.append(f"restored {path} from {entry}")
            else:
                _remove(leftover)
                done.append(f"removed {entry}")
        except OSError:
            pass
        finally:
            os.close(fd)
    return done


def _locked_sibling(target: Path, create: Callable[[Path], None]) -> tuple[Path, int | None]:
    """A new `.NAME.<token>.tmp` sibling of `target` made by `create` (with the user's umask) and a
    descriptor locking it. Another command's `recover` may take an unlocked sibling for a dead one
    and remove it in the instant between creation and locking: then a fresh one is made."""
    for _ in range(100):
        path = target.parent / f".{target.name}.{secrets.token_hex(6)}.tmp"
        try:
            create(path)
        except FileExistsError:
            continue
        fd = _try_lock(path)
        if fd is None and fcntl is not None:
            continue  # removed (or being removed) by a recovery: not ours any more
        try:
            if fd is None or os.path.samestat(os.fstat(fd), os.lstat(path)):
                return path, fd
        except FileNotFoundError:
            pass
        if fd is not None:
            os.close(fd)
    raise OSError(errno.EEXIST, "no free name for a staging folder", str(target))


class Staging:
    """A new version of folder `target`, assembled in a locked hidden sibling and put in place by
    `commit()` (see the module docstring); `discard()` removes it. The staging folder gets the
    user's umask, and on commit the mode of the folder it replaces."""

    def __init__(self, target: str | Path):
        target = Path(target)
        self.target = target.resolve() if target.is_symlink() else target  # replace what a symlink names
        self.target.parent.mkdir(parents=True, exist_ok=True)
        recover(self.target)
        self.folder, self._lock = _locked_sibling(self.target, lambda p: os.mkdir(p, 0o777))
        self._done = False

    def commit(self, reclaim_in_background: bool = False, unsynced: Sequence[Path] = ()) -> None:
        """Put the staged folder at the target atomically, then delete the version it replaced (in a
        daemon thread with `reclaim_in_background`, for writers that commit often: a process that
        ends first leaves an unlocked leftover, which the next `recover` removes). `unsynced`: files
        of the staged folder written without a sync, synced here with its folders."""
        _sync_tree(self.folder, unsynced)
        if os.path.isdir(self.target) and not os.path.islink(self.target):
            os.chmod(self.folder, stat.S_IMODE(os.stat(self.target).st_mode))
        # The version replaced stays locked until the reclaim thread has deleted it: unlocked, the
        # next `recover` (every bundle open) took it for a dead writer's leftover and deleted it
        # itself, on the committing thread (about 10 ms of each live snapshot).
        held = _try_lock(self.target) if reclaim_in_background else None
        try:
            replaced = replace_folder(self.folder, self.target)
        except BaseException:
            _close(held)
            raise
        self._done = True
        self._release()
        if replaced is not None and reclaim_in_background:
            thread = threading.Thread(target=_reclaim, args=(replaced, held), name="terra-reclaim", daemon=True)
            _RECLAIMS[:] = [t for t in _RECLAIMS if t.is_alive()] + [thread]
            thread.start()
        else:
            _close(held)
            if replaced is not None:
                _remove(replaced)

    def discard(self) -> None:
        if not self._done:
            self._done = True
            _remove(self.folder)
            self._release()

    def _release(self) -> None:
        if self._lock is not None:
            os.close(self._lock)
            self._lock = None


_RECLAIMS: list[threading.Thread] = []  # deletions of replaced versions running in the background


def wait_for_reclaims(timeout: float | None = None) -> None:
    """Wait (at most `timeout` seconds per deletion) until the replaced versions this process is
    deleting in the background are gone: a live session's `close` leaves its folder clean."""
    for thread in list(_RECLAIMS):
        thread.join(timeout)
    _RECLAIMS[:] = [t for t in _RECLAIMS if t.is_alive()]


def _close(fd: int | None) -> None:
    if fd is not None:
        os.close(fd)


def _reclaim(folder: Path, lock: int | None) -> None:
    """Delete a replaced version, then release the lock that kept `recover` off it."""
    try:
        _remove(folder)
    finally:
        _close(lock)


def replace_folder(new: Path, target: Path) -> Path | None:
    """Make complete folder `new` (a sibling of `target`) the content of `target` in one step.
    Returns where the replaced version now is (to delete), or None when `target` did not exist."""
    if not os.path.lexists(target):
        try:
            os.rename(new, target)
            return None
        except OSError as exc:
            if exc.errno not in (errno.EEXIST, errno.ENOTEMPTY):  # created meanwhile: swap below
                raise
    if exchange_paths(new, target):
        return new
    old = target.parent / f".{target.name}.old-{secrets.token_hex(6)}"
    fd = _try_lock(target)  # recovery leaves the old version alone while it is moved aside
    try:
        os.rename(target, old)
        os.rename(new, target)
    finally:
        if fd is not None:
            os.close(fd)
    return old


def _sync_tree(folder: Path, files: Sequence[Path] = ()) -> None:
    """fsync every folder of a staged tree and its `files` not synced yet (the others were synced as
    they were written), so the new version is on disk before it replaces the old one."""
    sync_paths(files, [Path(root) for root, _, _ in os.walk(folder)])


def check_output_folder(
    out: str | Path,
    overwrite: bool,
    kind: str = "output folder",
    is_own: Callable[[Path], bool] | None = None,
    marker: str = "marker file",
) -> None:
    """TerraError unless folder `out` may be written: absent, empty, or an output of this kind
    (`is_own`: recognised by its `marker` file and that file's schema) with `overwrite`, which is
    then replaced as a whole when the new one is complete. A folder that is not of this kind is
    never replaced, even with `overwrite`: it may be a user's, and only `--overwrite` stood
    between it and deletion."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise TerraError(f"{out}: exists and is not a folder; choose another --out")
    if is_own is not None:
        refuse_foreign(out, kind, is_own, marker)
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise TerraError(f"{out}: folder exists and is not empty (pass --overwrite to replace it)")
    if not out.absolute().parent.exists():
        raise TerraError(f"{out.absolute().parent}: parent folder does not exist")


def refuse_foreign(out: Path, kind: str, is_own: Callable[[Path], bool], marker: str) -> None:
    """TerraError, whatever --overwrite says, when `out` is a non-empty folder that `is_own` does not
    recognise as this kind of output (by its `marker` file): it may be a user's."""
    if out.is_dir() and any(out.iterdir()) and not _recognised(is_own, out):
        raise TerraError(
            f"{out}: exists and is not a {kind} (no valid {marker}; it holds {found_entries(out)}); "
            "Terra never replaces a folder it did not write: choose another --out, or empty it yourself"
        )


def _recognised(is_own: Callable[[Path], bool], out: Path) -> bool:
    """Whether `is_own` recognises `out`; a marker that fails its schema is not recognised."""
    try:
        return bool(is_own(out))
    except (TerraError, OSError, ValueError):
        return False


def found_entries(folder: Path, shown: int = 3) -> str:
    """A few entries of `folder` for a message, e.g. "thesis.txt, notes/ and 4 more"."""
    names = sorted(f"{p.name[:40]}{'/' if p.is_dir() else ''}" for p in folder.iterdir())
    more = len(names) - shown
    return ", ".join(names[:shown]) + (f" and {more} more" if more > 0 else "")


def is_bundle(folder: Path) -> bool:
    """Whether `folder` is a Terra bundle: its manifest.json reads and validates."""
    return (Path(folder) / MANIFEST).is_file() and Bundle(folder).model is not None


def atomic_folder(out: str | Path, fill: Callable[[Path], None], what: str = "output folder") -> Path:
    """Call fill(staging) on a fresh staging folder of `out`, then replace `out` with it (the same
    mechanism as bundles). On any error the staging folder is removed and `out` is as it was;
    an OSError (full disk, read-only folder) becomes one TerraError line naming `out`."""
    out = Path(out).absolute()
    with writing(out, what):
        staging = Staging(out)
        try:
            fill(staging.folder)
            staging.commit()
        except BaseException:
            staging.discard()
            raise
    return staging.target


# ---------------------------------------------------------------------------------------- manifest
# The manifest has one view, the typed terra.schemas.BundleManifest: a Bundle reads it, a
# BundleWriter edits it, and it is written back as exactly the keys it was read or given with
# (defaults a file never had are not added), so a bundle's bytes do not depend on the model.
def manifest_json(model: BundleManifest) -> dict[str, Any]:
    """The manifest's JSON: the keys that were read or set, not the model's unset defaults."""
    return model.model_dump(mode="json", by_alias=True, exclude_unset=True)


def _manifest(data: dict[str, Any]) -> BundleManifest:
    """The manifest model of JSON `data` Terra is writing (a ValueError there is a defect in Terra)."""
    from terra.schemas import BundleManifest

    return BundleManifest.model_validate(data)


def listed_components(model: BundleManifest) -> list[str]:
    """The components the manifest lists (known ones and a newer writer's), sorted."""
    components = model.components
    known = [name for name in type(components).model_fields if getattr(components, name) is not None]
    extra = [name for name, value in (components.model_extra or {}).items() if value is not None]
    return sorted({*known, *extra})


# ----------------------------------------------------------------------------------------- reading
class Bundle:
    """Read access to a bundle folder. Raises TerraError (one line) for anything malformed."""

    def __init__(self, path: str | Path):
        from terra.schemas import BundleManifest, validate_model

        self.path = Path(path)
        recover(self.path)
        manifest_path = self.path / MANIFEST
        if not self.path.is_dir() or not manifest_path.exists():
            raise TerraError(f"{self.path}: not a Terra bundle (no {MANIFEST}); build one with `terra map`")
        manifest = read_json(manifest_path, "bundle manifest", MAX_MANIFEST_BYTES)
        if not isinstance(manifest, dict):
            raise TerraError(
                f"{manifest_path}: expected a JSON object with schema, schema_version and files, "
                f"got {type(manifest).__name__}"
            )
        if manifest.get("schema") != SCHEMA:
            raise TerraError(f"{manifest_path}: field 'schema' is {manifest.get('schema')!r:.60}, expected {SCHEMA!r}")
        version = manifest.get("schema_version")
        if version != SCHEMA_VERSION or isinstance(version, bool):
            raise TerraError(
                f"{manifest_path}: schema_version {version!r:.20} is not supported by terra {__version__} "
                f"(expected {SCHEMA_VERSION}); rebuild the bundle"
            )
        self.model: BundleManifest = validate_model(manifest, BundleManifest, manifest_path)
        self._real_root: str | None = None  # the folder with links followed, and a separator (`_inside`)
        self._real_folders: dict[str, str] = {}

    @property
    def manifest(self) -> dict[str, Any]:
        """The manifest as JSON, a fresh copy for display and tests; code asks the typed `model`."""
        return manifest_json(self.model)

    @property
    def files(self) -> dict[str, FileEntry]:
        return self.model.files

    @property
    def version(self) -> int:
        """The committed version this manifest describes (0 for bundles written before versions)."""
        return int(self.model.version or 0)

    @property
    def components(self) -> list[str]:
        """The components this bundle has (e.g. ["graph", "map"]): see `has_component`."""
        return [name for name in listed_components(self.model) if self.has_component(name)]

    def has_component(self, name: str) -> bool:
        """Whether the manifest lists component `name` (e.g. "map", "graph") with files present under
        `name/`: the one rule every stage and command asks."""
        return name in listed_components(self.model) and any(f.startswith(f"{name}/") for f in self.files)

    def component_config(self, name: str) -> dict[str, Any]:
        """components.<name>.config: the stage configuration component `name` was built with ({} when
        the manifest records none)."""
        info = getattr(self.model.components, name, None)
        config = getattr(info, "config", None)
        return dict(config) if isinstance(config, dict) else {}

    def has(self, name: str) -> bool:
        """Whether an array (`map/points`) or JSON file (`graph/scene_graph.json`) is present."""
        return self._file_name(name) in self.files

    @staticmethod
    def _file_name(name: str) -> str:
        return name if name.endswith(".json") else f"{name}.npy"

    def _inside(self, path: str) -> bool:
        """Whether file `path` (lstat found it a regular file, not a link) lies inside the bundle once
        links among its folders are followed. Each folder is resolved once per Bundle, on strings: a
        live snapshot checks some 300 chunk files, and pathlib's resolving and parsing of every path
        took about 10 ms of it."""
        if self._real_root is None:
            self._real_root = os.path.join(os.path.realpath(self.path), "")  # with its trailing separator
        parent = os.path.dirname(path)
        folder = self._real_folders.get(parent)
        if folder is None:
            folder = self._real_folders[parent] = os.path.join(os.path.realpath(parent), "")
        return folder.startswith(self._real_root)

    def _checked_path(self, name: str, verify: bool) -> str:
        return self._checked(name, verify)[0]

    def _checked(self, name: str, verify: bool) -> tuple[str, os.stat_result]:
        """The path of file `name` and its stat, checked against the manifest (size, SHA-256 with
        `verify`) and to be a regular file inside the bundle; TerraError otherwise."""
        file_name = self._file_name(name)
        entry = self.files.get(file_name)
        if entry is None:
            raise TerraError(f"{self.path}: bundle has no '{file_name}'")
        path = os.path.join(self.path, file_name)
        try:
            info = os.lstat(path)
            inside = self._inside(path)
        except FileNotFoundError:
            raise TerraError(f"{path}: listed in the manifest but missing (corrupt bundle)") from None
        except OSError as exc:
            raise read_error(path, exc, "bundle file") from None
        if not stat.S_ISREG(info.st_mode) or not inside:
            raise TerraError(f"{path}: not a regular file inside the bundle (corrupt bundle)")
        if info.st_size != entry.bytes:
            raise TerraError(f"{path}: size {info.st_size} bytes, manifest says {entry.bytes} (corrupt bundle)")
        if verify:
            try:
                digest = _verified_digest(path, info)
            except OSError as exc:
                raise read_error(path, exc, "bundle file") from None
            if digest != entry.sha256:
                raise TerraError(f"{path}: checksum mismatch: the file is damaged (corrupt bundle; rebuild it)")
        return path, info

    def check(self, name: str) -> None:
        """Check file `name` (as `array` or `json` name it) against the manifest's size and SHA-256
        without reading it (hashed once per file identity in a process): for a reader that takes
        the file's content from a view it derived before (terra/mapping/chunk_views.py)."""
        self._checked_path(name, verify=True)

    def array(self, name: str, spec: ArraySpec | None = None, verify: bool = True, mmap: bool = False) -> np.ndarray:
        """Load an array by name, e.g. `map/points`, checked against the manifest's size and SHA-256
        (hashed once per file identity in a process) and against `spec` before its data is read.
        An array this process wrote with hand_over=True comes from memory, checked against `spec`
        all the same, when the file is still the one written (the same identity)."""
        path, info = self._checked(name, verify)
        handed = _handed(info) if verify and not mmap else None
        if handed is not None:
            return check_array(handed, spec, path)
        return read_npy(path, spec, mmap=mmap, what="bundle array")

    def json(self, name: str, verify: bool = True, max_depth: int | None = 64) -> Any:
        """Load a JSON file by name, e.g. `graph/scene_graph.json`."""
        path = self._checked_path(name, verify)
        return read_json(path, "bundle JSON file", self.files[self._file_name(name)].bytes + 1, max_depth)

    def document(self, name: str, model: type[M], verify: bool = True, max_depth: int | None = 64) -> M:
        """A JSON file by name validated as pydantic `model` (TerraError naming the file and field)."""
        from terra.schemas import validate_model

        return validate_model(self.json(name, verify, max_depth), model, self.path / name)

    def verify(self) -> None:
        """Check every file's size and checksum against the manifest (TerraError naming the first
        damaged or missing file)."""
        for file_name in self.files:
            self._checked_path(file_name[:-4] if file_name.endswith(".npy") else file_name, verify=True)

    def component_bytes(self) -> dict[str, int]:
        """Bytes on disk per component folder (manifest included under 'manifest')."""
        sizes: dict[str, int] = {"manifest": (self.path / MANIFEST).stat().st_size}
        for file_name, entry in self.files.items():
            component = file_name.split("/", 1)[0] if "/" in file_name else file_name
            sizes[component] = sizes.get(component, 0) + entry.bytes
        return sizes


# ----------------------------------------------------------------------------------------- writing
def _version_on_disk(path: Path) -> int | None:
    """The committed version of the bundle at `path` now (0 before versions; None without one)."""
    try:
        manifest = json.loads((Path(path) / MANIFEST).read_bytes())
    except (OSError, ValueError):
        return None
    version = manifest.get("version", 0) if isinstance(manifest, dict) else None
    return int(version) if isinstance(version, int) and not isinstance(version, bool) else 0


class BundleWriter:
    """Assembles a new bundle version and swaps it in atomically on `commit()` (see the module
    docstring). A full disk or read-only folder is one TerraError line; the old bundle stays.

    With `base`, the new version starts as a copy (hard links where possible) of that bundle, so a
    later stage (e.g. `terra build`) adds or replaces components without touching the others.
    `drop_components` removes stale components (e.g. `graph` when the map is rebuilt).
    """

    def __init__(
        self, path: str | Path, base: Bundle | None = None, drop_components: tuple[str, ...] = (), what: str = "bundle"
    ):
        self.path = Path(path)
        self.what = what  # for messages: "bundle", "mapping checkpoint"
        self.model: BundleManifest = _manifest({"schema": SCHEMA, "schema_version": SCHEMA_VERSION, "files": {}})
        self._done = False
        self._folders: set[str] = set()  # folders of the staged version made so far (`_folder`)
        self._unsynced: dict[Path, None] = {}  # files written, to sync before the manifest (in order)
        self._handed: list[tuple[tuple[int, int, int, int], np.ndarray]] = []  # put_array(hand_over=True)
        with writing(self.path, what):
            self._staging = Staging(self.path)
            self._tmp = self._staging.folder
            try:
                if base is not None:
                    self._check_base(base)
                    self._start_from(base, drop_components)
            except BaseException:
                self.abort()
                raise
        self.model.written_by = f"terra {__version__}"
        self.model.version = (base.version if base is not None else 0) + 1
        self._base = base
        # A version built on `base` must replace `base` itself: another writer (a live session, a
        # second command) committing in between would otherwise be silently undone.
        same = base is not None and os.path.abspath(base.path) == os.path.abspath(self.path)
        self._base_version = base.version if base is not None and same else None
        self._base_manifest = manifest_json(base.model) if base is not None and same else None

    @property
    def base(self) -> Bundle | None:
        """The version this one starts from (None for a first version)."""
        return self._base

    @property
    def files(self) -> dict[str, FileEntry]:
        """The files of the version being written, by name (e.g. `graph/scene_graph.json`)."""
        return self.model.files

    def _start_from(self, base: Bundle, drop_components: tuple[str, ...]) -> None:
        data = manifest_json(base.model)
        data["files"] = {}
        for component in drop_components:
            data.get("components", {}).pop(component, None)
        self.model = _manifest(data)
        for file_name in base.files:
            if file_name.split("/", 1)[0] not in drop_components:
                self._link(base, file_name)

    def _link(self, base: Bundle, file_name: str) -> None:
        """File `file_name` of `base` into this version as it is: a hard link (a copy where links
        fail), never written through (`_put` unlinks before writing)."""
        # Checksummed: a damaged file of the same size must not be carried into a version whose
        # manifest vouches for it (hashed once per file identity: a file carried on is not hashed again).
        source = base._checked_path(file_name[:-4] if file_name.endswith(".npy") else file_name, verify=True)
        dst = os.path.join(self._tmp, file_name)  # strings: a live version links some 200 files
        self._folder(os.path.dirname(dst))
        try:
            os.link(source, dst)
        except OSError:
            shutil.copy2(source, dst)
        self.model.files[file_name] = base.files[file_name]

    def _folder(self, folder: str) -> None:
        """Make `folder` of the staged version once (a live version links some 200 chunk files)."""
        if folder not in self._folders:
            os.makedirs(folder, exist_ok=True)
            self._folders.add(folder)

    def keep_from_base(self, file_names: Sequence[str]) -> bool:
        """Carry files of the base version (e.g. a map chunk dropped with its component) into this
        version unchanged, when the base has all of them; False (nothing carried) otherwise."""
        base = self._base
        if base is None or not all(name in base.files for name in file_names):
            return False
        with writing(self.path, self.what):
            for name in file_names:
                self._link(base, name)
        return True

    def _edit(self, **changes: Any) -> None:
        """Set top-level manifest fields (JSON values), validated as the manifest model: a value
        the schema refuses (a user's duplicate class name, an oversized embedder name) is one
        TerraError line naming the field, raised before anything is committed."""
        from pydantic import ValidationError

        from terra.schemas import validation_message

        # The files (some 200 entries in a live version) are Terra's own, each a FileEntry made when
        # it was written: they are not validated again at each of a version's half dozen edits.
        fields = self.model.model_dump(mode="json", by_alias=True, exclude_unset=True, exclude={"files"})
        try:
            model = _manifest({**fields, **changes, "files": {}})
        except ValidationError as exc:
            raise TerraError(validation_message(f"{self.path / MANIFEST}", exc)) from None
        model.files = self.model.files
        self.model = model

    def set_embedder(self, name: str, dim: int) -> None:
        """The text embedder whose space the stored embeddings are in."""
        self._edit(embedder={"name": name, "dim": dim})

    def set_terrain_classes(self, names: list[str]) -> None:
        self._edit(terrain_classes=list(names))

    def set_perception(self, description: dict[str, Any]) -> None:
        """What produced the map's semantics (terra.perception.base.Perception.describe)."""
        self._edit(perception=description)

    def set_component(self, name: str, info: dict[str, Any]) -> None:
        """Manifest entry components.<name> (counts, config, stats), replacing any earlier one."""
        components = self.model.components.model_dump(mode="json", by_alias=True, exclude_unset=True)
        self._edit(components={**components, name: info})

    def update_component(self, name: str, **fields: Any) -> None:
        """Set `fields` of the existing entry components.<name>, keeping its others."""
        components = self.model.components.model_dump(mode="json", by_alias=True, exclude_unset=True)
        self._edit(components={**components, name: {**components.get(name, {}), **fields}})

    def _put(
        self, file_name: str, data: bytes | Sequence[bytes | memoryview], share: bool = False
    ) -> tuple[int, int, int, int] | None:
        """Write file `file_name` of the version (or link the base's, `share`); its identity when written."""
        from terra.schemas import FileEntry

        parts = [data] if isinstance(data, bytes) else list(data)
        hasher = hashlib.sha256()
        for part in parts:
            hasher.update(part)
        digest, size = hasher.hexdigest(), sum(len(p) for p in parts)
        if share and self._same_in_base(file_name, size, digest):
            return None
        dst = self._tmp / file_name
        with writing(self.path, self.what):
            self._folder(str(dst.parent))
            if dst.exists():
                dst.unlink()  # may be a hard link into the base bundle: never write through it
            identity = _write_new_file(dst, parts, sync=False)  # synced at commit, with the others
        self._unsynced[dst] = None
        _VERIFIED[identity] = digest
        self.model.files[file_name] = FileEntry(bytes=size, sha256=digest)
        return identity

    def _same_in_base(self, file_name: str, size: int, digest: str) -> bool:
        """Whether the base version holds `file_name` with these bytes (`size`, SHA-256 `digest`): then
        this version shares its file (a hard link) instead of writing the same bytes again, e.g. the
        unchanged arrays of a map chunk in which some points changed."""
        base = self._base
        entry = base.files.get(file_name) if base is not None else None
        if base is None or entry is None or entry.bytes != size or entry.sha256 != digest:
            return False
        dst = self._tmp / file_name
        if self.model.files.get(file_name) == entry and dst.exists():
            return True  # carried over from the base already
        try:
            with writing(self.path, self.what):
                dst.unlink(missing_ok=True)
                self._link(base, file_name)
        except TerraError:
            return False  # the base's copy is damaged: the bytes are written again
        return True

    def put_array(self, name: str, array: np.ndarray, share: bool = False, hand_over: bool = False) -> None:
        """Store an array as `<name>.npy`, e.g. `map/points` (written from the array's own memory).
        share: when the base version holds the same bytes under that name, link its file instead
        (a map chunk in which some arrays did not change: terra/mapping/chunks.py). hand_over: once
        the version is committed, the next `Bundle.array` of the file in this process takes a copy of
        `array` instead of reading it back (a live session's view of the version it committed)."""
        identity = self._put(f"{name}.npy", npy_parts(array), share)
        if hand_over and identity is not None:
            self._handed.append((identity, array.copy()))

    def put_json(self, name: str, obj: Any) -> None:
        """Store canonical JSON as `name` (which ends in .json)."""
        if not name.endswith(".json"):
            raise ValueError(f"JSON names end in .json, got {name!r}")
        self._put(name, dumps_json(obj).encode())

    def remove(self, name: str) -> None:
        file_name = Bundle._file_name(name)
        self.model.files.pop(file_name, None)
        (self._tmp / file_name).unlink(missing_ok=True)

    def commit(self, reclaim_in_background: bool = False) -> Bundle:
        """Write the manifest and swap the new version into place (the replaced version deleted
        in a background thread with `reclaim_in_background`: see Staging.commit)."""
        text = dumps_json(manifest_json(self.model)).encode()  # sorted keys: the files in name order
        current = _version_on_disk(self.path)
        if self._base_version is not None and current != self._base_version:
            self.abort()
            raise TerraError(
                f"{self.path}: the bundle changed while this {self.what} was written (version "
                f"{self._base_version} became {current}); nothing was written, run the command again"
            )
        if self._unchanged():
            self.abort()  # the same content again (a rerun, an identical rebuild): no new version
            return Bundle(self.path)
        try:
            with writing(self.path, self.what):
                # Every file and folder of the version is synced in one round before it is swapped in
                # (a staged folder is never rolled forward, so the manifest needs no sync of its own).
                _write_new_file(self._tmp / MANIFEST, text, sync=False)
                unsynced = [path for path in self._unsynced if os.path.lexists(path)] + [self._tmp / MANIFEST]
                self._staging.commit(reclaim_in_background, unsynced)
        except BaseException:
            self.abort()  # e.g. no room for the manifest: a failed commit leaves no staged version behind
            raise
        self._done = True
        for identity, array in self._handed:
            _hand_over(identity, array)
        self._handed.clear()
        return Bundle(self.path)

    def _check_base(self, base: Bundle) -> None:
        """Refuse to start from `base` when the bundle at the same path is no longer that version."""
        if os.path.abspath(base.path) != os.path.abspath(self.path):
            return
        current = _version_on_disk(self.path)
        if current != base.version:
            raise TerraError(
                f"{self.path}: the bundle changed while this {self.what} was written (version "
                f"{base.version} became {current}); nothing was written, run the command again"
            )

    def _unchanged(self) -> bool:
        """Whether this version holds exactly what its base (the bundle at the same path) holds."""
        if self._base_manifest is None:
            return False
        mine = manifest_json(self.model)
        mine.pop("version", None)
        base = {k: v for k, v in self._base_manifest.items() if k != "version"}
        return mine == base

    def abort(self) -> None:
        if not self._done:
            self._staging.discard()
            self._done = True
        self._handed.clear()

    def __enter__(self) -> BundleWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.abort()
        elif not self._done:
            self.commit()
