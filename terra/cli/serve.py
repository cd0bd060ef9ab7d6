"""`terra serve`: an HTTP service answering find, monitor, plan and node lookups from one warm
bundle (terra.serve.app)."""

from __future__ import annotations

from pathlib import Path

import typer

from terra.cli import app


@app.command("serve")
def serve_command(
    bundle: Path = typer.Argument(..., help="Bundle folder with a map and a scene graph."),
    host: str = typer.Option(
        "127.0.0.1", "--host", help="Address to bind (loopback by default; 0.0.0.0 opens it to the network)."
    ),
    port: int = typer.Option(8765, "--port", "-p", help="TCP port."),
    token: str | None = typer.Option(
        None,
        "--token",
        envvar="TERRA_SERVE_TOKEN",
        show_envvar=True,
        help="Bearer token required on every request (at least 8 characters).",
    ),
    max_queries: int = typer.Option(32, "--max-queries", help="Most text queries per request (more: 413)."),
    max_body_bytes: int = typer.Option(65536, "--max-body-bytes", help="Largest request body in bytes (more: 413)."),
    config: Path | None = typer.Option(None, "--config", "-c", help="YAML config; its `tasks` section is used."),
    access_log: bool = typer.Option(False, "--access-log", help="Log every request on stderr."),
) -> None:
    """Answer find, monitor and plan queries over HTTP.

    Serve the bundle's task queries over HTTP: POST /find, /monitor, /plan with the JSON of
    `terra find/monitor/plan --json`, GET /nodes/NODE, /regions/LEVEL/INDEX, /locate?x=&y=,
    /health; OpenAPI at /docs. The map, scene graph and text model are loaded once, before it
    listens. Needs the `serve` extra (pip install "terra-3dsg[serve]").

    Example: terra serve campus.terra --port 8765 --token "$TERRA_SERVE_TOKEN"
    """
    from terra.cli.task_options import build, load_tasks_config, open_bundle
    from terra.errors import TerraError
    from terra.serve.config import ServeConfig
    from terra.tasks.commands import warm

    try:
        import uvicorn

        from terra.serve.app import create_app
    except ImportError as exc:
        raise TerraError(f'terra serve needs FastAPI and uvicorn: pip install "terra-3dsg[serve]" ({exc})') from None
    settings = build(
        ServeConfig,
        "command line",
        {
            "host": host,
            "port": port,
            "token": token or None,
            "max_queries": max_queries,
            "max_body_bytes": max_body_bytes,
        },
    )
    cfg = load_tasks_config(config)
    loaded = open_bundle(bundle, cfg)
    loaded.require_graph("terra serve")
    warm(loaded)
    if settings.token is None and host not in ("127.0.0.1", "localhost", "::1"):
        typer.echo(
            f"terra serve: warning: listening on {host} without a token; anyone on the network may query", err=True
        )
    typer.echo(f"terra serve: {loaded.path} on http://{host}:{port} (OpenAPI at /docs; Ctrl-C stops)", err=True)
    uvicorn.run(
        create_app(loaded, cfg, settings),
        host=settings.host,
        port=settings.port,
        log_level="warning",
        access_log=access_log,
        server_header=False,
    )
