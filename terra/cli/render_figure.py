"""`terra render`: one top-down figure of a bundle as a PNG."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from terra.cli import app


@app.command("render")
def render_command(
    bundle: Path = typer.Argument(..., help="Bundle folder (`terra map`; `terra build` for all but terrain)."),
    what: str = typer.Option(..., "--what", "-w", help="terrain | places | regions | objects | path."),
    out: Path = typer.Option(..., "--out", "-o", help="PNG file to write; an existing one is kept unless --overwrite."),
    dpi: int = typer.Option(120, "--dpi", help="Resolution of the PNG."),
    query: list[str] | None = typer.Option(
        None, "--query", "-q", help="objects: find these objects and draw them (repeatable)."
    ),
    to: str | None = typer.Option(None, "--to", help="path: destination query, as in `terra plan`."),
    to_node: int | None = typer.Option(None, "--to-node", help="path: destination place id."),
    from_query: str | None = typer.Option(None, "--from", help="path: start at the object a query names."),
    from_node: int | None = typer.Option(None, "--from-node", help="path: start place id."),
    from_xy: tuple[float, float] | None = typer.Option(
        None, "--from-xy", help="path: start nearest X Y (metres, map frame)."
    ),
    prefer: list[str] | None = typer.Option(None, "--prefer", help="path: preferred terrain (repeatable)."),
    penalty: list[str] | None = typer.Option(None, "--penalty", help="path: TERRAIN=W cost factor (repeatable)."),
    forbid: list[str] | None = typer.Option(None, "--forbid", help="path: terrain never to enter (repeatable)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing PNG at --out."),
    as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
) -> None:
    """Draw one top-down figure of a bundle as a PNG.

    Draw one top-down figure of BUNDLE (the ones `terra eval` puts in its report): map terrain,
    the places layer, the region levels, the objects, or a terrain-aware path.

    Example: terra render campus.terra --what path --to "get bike from the bicycle rack" --out path.png
    """
    from terra.cli.interrupts import on_interrupt
    from terra.cli.outputs import refuse_existing
    from terra.cli.task_options import open_bundle, plan_request
    from terra.tasks.config import TasksConfig
    from terra.viz.render import render_bundle

    refuse_existing(out, overwrite)
    on_interrupt(f"nothing was written ({out} is unchanged); run the same command again")

    plan = None
    if what == "path":
        plan = plan_request(to, to_node, from_query, from_node, from_xy, prefer or [], penalty or [], forbid or [])
    summary = render_bundle(open_bundle(bundle, TasksConfig()), what, out, dpi, query or [], plan)
    if as_json:
        typer.echo(json.dumps(summary, indent=1, sort_keys=True))
    else:
        typer.echo(f"{what} -> {out}")
