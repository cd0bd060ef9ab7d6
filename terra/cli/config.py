"""`terra config dump STAGE`: print a stage's default configuration as YAML."""

from __future__ import annotations

import typer

from terra.cli import app

config_app = typer.Typer(
    help="Inspect configuration.\n\nExample: terra config dump mapping > mapping.yaml", no_args_is_help=True
)
app.add_typer(config_app, name="config")


@config_app.command("dump")
def dump(stage: str = typer.Argument(..., help="Stage: sim, mapping, build, tasks or eval.")) -> None:
    """Print the defaults of STAGE as YAML (edit and pass with --config).

    Example: terra config dump build > build.yaml
    """
    from terra.config import dump_section, stage_names

    if stage not in stage_names():
        from terra.errors import TerraError

        raise TerraError(f"unknown stage {stage!r}; expected one of: {', '.join(stage_names())}")
    typer.echo(dump_section(stage), nl=False)
