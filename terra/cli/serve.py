"""`terra serve`: an HTTP service answering find, monitor, plan and node lookups from one warm
bundle (terra.serve.app)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from terra.cli import app

if TYPE_CHECKING:  # every cli module is imported for `terra --help`: the service loads on use
    from terra.loaded import LoadedBundle
    from terra.serve.config import ServeConfig

BundleArg = Annotated[Path, typer.Argument(help="Bundle folder with a map and a scene graph.")]
HostOpt = Annotated[
    str, typer.Option("--host", help="Address to bind (loopback by default; 0.0.0.0 opens it to the network).")
]
PortOpt = Annotated[int, typer.Option("--port", "-p", help="TCP port.")]
TokenOpt = Annotated[
    str | None,
    typer.Option(
        "--token",
        envvar="TERRA_SERVE_TOKEN",
        show_envvar=True,
        help="Bearer token required on every request (at least 8 characters).",
    ),
]
MaxQueriesOpt = Annotated[int, typer.Option("--max-queries", help="Most text queries per request (more: 413).")]
MaxBodyOpt = Annotated[int, typer.Option("--max-body-bytes", help="Largest request body in bytes (more: 413).")]
ConfigOpt = Annotated[Path | None, typer.Option("--config", "-c", help="YAML config; its `tasks` section is used.")]
AllowWritesOpt = Annotated[
    bool,
    typer.Option(
        "--allow-writes",
        help='Let requests change the bundle (POST /find with "save": true); else read-only (403).',
    ),
]
AccessLogOpt = Annotated[bool, typer.Option("--access-log", help="Log every request on stderr.")]


@app.command("serve")
def serve_command(
    bundle: BundleArg,
    host: HostOpt = "127.0.0.1",
    port: PortOpt = 8765,
    token: TokenOpt = None,
    max_queries: MaxQueriesOpt = 32,
    max_body_bytes: MaxBodyOpt = 65536,
    config: ConfigOpt = None,
    access_log: AccessLogOpt = False,
    allow_writes: AllowWritesOpt = False,
) -> None:
    """Answer find, monitor and plan queries over HTTP.

    Serve the bundle's task queries over HTTP: POST /find, /monitor, /plan with the JSON of
    `terra find/monitor/plan --json`, GET /nodes/NODE, /regions/LEVEL/INDEX, /locate?x=&y=,
    /health; OpenAPI at /docs. The map, scene graph and text model are loaded once, before it
    listens. Read-only unless --allow-writes (then `"save": true` on /find stores the objects in
    the bundle). Needs the `serve` extra (pip install "terra-3dsg[serve]").

    Example: terra serve campus.terra --port 8765 --token "$TERRA_SERVE_TOKEN"
    """
    from terra.cli.interrupts import on_interrupt
    from terra.cli.task_options import build, load_tasks_config, open_bundle
    from terra.serve.config import ServeConfig
    from terra.tasks.commands import warm

    uvicorn, create_app = _service_modules()
    values = {"host": host, "port": port, "token": token or None, "max_queries": max_queries}
    settings = build(
        ServeConfig, "command line", {**values, "max_body_bytes": max_body_bytes, "allow_writes": allow_writes}
    )
    cfg = load_tasks_config(config)
    loaded = open_bundle(bundle, cfg)
    loaded.require_graph("terra serve")
    warm(loaded)
    _announce(loaded, settings)
    on_interrupt(f"the service on port {settings.port} stopped; {loaded.path} is unchanged")
    config = uvicorn.Config(
        create_app(loaded, cfg, settings),
        host=settings.host,
        port=settings.port,
        log_level="warning",
        access_log=access_log,
        server_header=False,
    )
    # uvicorn.Server, not uvicorn.run: run() swallows the KeyboardInterrupt that the server re-raises
    # after a graceful shutdown on Ctrl-C, which made `terra serve` exit 0 without a word.
    uvicorn.Server(config).run()


def _service_modules():
    """uvicorn and the app factory, or TerraError naming the extra to install."""
    from terra.errors import TerraError

    try:
        import uvicorn

        from terra.serve.app import create_app
    except ImportError as exc:
        raise TerraError(f'terra serve needs FastAPI and uvicorn: pip install "terra-3dsg[serve]" ({exc})') from None
    return uvicorn, create_app


def _announce(loaded: LoadedBundle, settings: ServeConfig) -> None:
    """Where it listens (on stderr), with a warning when it is open to the network without a token."""
    host, port = settings.host, settings.port
    if settings.token is None and host not in ("127.0.0.1", "localhost", "::1"):
        typer.echo(
            f"terra serve: warning: listening on {host} without a token; anyone on the network may query", err=True
        )
    typer.echo(f"terra serve: {loaded.path} on http://{host}:{port} (OpenAPI at /docs; Ctrl-C stops)", err=True)
