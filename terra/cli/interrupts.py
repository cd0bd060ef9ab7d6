"""What Ctrl-C keeps: each long command says, before it starts working, what an interruption
leaves behind and how to go on; `terra` prints that one line and exits with 130. No commands
live here.

A note is a callable evaluated at the moment of the interruption, so it can report how far the
work got (e.g. the frame of `terra map`'s last checkpoint).
"""

from __future__ import annotations

from typing import Callable

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
