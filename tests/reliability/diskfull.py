"""A full disk in-process: every file written through Python's `open` (builtins.open, io.open, so also
pathlib's write_bytes / write_text and os.fdopen) and every folder made with os.mkdir counts as one
write; the n-th raises OSError(ENOSPC) naming its path, as a full disk does. Used by
tests/reliability/test_full_disk.py to fail each writing command at every write of a run.

`count_writes(fn)` runs `fn` with the counter on and returns how many writes it made (and what).
"""

from __future__ import annotations

import builtins
import errno
import io
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

_WRITE_MODES = set("wax+")


class DiskFull:
    """The counter: `fail_at` (None: never) is the write number, from 1, that raises ENOSPC."""

    def __init__(self, fail_at: int | None = None) -> None:
        self.fail_at = fail_at
        self.seen: list[str] = []

    def hit(self, what: str) -> None:
        self.seen.append(what)
        if self.fail_at is not None and len(self.seen) == self.fail_at:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), what)


class _FullFile:
    """A real file object whose first `write` counts (and may fail); everything else passes through."""

    def __init__(self, f: Any, disk: DiskFull, name: str) -> None:
        self._f, self._disk, self._name, self._counted = f, disk, name, False

    def write(self, data: Any) -> int:
        if not self._counted:
            self._counted = True
            self._disk.hit(self._name)
        return self._f.write(data)

    def __enter__(self) -> _FullFile:
        self._f.__enter__()
        return self

    def __exit__(self, *exc: Any) -> Any:
        return self._f.__exit__(*exc)

    def __iter__(self) -> Iterator[Any]:
        return iter(self._f)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)


@contextmanager
def full_disk(fail_at: int | None) -> Iterator[DiskFull]:
    """Within the block, the `fail_at`-th write (a file's first write or a mkdir) raises ENOSPC."""
    disk = DiskFull(fail_at)
    real_open, real_mkdir = io.open, os.mkdir

    def opener(file: Any, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        f = real_open(file, mode, *args, **kwargs)
        if not _WRITE_MODES & set(mode):
            return f
        name = os.fsdecode(file) if not isinstance(file, int) else _fd_name(file)
        return _FullFile(f, disk, name)

    def mkdir(path: Any, mode: int = 0o777, *args: Any, **kwargs: Any) -> None:
        if not os.path.lexists(path):  # an existing one is FileExistsError, full disk or not
            disk.hit(os.fsdecode(path))
        real_mkdir(path, mode, *args, **kwargs)

    builtins.open, io.open, os.mkdir = opener, opener, mkdir
    try:
        yield disk
    finally:
        builtins.open, io.open, os.mkdir = real_open, real_open, real_mkdir


def _fd_name(fd: int) -> str:
    try:
        return os.readlink(f"/proc/self/fd/{fd}")
    except OSError:
        return f"<fd {fd}>"


def count_writes(fn: Callable[[], Any]) -> tuple[Any, list[str]]:
    """(fn's result, the writes it made, in order) with no failure injected."""
    with full_disk(None) as disk:
        result = fn()
    return result, disk.seen
