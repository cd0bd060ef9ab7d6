"""Counts in words for people: "1 region", "2 regions", "1 query", "3 queries"."""

from __future__ import annotations


def counted(count: int, singular: str, plural: str | None = None) -> str:
    """`count` and the noun in the right number ("1 region", "0 regions"); `plural` when the noun
    does not simply take an s ("query", "queries"). Counts from 10,000 get thousands separators."""
    noun = singular if count == 1 else (plural or singular + "s")
    number = f"{count:,}" if abs(count) >= 10_000 else str(count)
    return f"{number} {noun}"
