"""Run `terra ARGS` and kill the process with SIGKILL at a named point of terra.bundle's writing
(tests/reliability/test_crash_safety.py). Usage: python -m tests.reliability.killpoint POINT N -- ARGS...

Points (the Nth time the process gets there, counted from 1; no kill when it never does):
  write     before the Nth file of a staged bundle or checkpoint is written
  exchange  before the Nth atomic exchange of a staged folder with its target
  remove    after the Nth swap, before the replaced version is deleted
  rmtree    in the middle of deleting the Nth replaced version (some files gone, not all)
  rename    with the exchange unavailable (the two-rename fallback), between the two renames
  fsize     no kill: RLIMIT_FSIZE of N bytes (a write past it fails with EFBIG, like a full disk)
"""

from __future__ import annotations

import os
import signal
import sys


def _kill() -> None:
    sys.stdout.flush()
    sys.stderr.flush()
    os.kill(os.getpid(), signal.SIGKILL)


class _Counter:
    def __init__(self, n: int) -> None:
        self.n, self.seen = n, 0

    def hit(self) -> bool:
        self.seen += 1
        return self.seen == self.n


def install(point: str, n: int) -> None:
    import terra.bundle as bundle

    counter = _Counter(n)
    if point == "write":
        _kill_on_write(bundle, counter)
    elif point == "exchange":
        _kill_on_exchange(bundle, counter)
    elif point in ("remove", "rmtree"):
        _kill_on_replace(bundle, counter, remove_half=point == "rmtree")
    elif point == "rename":
        _kill_on_rename(bundle, counter)
    elif point == "fsize":
        _limit_file_size(n)
    else:
        raise SystemExit(f"unknown kill point {point!r}")


def _kill_on_write(bundle, counter: _Counter) -> None:
    """Die before the n-th new file of a bundle is written."""
    real_write = bundle._write_new_file

    def write(path, data, mode=0o666, **options):
        if counter.hit():
            _kill()
        return real_write(path, data, mode, **options)

    bundle._write_new_file = write


def _kill_on_exchange(bundle, counter: _Counter) -> None:
    """Die before the n-th atomic exchange of two folders."""
    real_exchange = bundle.exchange_paths

    def exchange(a, b):
        if counter.hit():
            _kill()
        return real_exchange(a, b)

    bundle.exchange_paths = exchange


def _kill_on_replace(bundle, counter: _Counter, remove_half: bool) -> None:
    """Die after the n-th folder swap, before the replaced folder is removed (with remove_half,
    after half of its files are: a removal cut short)."""
    real_replace = bundle.replace_folder

    def replace(new, target):
        replaced = real_replace(new, target)
        if replaced is not None and counter.hit():
            if remove_half:
                files = sorted(p for p in replaced.rglob("*") if p.is_file())
                for p in files[: max(1, len(files) // 2)]:
                    p.unlink()
            _kill()
        return replaced

    bundle.replace_folder = replace


def _kill_on_rename(bundle, counter: _Counter) -> None:
    """Without atomic exchange (the two-rename fallback), die after the n-th rename to an .old- name."""
    bundle.exchange_paths = lambda a, b: False
    real_os = bundle.os

    class OsWithKill:
        def __getattr__(self, name):
            return getattr(real_os, name)

        @staticmethod
        def rename(a, b):
            real_os.rename(a, b)
            if ".old-" in os.fspath(b) and counter.hit():
                _kill()

    bundle.os = OsWithKill()


def _limit_file_size(n: int) -> None:
    """Files may grow to n bytes; writing past that fails (EFBIG) instead of killing the process."""
    import resource

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (n, n))


def main() -> None:
    point, n, sep, *args = sys.argv[1:]
    if sep != "--":
        raise SystemExit(__doc__)
    install(point, int(n))
    from terra.cli import main as terra_main

    terra_main(args)


if __name__ == "__main__":
    main()
