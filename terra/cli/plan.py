"""`terra plan`: terrain-aware A* on the places layer to the object a task names."""

from __future__ import annotations

from pathlib import Path

import typer

from terra.cli import app

FROM_XY_HELP = "Start at the allowed place nearest X Y (metres, map frame)."
PREFER_HELP = "Preferred terrain (repeatable); others get the default penalty."
PENALTY_HELP = "TERRAIN=W: cost per metre x (1 + W) on that terrain (repeatable)."
ROBOT_HELP = (
    "wheelchair, wheeled, legged or a YAML profile file (max_step m, max_slope_up/down deg, min_width m, "
    "slope_cost, terrain_costs, forbidden_terrain): edges it cannot drive are removed, slopes cost extra."
)
TASKS_HELP = "YAML task file (terrain_preferences, queries: start/destination)."


@app.command("plan")
def plan_command(
    bundle: Path = typer.Argument(..., help="Bundle folder with a scene graph (`terra build`)."),
    to: str | None = typer.Option(None, "--to", help='Destination task, e.g. "get bike from the bicycle rack".'),
    to_node: int | None = typer.Option(None, "--to-node", help="Destination place id instead of a query."),
    from_query: str | None = typer.Option(None, "--from", help="Start at the object a query names."),
    from_node: int | None = typer.Option(None, "--from-node", help="Start place id."),
    from_xy: tuple[float, float] | None = typer.Option(None, "--from-xy", help=FROM_XY_HELP),
    prefer: list[str] | None = typer.Option(None, "--prefer", help=PREFER_HELP),
    penalty: list[str] | None = typer.Option(None, "--penalty", help=PENALTY_HELP),
    forbid: list[str] | None = typer.Option(None, "--forbid", help="Terrain never to enter (repeatable)."),
    robot: str | None = typer.Option(None, "--robot", help=ROBOT_HELP),
    method: str | None = typer.Option(None, "--method", "-m", help="Retrieval method for the queries (default 3dsg)."),
    alpha: float | None = typer.Option(None, "--alpha", "-a", help="Cosine threshold for the queries."),
    tasks: Path | None = typer.Option(None, "--tasks", help=TASKS_HELP),
    config: Path | None = typer.Option(None, "--config", "-c", help="YAML config; its `tasks` section is used."),
    as_json: bool = typer.Option(False, "--json", help="Print the plan as JSON (as POST /plan)."),
) -> None:
    """Plan a terrain-aware path to what a task names.

    Plan a path from a start to the place of the object a task names, honouring terrain
    preferences. Edge cost = the edge's length along the graph (the GVD path between its two
    places, never shorter than the straight segment) x (1 + mean penalty of its two places'
    terrains); forbidden terrain is removed. The plan reports the straight length between its
    waypoints and the length along the graph per terrain, so cost = sum of terrain length along
    the graph x (1 + its penalty). Without --from*, the start is the place nearest the first
    camera pose. With --robot, edges whose step or slope is beyond the robot are removed (the map
    must have ground geometry: any `terra build` of this version), and the plan reports its
    largest step and slope. Exit code 3 when no path exists.

    Example: terra plan campus.terra --to "get bike from the bicycle rack" --prefer sidewalk --forbid water --json
    Example: terra plan lidar.terra --from-xy 0 0 --to-node 42 --robot wheelchair
    """
    from terra.cli.task_options import load_tasks_config, open_bundle, plan_request

    request = plan_request(
        to,
        to_node,
        from_query,
        from_node,
        from_xy,
        prefer or [],
        penalty or [],
        forbid or [],
        method,
        alpha,
        tasks,
        robot,
    )
    cfg = load_tasks_config(config)
    loaded = open_bundle(bundle, cfg)
    loaded.prefetch([q for q in (request.to, request.from_query) if q])  # embeds while the query modules import
    from terra.cli.render import render_json, render_plan
    from terra.tasks.commands import plan

    result = plan(loaded, request, cfg)
    typer.echo(render_json(result) if as_json else render_plan(result))
