"""Reading and writing files at Terra's boundary: every failure a file can cause is one TerraError line.

Readers open files without blocking (a FIFO or device named as a scan is refused, never waited
on), refuse folders and oversized files before reading, and map what a file's content can raise
(undecodable UTF-8, nesting deep enough to exhaust the parser's recursion, NaN and infinity in JSON,
truncated data, an allocation that cannot be met) to one line naming the file. Writers map
`OSError` to one line naming the path and, for a full disk, a read-only file system or missing
permission, what to do about it.

Only these I/O and parsing errors are mapped, and only here: an exception raised anywhere else is a
defect and keeps its traceback (terra.cli asks the user to report it).
"""

from __future__ import annotations

import errno
import json
import math
import os
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from terra.errors import TerraError

MAX_TEXT_BYTES = 256 << 20  # text, JSON and YAML files larger than this are refused before reading
MAX_DEPTH = 64  # nesting of a JSON / YAML document a person or Terra writes (configs need < 10)
MAX_YAML_NODES = 1_000_000  # values of a YAML document with its aliases expanded ("billion laughs")

_WHAT_TO_DO = {
    errno.ENOSPC: "the disk is full: free some space (or write to another disk) and run the command again",
    errno.EDQUOT: "the disk quota is exceeded: free some space (or write elsewhere) and run the command again",
    errno.EFBIG: "the file is larger than this system or user may write: write elsewhere or raise the limit",
    errno.EROFS: "the file system is read-only: write to another folder",
    errno.EACCES: "permission denied: write to a folder you may write to, or change its permissions",
    errno.EPERM: "operation not permitted: write to a folder you may write to, or change its permissions",
}


# ------------------------------------------------------------------------------------- errors
def _a(what: str) -> str:
    """`what` with its indefinite article: "a JSON file", "an image", "a .npy array"."""
    return ("an " if what[:1].lower() in "aeiou" else "a ") + what


class OutputError(TerraError):
    """An output could not be written (full disk, read-only folder, permissions): what a long run
    that checkpoints can resume from once the cause is fixed."""


def read_error(path: str | Path, exc: OSError, what: str = "file") -> TerraError:
    """One line for an OSError met reading `path` (a `what`)."""
    reason = exc.strerror or type(exc).__name__
    if isinstance(exc, IsADirectoryError):
        return TerraError(f"{path}: is a folder, expected {_a(what)}")
    if isinstance(exc, FileNotFoundError):
        return TerraError(f"{path}: no such {what}")
    return TerraError(f"{path}: cannot read the {what} ({reason})")


def write_error(path: str | Path, exc: OSError, what: str = "output") -> OutputError:
    """One line for an OSError met writing `path` (a `what`): the path, the system's reason and,
    for a full disk, a read-only file system or a permission problem, what to do."""
    where = exc.filename or path
    reason = exc.strerror or str(exc) or type(exc).__name__  # some writers (ndarray.tofile) set no errno
    advice = _WHAT_TO_DO.get(exc.errno or 0)
    tail = f"; {advice}" if advice else ""
    return OutputError(f"{where}: cannot write the {what} ({reason}){tail}; nothing was replaced")


# A write failure whose errno only a write can meet (never a read), and a name the system refuses.
_WRITE_ONLY = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS)


def escaped_os_error(exc: OSError) -> TerraError | None:
    """The one line for an OSError that reached the command line outside this module's readers and
    writers, where its cause is the user's to fix whoever met it: a full disk, quota, size limit or
    read-only file system (`write_error`), or a file name longer than the system allows (a name the
    user gave). None for any other OSError: that one is a defect and keeps its traceback."""
    if exc.errno in _WRITE_ONLY:
        return write_error(exc.filename or "output", exc)
    if exc.errno == errno.ENAMETOOLONG:
        name = os.fsdecode(exc.filename) if exc.filename is not None else "a path"
        return TerraError(f"{name}: file name too long for this system (at most {_name_max()} bytes a name)")
    return None


def _name_max() -> int:
    try:
        return os.pathconf(".", "PC_NAME_MAX")
    except (OSError, ValueError):
        return 255


@contextmanager
def writing(path: str | Path, what: str = "output") -> Iterator[None]:
    """Map an OSError raised while writing `path` to one TerraError line (see `write_error`)."""
    try:
        yield
    except OSError as exc:
        raise write_error(path, exc, what) from None


def memory_error(path: str | Path, size: int, what: str) -> TerraError:
    return TerraError(f"{path}: not enough memory to load the {what} ({size:,} bytes)")


# ------------------------------------------------------------------------------------ reading
def open_regular(path: str | Path, what: str = "file") -> int:
    """A read-only descriptor of regular file `path`, opened without blocking: a folder, FIFO,
    socket or device is refused (TerraError), so a scan that is a named pipe never hangs a run."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise read_error(path, exc, what) from None
    try:
        mode = os.fstat(fd).st_mode
    except OSError as exc:
        os.close(fd)
        raise read_error(path, exc, what) from None
    if not stat.S_ISREG(mode):
        os.close(fd)
        kind = "a folder" if stat.S_ISDIR(mode) else "not a regular file (a pipe, socket or device)"
        raise TerraError(f"{path}: is {kind}, expected {_a(what)}")
    if hasattr(os, "set_blocking"):
        os.set_blocking(fd, True)
    return fd


def read_bytes(path: str | Path, what: str = "file", limit: int | None = None) -> bytes:
    """The bytes of regular file `path` (see `open_regular`); TerraError when it holds more than
    `limit` bytes, checked before reading."""
    fd = open_regular(path, what)
    with os.fdopen(fd, "rb") as f:
        try:
            size = os.fstat(f.fileno()).st_size
            if limit is not None and size > limit:
                raise TerraError(f"{path}: {size:,} bytes, more than the {limit:,} {_a(what)} may hold")
            return f.read()
        except OSError as exc:
            raise read_error(path, exc, what) from None
        except MemoryError:
            raise memory_error(path, size, what) from None


def decode_text(data: bytes, source: str | Path, what: str = "text file") -> str:
    """UTF-8 text of `data` (a BOM is dropped); TerraError naming the first undecodable byte."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise TerraError(
            f"{source}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}); expected {_a(what)}"
        ) from None


