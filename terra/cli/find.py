"""`terra find`: open-vocabulary object retrieval on a bundle (Terra-MS or Terra-3DSG)."""

from __future__ import annotations

from pathlib import Path

import typer

from terra.cli import app


@app.command("find")
def find_command(
    bundle: Path = typer.Argument(
        ..., help="Bundle folder written by `terra map` (and `terra build` for 3dsg/--save)."
    ),
    queries: list[str] | None = typer.Argument(
        None, help='Text queries, e.g. "find the dumpster"; several share one load.'
    ),
    method: str | None = typer.Option(
        None, "--method", "-m", help="ms-avg, ms-max or 3dsg (default from the config: ms-avg)."
    ),
    alpha: float | None = typer.Option(
        None, "--alpha", "-a", help="Cosine threshold; default per embedder (tasks.retrieval.alpha)."
    ),
    tasks: Path | None = typer.Option(None, "--tasks", help="YAML task file (object_tasks, alpha, prediction_method)."),
    save: bool = typer.Option(
        False, "--save", help="Add the objects to the bundle's scene graph (same-label objects are replaced)."
    ),
    config: Path | None = typer.Option(None, "--config", "-c", help="YAML config; its `tasks` section is used."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON (as POST /find answers)."),
) -> None:
    """Find the objects that text queries name.

    Find objects matching text QUERIES: oriented boxes with scores and their nearest place.

    Example: terra find campus.terra "find the dumpster" "get bike from the bicycle rack" --method 3dsg --json
    """
    from terra.cli.task_options import find_request, load_tasks_config, open_bundle

    request = find_request(queries or [], method, alpha, save, tasks)
    cfg = load_tasks_config(config)
    loaded = open_bundle(bundle, cfg)
    loaded.prefetch(list(request.queries))  # the text model runs while the query modules import
    from terra.cli.render import render_find, render_json
    from terra.tasks.commands import find

    result = find(loaded, request, cfg)
    typer.echo(render_json(result) if as_json else render_find(result))
