"""Errors a user can cause and fix. The CLI prints them as one line and exits with `exit_code`.

Every TerraError message is made safe to print as that one line when it is raised (`one_line`): an
echoed input over MAX_ECHO characters (a 10,000-digit node id, a query of a megabyte) is cut to its
start, an ellipsis and its length; control characters (a newline, a terminal escape) and lone
surrogates in it are shown escaped; and a message still longer than MAX_LINE is cut the same way.
"""

from __future__ import annotations

import re

MAX_ECHO = 200  # characters of one echoed value (a quoted input, a word, a path) in a message
MAX_LINE = 2000  # characters of a whole message

_LONG = f"{{{MAX_ECHO + 1},}}"  # a regex repeat: more than MAX_ECHO characters
_QUOTED = re.compile(f"'([^'\\n]{_LONG})'|\"([^\"\\n]{_LONG})\"")
_WORD = re.compile(rf"\S{_LONG}")


def shorten(text: str, limit: int = MAX_ECHO) -> str:
    """`text` if it has at most `limit` characters, else its first `limit - 3`, '...' and its length
    ("99999... (10,000 characters)"): at most `limit` characters before the count, so `one_line`
    of a line it made changes nothing."""
    if len(text) <= limit:
        return text
    return f"{text[: limit - 3]}... ({len(text):,} characters)"


def _printable(text: str) -> str:
    """`text` with characters a terminal would act on or could not encode shown escaped (\\n, \\x1b,
    \\ud800); spaces and every printable character of any script stay as they are."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() or c == " " else repr(c)[1:-1] for c in text)


def one_line(message: str) -> str:
    """`message` as one short printable line (see the module docstring)."""
    text = _printable(str(message))

    def quoted(match: re.Match[str]) -> str:
        quote, inner = ("'", match.group(1)) if match.group(1) is not None else ('"', match.group(2))
        short = shorten(inner, MAX_ECHO - 2)  # the quotes count too
        head, _, count = short.rpartition("... (")
        return f"{quote}{head}...{quote} ({count}"

    text = _QUOTED.sub(quoted, text)
    text = _WORD.sub(lambda m: shorten(m.group(0).rstrip(":;,")) + m.group(0)[len(m.group(0).rstrip(":;,")) :], text)
    return shorten(text, MAX_LINE)


class TerraError(Exception):
    """Bad input or configuration: one clear line naming the file or field and what was expected."""

    exit_code = 2

    def __init__(self, message: object = "", *args: object) -> None:
        super().__init__(one_line(str(message)), *args)


class NoPathError(TerraError):
    """A plan request whose goal cannot be reached under the given terrain constraints."""

    exit_code = 3
