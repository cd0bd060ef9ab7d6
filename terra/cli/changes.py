"""`terra changes`: what changed between two sessions of a joined map (terra/mapping/changes.py)."""

from __future__ import annotations

from pathlib import Path

import typer

from terra.cli import app


@app.command("changes")
def changes_command(
    bundle: Path = typer.Argument(..., help="Bundle folder holding a map of two or more sessions."),
    between: tuple[int, int] = typer.Option(
        (1, 2), "--between", help="The two sessions to compare (numbers as `terra info` lists them)."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print the changes as JSON."),
    figure: Path | None = typer.Option(
        None, "--figure", help="Also draw the changes over the map from above into this PNG file."
    ),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing PNG at --figure."),
) -> None:
    """What changed between two sessions of a map.

    Objects added, removed and moved (with the distance) and terrain that changed class (area per
    pair of classes), from the first session given to the second, judged only where both sessions
    observed: what the second session did not see has not changed.

    Each object is named by its class where the map can name it, and with a scene graph in the
    bundle (`terra build`) the changes are also summed per region.

    Example: terra changes campus.terra --between 1 2 --json --figure changes.png
    """
    from terra.bundle import Bundle
    from terra.cli.render import render_changes, render_stage_json
    from terra.tasks.change_report import report_changes

    Bundle(bundle)  # one line for a folder that is not a bundle
    if figure is not None:
        from terra.cli.outputs import refuse_existing
        from terra.viz.changes import check_figure_path

        check_figure_path(figure)
        refuse_existing(figure, overwrite)
    result = report_changes(bundle, between[0], between[1])
    if figure is not None:
        from terra.viz.changes import changes_figure

        changes_figure(result, figure)
    typer.echo(render_stage_json(result) if as_json else render_changes(result))
