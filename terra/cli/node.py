"""`terra node`: what a scene-graph node is (place, region, object), or where a map point falls."""

from __future__ import annotations

from pathlib import Path

import typer

from terra.cli import app


# "-1" is a node to look up (and refused as one), not an unknown option
@app.command("node", context_settings={"ignore_unknown_options": True})
def node_command(
    bundle: Path = typer.Argument(..., help="Bundle folder with a scene graph (`terra build`)."),
    node: str | None = typer.Argument(
        None,
        help="Node: p12 (place), R3 (region of level 1; S, T, ... above), O0 (object), "
        "Z0 (root) or a numeric spark_dsg id.",
    ),
    at: tuple[float, float] | None = typer.Option(
        None, "--at", help="Instead of NODE: the place nearest X Y (metres, map frame) and its regions."
    ),
    as_json: bool = typer.Option(
        False, "--json", help="Print JSON (the body of GET /nodes/NODE or GET /locate?x=X&y=Y)."
    ),
) -> None:
    """Look up a place, region or object of the scene graph.

    Look up a scene-graph node: a place's terrain, neighbours, regions and objects; a region's
    level, parent, children and places; an object's box. With --at, the place nearest a point.

    Example: terra node campus.terra p12 --json
    """
    from terra.cli.render import render_json, render_location, render_node
    from terra.errors import TerraError
    from terra.loaded import LoadedBundle
    from terra.tasks.lookup import locate, node_info

    if (node is None) == (at is None):
        raise TerraError("give one of NODE (e.g. p12) and --at X Y")
    graph = LoadedBundle(bundle).require_graph("terra node")
    if node is not None:
        info = node_info(graph, node)
        typer.echo(render_json(info) if as_json else render_node(info))
    elif at is not None:
        location = locate(graph, *at)
        typer.echo(render_json(location) if as_json else render_location(location))
