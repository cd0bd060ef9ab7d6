"""Progress bars and per-stage timing tables for long commands."""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager
from typing import Iterable, Iterator, TypeVar

from tqdm.auto import tqdm

T = TypeVar("T")


def progress(iterable: Iterable[T], desc: str, total: int | None = None, enabled: bool = True) -> Iterator[T]:
    """A progress bar on stderr; silent when disabled or when stderr is not a terminal."""
    return iter(tqdm(iterable, desc=desc, total=total, disable=not enabled or not sys.stderr.isatty(), leave=False, dynamic_ncols=True))


def close_bars() -> None:
    """Close every open progress bar, ours and libraries' (Terra's bars do not stay on screen): an
    error printed next starts on a clean line and stays one line."""
    for bar in list(getattr(tqdm, "_instances", ())):
        try:
            bar.close()
        except Exception:  # noqa: BLE001 - a bar that cannot be closed must not hide the error being reported
            pass


class StageTimer:
    """Accumulates wall time per named stage; `table()` renders the summary printed at the end."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.calls: dict[str, int] = {}

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, time.perf_counter() - start)

    def add(self, name: str, seconds: float) -> None:
        self.seconds[name] = self.seconds.get(name, 0.0) + seconds
        self.calls[name] = self.calls.get(name, 0) + 1

    def table(self, title: str = "timing") -> str:
        total = sum(self.seconds.values())
        width = max([len(n) for n in self.seconds] + [5])
        lines = [f"{title}:", f"  {'stage':<{width}}  {'calls':>6}  {'seconds':>9}  {'share':>6}"]
        for name, sec in self.seconds.items():
            share = sec / total if total > 0 else 0.0
            lines.append(f"  {name:<{width}}  {self.calls[name]:>6}  {sec:>9.3f}  {share:>6.1%}")
        lines.append(f"  {'total':<{width}}  {'':>6}  {total:>9.3f}")
        return "\n".join(lines)

    def to_json(self) -> dict[str, float]:
        return {k: round(v, 6) for k, v in self.seconds.items()}


class TimeProgress:
    """A progress bar over a span of message time (seconds), for streams read in time order."""

    def __init__(self, start: float, end: float, desc: str, enabled: bool = True) -> None:
        self.start, self.done = float(start), 0.0
        self.bar = tqdm(total=max(float(end) - float(start), 0.0), desc=desc, unit="s", leave=False, dynamic_ncols=True,
                        disable=not enabled or not sys.stderr.isatty(),
                        bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s")

    def update(self, t: float) -> None:
        """Advance to message time `t` (seconds)."""
        now = min(max(float(t) - self.start, self.done), self.bar.total)
        if now > self.done:
            self.bar.update(now - self.done)
            self.done = now

    def close(self) -> None:
        self.bar.close()
