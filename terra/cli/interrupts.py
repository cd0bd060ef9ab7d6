"""What Ctrl-C keeps: each long command says, before it starts working, what an interruption
leaves behind and how to go on; `terra` prints that one line and exits with 130. No commands
live here.

A note is a callable evaluated at the moment of the interruption, so it can report how far the
work got (e.g. the frame of `terra map`'s last checkpoint).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

NOTHING_WRITTEN = "nothing was written; run the same command again"
_note: dict[str, Callable[[], str] | None] = {"note": None}


def on_interrupt(note: str | Callable[[], str]) -> None:
    """Set what the current command's interruption message says (replacing any earlier note)."""
    _note["note"] = (lambda: note) if isinstance(note, str) else note


def clear() -> None:
    _note["note"] = None


def interrupted_message() -> str:
    """The one line printed on Ctrl-C: 'terra: interrupted; <what was kept and how to resume>'."""
    note = _note["note"]
    try:
        text = note() if note is not None else NOTHING_WRITTEN
    except Exception:  # the note describes files; never let it hide the interruption itself
        text = NOTHING_WRITTEN
    return f"terra: interrupted; {text}"


class Interrupted(Exception):
    """Ctrl-C inside a command (Typer would otherwise turn it into a silent exit code 130)."""


def _caused_by_interrupt(exc: BaseException) -> bool:
    """Whether a KeyboardInterrupt is among the causes and contexts of `exc`."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        if isinstance(current, KeyboardInterrupt):
            return True
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return False


def catch_interrupts(command: Any) -> Any:
    """Every command of the tree raises Interrupted on Ctrl-C, for `terra.cli.run` to report."""
    callback = getattr(command, "callback", None)
    if callback is not None and not getattr(callback, "_terra_interruptible", False):

        @functools.wraps(callback)
        def interruptible(*args: Any, **kwargs: Any) -> Any:
            try:
                return callback(*args, **kwargs)
            except KeyboardInterrupt as exc:
                raise Interrupted() from exc
            except SystemError as exc:
                # Ctrl-C inside a compiled kernel (the simulator's numba loops) surfaces as a
                # SystemError whose context is the KeyboardInterrupt: it is the same interruption.
                if _caused_by_interrupt(exc):
                    raise Interrupted() from exc
                raise

        interruptible._terra_interruptible = True  # type: ignore[attr-defined]
        command.callback = interruptible
    for sub in getattr(command, "commands", {}).values():
        catch_interrupts(sub)
    return command
