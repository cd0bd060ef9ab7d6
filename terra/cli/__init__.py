"""The `terra` command line: one Typer app; each module in this package adds its commands.

Every user error (TerraError) becomes one line on stderr and its exit code (2, or 3 for an
unreachable plan goal); never a traceback for bad input.
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


def main(argv: list[str] | None = None) -> None:
    """Console entry point."""
    _load_commands()
    try:
        app(args=argv, standalone_mode=False)
    except TerraError as exc:
        typer.echo(f"terra: error: {exc}", err=True)
        sys.exit(exc.exit_code)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.Abort:
        typer.echo("terra: aborted", err=True)
        sys.exit(130)
    except KeyboardInterrupt:
        typer.echo("terra: interrupted", err=True)
        sys.exit(130)
    except Exception as exc:  # click usage errors
        import click

        if isinstance(exc, click.exceptions.ClickException):
            exc.show()
            sys.exit(2)
        raise
