"""`terra view`: the map and scene graph in the browser, with find, monitor and plan."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from terra.cli import app


@app.command("view")
def view_command(
    bundle: Path = typer.Argument(
        ..., help="Bundle folder (`terra map`; `terra build` for the graph layers and planning)."
    ),
    port: int = typer.Option(8080, "--port", "-p", help="Port to listen on."),
    host: str = typer.Option(
        "127.0.0.1", "--host", help="Address to listen on (loopback by default; 0.0.0.0 shares the map on the network)."
    ),
    max_points: int = typer.Option(
        200_000, "--max-points", help="Points drawn at most (a fixed subset; queries use every point)."
    ),
    config: Path | None = typer.Option(
        None, "--config", "-c", help="YAML config; its `tasks` section is used for the queries."
    ),
    live: bool = typer.Option(
        False,
        "--live",
        help="Follow a map that grows (terra serve --live, terra map --follow, a terra.live.Session): draw "
        "each new version in the open page.",
    ),
    poll: float = typer.Option(1.0, "--poll", min=0.1, max=60.0, help="With --live: seconds between checks."),
) -> None:
    """Open a bundle in the web viewer.

    Open BUNDLE in a web viewer: points coloured by terrain, MS-Max class or similarity to a
    text; places, each region level and the objects as layers; find and monitor queries that
    highlight their answers; terrain-aware plans between typed or picked places. Ctrl-C stops it.

    Example: terra view campus.terra --port 8080   (then open http://127.0.0.1:8080)
    """
    from terra.cli.task_options import load_tasks_config, open_bundle
    from terra.errors import TerraError
    from terra.viewer.app import TerraViewer

    if max_points < 1000:
        raise TerraError(f"--max-points must be at least 1000, got {max_points}")
    cfg = load_tasks_config(config)
    viewer = TerraViewer(open_bundle(bundle, cfg), host=host, port=port, max_points=max_points, config=cfg)
    typer.echo(f"terra view: {bundle} at {viewer.url} (Ctrl-C to stop)")
    from terra.cli.interrupts import on_interrupt

    on_interrupt("the viewer stopped; nothing was written")
    if host not in ("127.0.0.1", "localhost", "::1"):
        typer.echo(f"note: listening on {host}: anyone who can reach this machine can see the map", err=True)
    try:
        if not live:
            viewer.server.sleep_forever()
        while live:
            time.sleep(poll)
            if _refreshed(viewer):
                typer.echo(f"terra view: version {viewer.version} drawn ({len(viewer.msm):,} points)")
    finally:
        viewer.stop()


def _refreshed(viewer) -> bool:
    """viewer.refresh(), a version replaced while it was being read being tried again at the next poll."""
    from terra.errors import TerraError

    try:
        return viewer.refresh()
    except TerraError:
        return False
