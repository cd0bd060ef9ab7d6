"""How `terra ... --help` reads: plain text wrapped to the terminal, the same on a terminal and in a
log, with placeholders in capitals as in most command lines (`--out PATH`, `BUNDLE`, `QUERIES...`).

Typer's own rendering shows `<bool>`, `<path>` and `{bundle}` placeholders, keeps a docstring's
line breaks in the command list and reads square brackets as markup (`terra-3dsg[serve]` came out
as `terra-3dsg`); this module turns that off on the finished command tree. No commands live here.
"""

from __future__ import annotations

import inspect
import types
from pathlib import Path
from typing import Any, get_args, get_origin

_NAMES = {Path: "PATH", str: "TEXT", int: "INTEGER", float: "NUMBER"}


def _metavar(annotation: Any) -> str | None:
    """A placeholder for a value of `annotation` (None for flags)."""
    origin = get_origin(annotation)
    if origin in (list, tuple):
        args = [a for a in get_args(annotation) if a is not Ellipsis]
        if origin is tuple:
            return " ".join(_metavar(a) or "VALUE" for a in args)
        return _metavar(args[0]) if args else "VALUE"
    if annotation is bool:
        return None
    return _NAMES.get(annotation, "VALUE")


def _usage_name(param: Any) -> str:
    """Usage-line name of an argument: BUNDLE, [QUERIES]... (not typer's {bundle})."""
    name = param.metavar
    if not param.required:
        name = f"[{name}]"
    return name + ("..." if param.nargs != 1 else "")


def _no_type(param: Any, ctx: Any = None) -> None:
    return None


def _tidy_params(command: Any) -> None:
    for param in command.params:
        kind = type(param).__name__
        if kind == "TyperArgument":
            if param.metavar is None:
                param.metavar = (param.name or "value").upper()
            # Instance overrides: BUNDLE rather than {bundle} in the usage line, no `<path>` beside it.
            param._usage_display_name = types.MethodType(_usage_name, param)
            param.display_type_rich = types.MethodType(_no_type, param)
        elif kind == "TyperOption" and param.metavar is None and not getattr(param, "is_flag", False):
            descriptor = getattr(param, "type_descriptor", None)
            if descriptor is not None:
                param.metavar = _metavar(descriptor.annotation)


def _examples_verbatim(text: str) -> str:
    """Help text whose 'Example...' paragraphs keep their lines (click's \\b marker), so a
    command to copy is never wrapped in the middle."""
    paragraphs = inspect.cleandoc(text).split("\n\n")
    return "\n\n".join("\b\n" + p if p.lstrip().startswith("Example") else p for p in paragraphs)


def tidy_help(command: Any) -> Any:
    """Plain help text and capitalised placeholders on every command of the tree; returns it."""
    if hasattr(command, "rich_markup_mode"):
        command.rich_markup_mode = None
    if command.help and "\b" not in command.help:
        command.help = _examples_verbatim(command.help)
    _tidy_params(command)
    for sub in getattr(command, "commands", {}).values():
        tidy_help(sub)
    return command
