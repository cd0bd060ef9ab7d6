"""Progress of long work, one mechanism for every command, and per-stage timing tables.

Where stderr is a terminal, long loops show tqdm bars. Where it is not (a log file, CI, a pipe),
a bar would be invisible or garble the log, so a loop prints one line every few seconds instead:

    terra: mapping 120/400 frames (30%), 4.1 frames/s, about 1 min 08 s left

and a closing line (`mapping 400/400 frames in 1 min 37 s`) when it printed any. Work with no
count (clustering, building a world) reports that it is still running the same way (`working`).
A step of a few seconds prints nothing, so short commands stay quiet.

Environment: TERRA_PROGRESS = auto (default: bars on a terminal, lines elsewhere), bars, lines or
off; TERRA_PROGRESS_INTERVAL = seconds between lines (default 5).
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

T = TypeVar("T")

MODES = ("auto", "bars", "lines", "off")
DEFAULT_INTERVAL_S = 5.0
_state = {"last_line": 0.0, "active": 0}  # when a line was last printed (monotonic s); counted stages running
_lock = threading.Lock()


def progress_mode() -> str:
    """'bars', 'lines' or 'off' for this process: $TERRA_PROGRESS, else bars on a terminal."""
    mode = os.environ.get("TERRA_PROGRESS", "auto").strip().lower() or "auto"
    if mode not in MODES:
        mode = "auto"
    if mode != "auto":
        return mode
    return "bars" if _isatty(sys.stderr) else "lines"


def line_interval() -> float:
    """Seconds between progress lines ($TERRA_PROGRESS_INTERVAL, default 5)."""
    try:
        return max(float(os.environ.get("TERRA_PROGRESS_INTERVAL", DEFAULT_INTERVAL_S)), 0.0)
    except ValueError:
        return DEFAULT_INTERVAL_S


def _isatty(stream: Any) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def duration(seconds: float) -> str:
    """'8 s', '1 min 08 s', '2 h 03 min': a duration for people."""
    seconds = max(float(seconds), 0.0)
    if seconds < 60:
        return f"{seconds:.0f} s"
    minutes, sec = divmod(int(round(seconds)), 60)
    if minutes < 60:
        return f"{minutes} min {sec:02d} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min"


def _emit(line: str) -> None:
    with _lock:
        _state["last_line"] = time.monotonic()
        print(f"terra: {line}", file=sys.stderr, flush=True)


def note(line: str) -> None:
    """One line on stderr for a one-off wait the user should know about (a model prepared once),
    on a terminal and elsewhere alike; nothing with TERRA_PROGRESS=off."""
    if os.environ.get("TERRA_PROGRESS", "auto").strip().lower() != "off":
        _emit(line)


class Progress:
    """Progress of one stage of `total` steps (None: unknown): `update(n)`, then `close()`.

    A tqdm bar on a terminal; otherwise a line every `line_interval()` seconds with the stage,
    the count, the rate and the time left, and a closing line when any was printed."""

    def __init__(
        self, desc: str, total: float | None = None, unit: str = "", enabled: bool = True, count_format: str = "{:.0f}"
    ) -> None:
        self.desc, self.total, self.unit = desc, total, unit
        self.count_format = count_format
        self.done = 0.0
        self.mode = progress_mode() if enabled else "off"
        self.start = self.last = time.monotonic()
        self.printed = False
        self.bar = None
        if self.mode == "lines":
            _state["active"] += 1
        if self.mode == "bars":
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, desc=desc, unit=f" {unit}" if unit else "it", leave=False, dynamic_ncols=True)

    def update(self, n: float = 1) -> None:
        self.done += n
        if self.bar is not None:
            self.bar.update(n)
        elif self.mode == "lines":
            now = time.monotonic()
            if now - self.last >= line_interval():
                self.last = now
                self.printed = True
                _emit(self.line(now))

    def line(self, now: float) -> str:
        """'mapping 120/400 frames (30%), 4.1 frames/s, about 1 min 08 s left'."""
        elapsed = max(now - self.start, 1e-9)
        rate = self.done / elapsed
        unit = f" {self.unit}" if self.unit else ""
        count = self.count_format.format(self.done)
        if self.total:
            count += f"/{self.count_format.format(self.total)}{unit} ({100 * self.done / self.total:.0f}%)"
        else:
            count += unit
        text = f"{self.desc} {count}, {rate:.3g}{unit}/s"
        if not self.total:
            return text + f" ({duration(elapsed)} so far)"
        if rate > 0:
            text += f", about {duration((self.total - self.done) / rate)} left"
        return text

    def close(self, finished: bool = True) -> None:
        """End the stage; the closing line only when it `finished` (not on an error or Ctrl-C)."""
        if self.mode == "lines":
            self.mode = "closed"
            _state["active"] -= 1
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        elif self.printed and finished:
            self.printed = False
            unit = f" {self.unit}" if self.unit else ""
            took = duration(time.monotonic() - self.start)
            _emit(f"{self.desc} {self.count_format.format(self.done)}{unit} done in {took}")


def progress(
    iterable: Iterable[T], desc: str, total: int | None = None, enabled: bool = True, unit: str = ""
) -> Iterator[T]:
    """Iterate `iterable`, reporting progress (see Progress); nothing when disabled."""
    if total is None and hasattr(iterable, "__len__"):
        total = len(iterable)  # type: ignore[arg-type]
    bar = Progress(desc, total, unit, enabled)
    finished = False
    try:
        for item in iterable:
            yield item
            bar.update(1)
        finished = True
    finally:
        bar.close(finished)


@contextmanager
def working(desc: str, enabled: bool = True) -> Iterator[None]:
    """Work with no count (a clustering, building a world): on a terminal a line with the time
    so far, elsewhere 'DESC: still working (25 s so far)' every few seconds, unless some other
    progress line was printed meanwhile."""
    mode = progress_mode() if enabled else "off"
    if mode == "off":
        yield
        return
    stop = threading.Event()
    start = time.monotonic()
    bar = None
    if mode == "bars":
        from tqdm.auto import tqdm

        bar = tqdm(total=None, desc=desc, leave=False, dynamic_ncols=True, bar_format="{desc}: {elapsed}")

    def beat() -> None:
        while not stop.wait(1.0 if bar is not None else min(max(line_interval(), 0.05), 1.0)):
            if bar is not None:
                bar.refresh()
            elif quiet_for() >= line_interval() * (2 if _state["active"] else 1):
                _emit(f"{desc}: still working ({duration(time.monotonic() - start)} so far)")

    def quiet_for() -> float:  # seconds since the last line (of any reporter) or the start
        return time.monotonic() - max(_state["last_line"], start)

    thread = threading.Thread(target=beat, name="terra-progress", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
        if bar is not None:
            bar.close()


def close_bars() -> None:
    """Close every open progress bar, ours and libraries' (Terra's bars do not stay on screen): an
    error printed next starts on a clean line and stays one line."""
    tqdm_module = sys.modules.get("tqdm.std")  # no bar was ever made when tqdm is not imported
    for bar in list(getattr(getattr(tqdm_module, "tqdm", None), "_instances", ())):
        with contextlib.suppress(Exception):  # a bar that cannot be closed must not hide the error being reported
            bar.close()


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
    """Progress over a span of message time (seconds), for streams read in time order."""

    def __init__(self, start: float, end: float, desc: str, enabled: bool = True) -> None:
        self.start = float(start)
        self.span = max(float(end) - float(start), 0.0)
        self.bar = Progress(desc, self.span, "s of log", enabled)

    def update(self, t: float) -> None:
        """Advance to message time `t` (seconds)."""
        now = min(max(float(t) - self.start, self.bar.done), self.span)
        if now > self.bar.done:
            self.bar.update(now - self.bar.done)

    def close(self) -> None:
        self.bar.close()
