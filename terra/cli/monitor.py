"""`terra monitor`: which regions and places a monitoring task asks to watch."""

from __future__ import annotations

from pathlib import Path

import typer

from terra.cli import app


@app.command("monitor")
def monitor_command(
    bundle: Path = typer.Argument(..., help="Bundle folder with a scene graph (`terra build`)."),
    queries: list[str] | None = typer.Argument(
        None, help='Monitoring task text, e.g. "large parking lot surrounded by buildings".'
    ),
    method: str | None = typer.Option(
        None, "--method", "-m", help="mix (paper), max, thresh or aib (Clio baseline); default mix."
    ),
    k: int | None = typer.Option(
        None, "--k", "-k", help="Number of top regions for mix and max (default: the config's tasks.monitoring.k, 5)."
    ),
    alpha: float | None = typer.Option(
        None, "--alpha", "-a", help="Cosine threshold; default per embedder (tasks.monitoring.alpha)."
    ),
    tasks: Path | None = typer.Option(
        None, "--tasks", help="YAML task file (region_tasks, k, alpha, prediction_method)."
    ),
    config: Path | None = typer.Option(None, "--config", "-c", help="YAML config; its `tasks` section is used."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON (as POST /monitor answers)."),
) -> None:
    """Choose the regions and places to watch for a monitoring task.

    Choose the regions and places to monitor for each task in QUERIES.

    Example: terra monitor campus.terra "large parking lot surrounded by buildings" --k 2 --json
    """
    from terra.cli.task_options import load_tasks_config, monitor_request, open_bundle

    request = monitor_request(queries or [], method, k, alpha, tasks)
    cfg = load_tasks_config(config)
    loaded = open_bundle(bundle, cfg)
    loaded.prefetch(list(request.queries))  # the text model runs while the query modules import
    from terra.cli.render import render_json, render_monitor
    from terra.tasks.commands import monitor

    result = monitor(loaded, request, cfg)
    typer.echo(render_json(result) if as_json else render_monitor(result))
