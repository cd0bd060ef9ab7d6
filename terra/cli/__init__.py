"""The `terra` command line: one Typer app; each module in this package adds its commands.

Every user error (TerraError) becomes one line on stderr and its exit code (2, or 3 for an
unreachable plan goal); never a traceback for bad input. Any other exception is a defect in Terra:
`main` shows its traceback and asks for a report (exit code 1); `run` lets it propagate.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

import typer

from terra.errors import TerraError

app = typer.Typer(
    name="terra",
    help="Terra: terrain-aware 3D scene graphs for outdoor robots.\n\nExample: terra demo --out terra-demo",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _load_commands() -> None:
    for module in sorted(m.name for m in pkgutil.iter_modules(__path__)):
        importlib.import_module(f"{__name__}.{module}")


def fail(message: str, code: int = 2) -> None:
    """Print one error line and exit with `code`."""
    typer.echo(f"terra: error: {message}", err=True)
    raise typer.Exit(code)


def run(argv: list[str] | None = None) -> int:
    """Run the CLI in-process and return its exit code (0 success, 2 user error, 3 no path)."""
    _load_commands()
    try:
        result = app(args=argv, standalone_mode=False)
        return result if isinstance(result, int) else 0
    except TerraError as exc:
        _close_bars()
        typer.echo(f"terra: error: {exc}", err=True)
        return exc.exit_code
    except typer.Exit as exc:
        return exc.exit_code
    except typer.Abort:
        typer.echo("terra: aborted", err=True)
        return 130
    except KeyboardInterrupt:
        typer.echo("terra: interrupted", err=True)
        return 130
    except Exception as exc:
        # Usage errors (unknown command or option, missing argument) from Typer's bundled click:
        # they know how to show themselves and carry their exit code.
        if hasattr(exc, "show") and hasattr(exc, "exit_code"):
            exc.show()
            return int(exc.exit_code)
        raise


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
        typer.echo(f"terra: internal error: this is a bug in terra {__version__}, not a problem with your input; "
                   "please report it with the command line and the traceback above", err=True)
        code = 1
    sys.exit(code)
