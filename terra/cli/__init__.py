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
    rich_markup_mode=None,  # plain help text (terra.cli.helptext)
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _version(value: bool) -> None:
    if value:
        from terra import __version__

        typer.echo(f"terra {__version__}")
        raise typer.Exit(0)


@app.callback()
def _options(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                 help="Print the version and exit."),
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


def run(argv: list[str] | None = None) -> int:
    """Run the CLI in-process and return its exit code (0 success, 2 user error, 3 no path)."""
    _load_commands()
    from terra.cli.helptext import tidy_help
    from terra.cli.interrupts import Interrupted, catch_interrupts, clear, interrupted_message

    clear()
    command = catch_interrupts(tidy_help(typer.main.get_command(app)))
    try:
        result = command.main(args=argv, prog_name="terra", standalone_mode=False)
        return result if isinstance(result, int) else 0
    except TerraError as exc:
        typer.echo(f"terra: error: {exc}", err=True)
        return exc.exit_code
    except typer.Exit as exc:
        return exc.exit_code
    except typer.Abort:
        typer.echo("terra: aborted", err=True)
        return 130
    except (KeyboardInterrupt, Interrupted):
        typer.echo(interrupted_message(), err=True)
        return 130
    except Exception as exc:
        # Usage errors (unknown command or option, missing argument) from Typer's bundled click:
        # they know how to show themselves and carry their exit code.
        if hasattr(exc, "show") and hasattr(exc, "exit_code"):
            exc.show()
            return int(exc.exit_code)
        raise


def main(argv: list[str] | None = None) -> None:
    """Console entry point: exits with the code of `run`."""
    sys.exit(run(argv))