def read_text(path: str | Path, what: str = "text file", limit: int = MAX_TEXT_BYTES) -> str:
    """UTF-8 text of regular file `path` (see `read_bytes`, `decode_text`)."""
    return decode_text(read_bytes(path, what, limit), path, what)


# --------------------------------------------------------------------------------------- JSON
def _no_constant(name: str) -> float:
    raise ValueError(f"{name} is not a JSON number")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"number {text[:20]} does not fit a 64-bit float")
    return value


def parse_json(text: str, source: str | Path, what: str = "JSON file", max_depth: int | None = MAX_DEPTH) -> Any:
    """The value of JSON `text`: NaN, Infinity and numbers beyond float range are refused, and with
    `max_depth` so is nesting deeper than that; TerraError naming `source` otherwise."""
    try:
        value = json.loads(text, parse_constant=_no_constant, parse_float=_finite_float)
    except RecursionError:
        raise TerraError(f"{source}: nested too deeply to be {_a(what)}") from None
    except ValueError as exc:  # json.JSONDecodeError, our number checks, int digits limit
        raise TerraError(f"{source}: not valid JSON ({str(exc).splitlines()[0]})") from None
    except MemoryError:
        raise memory_error(source, len(text), what) from None
    if max_depth is not None:
        check_depth(value, source, what, max_depth)
    return value


def read_json(
    path: str | Path, what: str = "JSON file", limit: int = MAX_TEXT_BYTES, max_depth: int | None = MAX_DEPTH
) -> Any:
    """The JSON value in file `path` (see `read_text`, `parse_json`)."""
    return parse_json(read_text(path, what, limit), path, what, max_depth)


def check_depth(
    value: Any, source: str | Path, what: str, max_depth: int = MAX_DEPTH, max_nodes: int | None = None
) -> None:
    """TerraError when `value` nests deeper than `max_depth`, refers to itself (a recursive YAML
    alias) or, with `max_nodes`, holds more values than that once shared sub-values (YAML aliases)
    are counted each time they appear. Iterative: no input can exhaust the recursion limit here."""
    height: dict[int, int] = {}
    size: dict[int, int] = {}
    active: set[int] = set()  # the containers on the current path (a DFS with explicit exit markers)
    stack: list[tuple[Any, bool]] = [(value, False)]
    while stack:
        item, leaving = stack.pop()
        if not isinstance(item, (dict, list)):
            continue
        key = id(item)
        children = [c for c in (item.values() if isinstance(item, dict) else item) if isinstance(c, (dict, list))]
        if leaving:
            active.discard(key)
            height[key] = 1 + max((height[id(c)] for c in children), default=0)
            size[key] = 1 + len(item) - len(children) + sum(size[id(c)] for c in children)
            if height[key] > max_depth:
                raise TerraError(f"{source}: nested more than {max_depth} levels deep; expected {_a(what)}")
            if max_nodes is not None and size[key] > max_nodes:
                raise TerraError(
                    f"{source}: holds more than {max_nodes:,} values once its aliases are expanded; expected {_a(what)}"
                )
            continue
        if key in height:
            continue
        active.add(key)
        stack.append((item, True))
        for child in children:
            if id(child) in active:
                raise TerraError(f"{source}: refers to itself (a recursive alias); expected {_a(what)}")
            if id(child) not in height:
                stack.append((child, False))


# --------------------------------------------------------------------------------------- YAML
def parse_yaml(text: str, source: str | Path, what: str = "YAML file") -> Any:
    """The value of YAML `text` (safe loader: plain data only); TerraError naming `source` for
    invalid YAML, nesting deeper than MAX_DEPTH, or aliases expanding past MAX_YAML_NODES."""
    import yaml

    try:
        value = yaml.safe_load(text)
    except RecursionError:
        raise TerraError(f"{source}: nested too deeply to be {_a(what)}") from None
    except yaml.YAMLError as exc:
        raise TerraError(f"{source}: not valid YAML ({str(exc).splitlines()[0]})") from None
    except (ValueError, OverflowError) as exc:  # a value the safe constructor cannot build (a date of year 0, ...)
        raise TerraError(f"{source}: not valid YAML ({str(exc).splitlines()[0]})") from None
    except MemoryError:
        raise memory_error(source, len(text), what) from None
    check_depth(value, source, what, MAX_DEPTH, MAX_YAML_NODES)
    return value


def read_yaml(path: str | Path, what: str = "YAML file", limit: int = MAX_TEXT_BYTES) -> Any:
    """The YAML value in file `path` (see `read_text`, `parse_yaml`)."""
    return parse_yaml(read_text(path, what, limit), path, what)
