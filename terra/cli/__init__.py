"""The `terra` command line: one Typer app; each module in this package adds its commands.

Every user error (TerraError) becomes one line on stderr and its exit code (2, or 3 for an
unreachable plan goal); never a traceback for bad input. Any other exception is a defect in Terra:
`main` shows its traceback and asks for a report (exit code 1); `run` lets it propagate.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
import warnings
from typing import Any, Protocol, runtime_checkable

import typer

from terra.errors import TerraError, one_line

app = typer.Typer(
    name="terra",
    help="Terra: terrain-aware 3D scene graphs for outdoor robots.\n\nExample: terra demo --out terra-demo",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # plain help text (terra.cli.helptext)
    context_settings={"help_option_names": ["-h", "--help"]},
)


@runtime_checkable
class _ShowsItself(Protocol):
    """A usage error of Typer's bundled click: it prints itself and carries its exit code."""

    exit_code: int

    def show(self) -> None: ...


def _version(value: bool) -> None:
    if value:
        from terra import __version__

        typer.echo(f"terra {__version__}")
        raise typer.Exit(0)


@app.callback()
def _options(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Terra: terrain-aware 3D scene graphs for outdoor robots.

    Example: terra demo --out terra-demo
    """


def _load_commands() -> None:
    for module in sorted(m.name for m in pkgutil.iter_modules(__path__)):
        importlib.import_module(f"{__name__}.{module}")


def fail(message: str, code: int = 2) -> None:
    """Print one error line and exit with `code`."""
    typer.echo(f"terra: error: {message}", err=True)
    raise typer.Exit(code)


_NOTES: list[str] = []
_COMMAND: Any = None  # the click command tree of `app`, as `run` prepares it


def note(message: str) -> None:
    """A remark for the user (e.g. keys of a task file the command ignores), printed on stderr once
    the command has succeeded: a refused command still says one line, its error."""
    _NOTES.append(message)


def run(argv: list[str] | None = None) -> int:
    """Run the CLI in-process and return its exit code (0 success, 2 user error, 3 no path).

    Warnings raised while the command runs (a library's notes: torch on a file's pickle protocol,
    numpy on overflow in a value that is then refused) are held back: a command that fails prints
    its one error line and nothing else; one that succeeds, or meets a defect, shows them after
    its output, each once, as Python would have."""
    failed = False
    held: list[warnings.WarningMessage] = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            held = caught
            code = _run(argv)
        failed = code != 0
        return code
    finally:
        if not failed:  # shown once the recording has stopped
            _show_warnings(held)


def _show_warnings(held: list[warnings.WarningMessage]) -> None:
    seen: set[tuple] = set()
    for w in held:
        key = (str(w.message), w.category, w.filename, w.lineno)
        if key not in seen:
            seen.add(key)
            warnings.showwarning(w.message, w.category, w.filename, w.lineno, w.file, w.line)


def _run(argv: list[str] | None) -> int:
    _load_commands()
    from terra.cli.helptext import tidy_help
    from terra.cli.interrupts import Interrupted, catch_interrupts, clear, interrupted_message
    from terra.fileio import escaped_os_error

    clear()
    _NOTES.clear()
    global _COMMAND
    if _COMMAND is None:  # built once per process: building it costs ~0.3 s, a query's whole budget
        _COMMAND = catch_interrupts(tidy_help(typer.main.get_command(app)))
    command = _COMMAND
    try:
        result = command.main(args=argv, prog_name="terra", standalone_mode=False)
        for message in _NOTES:
            typer.echo(f"note: {message}", err=True)
        return result if isinstance(result, int) else 0
    except TerraError as exc:
        return _error_line(exc)
    except typer.Exit as exc:
        return exc.exit_code
    except typer.Abort:
        typer.echo("terra: aborted", err=True)
        return 130
    except (KeyboardInterrupt, Interrupted):
        typer.echo(interrupted_message(), err=True)
        return 130
    except OSError as exc:
        mapped = escaped_os_error(exc)  # a name too long, a full disk met outside Terra's writers
        if mapped is None:
            raise
        return _error_line(mapped)
    except Exception as exc:
        # Usage errors (unknown command or option, missing argument) from Typer's bundled click:
        # they know how to show themselves and carry their exit code.
        if isinstance(exc, _ShowsItself):
            return _usage_error(exc)
        raise


def _usage_error(exc: _ShowsItself) -> int:
    """A usage error as one line like any other refusal, naming the command's help; `terra` alone
    (no command: the help is the answer) shows itself."""
    describe = getattr(exc, "format_message", None)
    if type(exc).__name__ == "NoArgsIsHelpError" or not callable(describe):
        exc.show()
        return int(exc.exit_code)
    ctx = getattr(exc, "ctx", None)
    hint = f" (see {ctx.command_path} -h)" if ctx is not None else ""
    _close_bars()
    typer.echo(f"terra: error: {one_line(str(describe()))}{hint}", err=True)
    return int(exc.exit_code)


def _error_line(exc: TerraError) -> int:
    _close_bars()
    typer.echo(f"terra: error: {exc}", err=True)
    return exc.exit_code


def _close_bars() -> None:
    from terra.progress import close_bars

    close_bars()


def main(argv: list[str] | None = None) -> None:
    """Console entry point: exits with the code of `run`. An unexpected exception is a bug: its
    traceback is shown, with a line asking to report it, and the exit code is 1."""
    try:
        code = run(argv)
    except Exception:  # noqa: BLE001 - not a catch-all: the traceback is printed in full
        import traceback

        from terra import __version__

        _close_bars()
        traceback.print_exc()
        typer.echo(
            f"terra: internal error: this is a bug in terra {__version__}, not a problem with your input; "
            "please report it with the command line and the traceback above",
            err=True,
        )
        code = 1
    sys.exit(code)
