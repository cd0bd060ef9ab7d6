"""`terra serve`: an HTTP service answering find, monitor, plan and node lookups from one warm
bundle (terra.serve.app)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from terra.cli import app
from terra.errors import TerraError

if TYPE_CHECKING:  # every cli module is imported for `terra --help`: the service loads on use
    from terra.datasets.base import ClassTable
    from terra.serve.config import LiveConfig, ServeConfig
    from terra.serve.live import LiveService
    from terra.tasks.config import TasksConfig

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
LiveOpt = Annotated[
    bool,
    typer.Option(
        "--live",
        help="Map live: take frames pushed to POST /frames (with --allow-writes) into BUNDLE (created, or "
        "continued from its kept fusion state) and answer on the latest version.",
    ),
]
ClassesOpt = Annotated[
    Path | None,
    typer.Option(
        "--classes", help="With --live, a new bundle: the class table (a dataset's classes.json, or its folder)."
    ),
]
UpdateEveryOpt = Annotated[float, typer.Option("--update-every", help="With --live: seconds between versions.")]
UpdateFramesOpt = Annotated[
    int | None, typer.Option("--update-frames", help="With --live: also commit after this many new frames.")
]
MaxFrameOpt = Annotated[
    int, typer.Option("--max-frame-bytes", help="With --live: largest POST /frames body in bytes (more: 413).")
]
NameOpt = Annotated[str, typer.Option("--name", help="With --live: the source name the map records.")]


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
    live: LiveOpt = False,
    classes: ClassesOpt = None,
    update_every: UpdateEveryOpt = 2.0,
    update_frames: UpdateFramesOpt = None,
    max_frame_bytes: MaxFrameOpt = 64 << 20,
    name: NameOpt = "live",
) -> None:
    """Answer find, monitor and plan queries over HTTP.

    Serve the bundle's task queries over HTTP: POST /find, /monitor, /plan with the JSON of
    `terra find/monitor/plan --json`, GET /nodes/NODE, /regions/LEVEL/INDEX, /locate?x=&y=,
    /health; OpenAPI at /docs. The map, scene graph and text model are loaded once, before it
    listens. Read-only unless --allow-writes (then `"save": true` on /find stores the objects in
    the bundle). Needs the `serve` extra (pip install "terra-3dsg[serve]").

    With --live the service maps: frames pushed to POST /frames (an uncompressed .npz, see the
    README's "Live mapping over HTTP") are fused into BUNDLE, a version is committed every
    --update-every seconds, and every answer names the version and map time it was answered on;
    GET /live reports frames received, fused and refused and the seconds since the last frame.

    Example: terra serve campus.terra --port 8765 --token "$TERRA_SERVE_TOKEN"
    Example: terra serve drive.terra --live --classes sim/classes.json --allow-writes
    """
    from terra.cli.interrupts import on_interrupt
    from terra.cli.task_options import build, load_tasks_config
    from terra.serve.config import LiveConfig, ServeConfig

    _service_modules()  # one line naming the extra before anything is loaded
    values = {"host": host, "port": port, "token": token or None, "max_queries": max_queries}
    settings = build(
        ServeConfig, "command line", {**values, "max_body_bytes": max_body_bytes, "allow_writes": allow_writes}
    )
    cfg = load_tasks_config(config)
    if live:
        live_values = {"update_every": update_every, "update_frames": update_frames, "max_frame_bytes": max_frame_bytes}
        service = open_live_service(bundle, classes, config, name, build(LiveConfig, "command line", live_values))
        service_app = _live_app(service)
        stopped = f"the service on port {settings.port} stopped; {bundle} keeps its last committed version"
    else:
        if classes is not None or update_frames is not None:
            raise TerraError("--classes and --update-frames are for --live")
        service_app = _static_app(bundle, cfg)
        stopped = f"the service on port {settings.port} stopped; {bundle} is unchanged"
    _announce(bundle, settings)
    on_interrupt(stopped)
    _run_server(service_app(cfg, settings), settings, access_log)


def _run_server(service, settings: ServeConfig, access_log: bool) -> None:
    uvicorn, _ = _service_modules()
    config = uvicorn.Config(
        service, host=settings.host, port=settings.port, log_level="warning", access_log=access_log, server_header=False
    )
    # uvicorn.Server, not uvicorn.run: run() swallows the KeyboardInterrupt that the server re-raises
    # after a graceful shutdown on Ctrl-C, which made `terra serve` exit 0 without a word.
    uvicorn.Server(config).run()


def _service_modules():
    """uvicorn and the app factory, or TerraError naming the extra to install."""
    try:
        import uvicorn

        from terra.serve.app import create_app
    except ImportError as exc:
        raise TerraError(f'terra serve needs FastAPI and uvicorn: pip install "terra-3dsg[serve]" ({exc})') from None
    return uvicorn, create_app


def _static_app(bundle: Path, cfg: TasksConfig):
    """The app factory of a bundle served as it is, loaded and warmed now."""
    from terra.cli.task_options import open_bundle
    from terra.serve.app import create_app
    from terra.tasks.commands import warm

    loaded = open_bundle(bundle, cfg)
    loaded.require_graph("terra serve")
    warm(loaded)
    return lambda tasks, settings: create_app(loaded, tasks, settings)


def _live_app(service: LiveService):
    from terra.serve.app import create_live_app

    return lambda tasks, settings: create_live_app(service, tasks, settings)


def open_live_service(
    bundle: Path, classes: Path | None, config: Path | None, name: str = "live", live: LiveConfig | None = None
) -> LiveService:
    """The live service of `terra serve BUNDLE --live`: a new session (classes from --classes) or the
    bundle's map continued (its classes and mapping configuration, unless --config gives one)."""
    from terra.config import TerraConfig
    from terra.live.session import Session
    from terra.serve.live import LiveService

    resume = bundle.is_dir() and any(bundle.iterdir())
    table = _live_classes(bundle, classes, resume)
    if resume and config is None:
        from terra.cli.map import _recorded_mapping

        mapping = _recorded_mapping(bundle, {})
    else:
        mapping = TerraConfig.read(config).mapping
    return LiveService(Session(bundle, table, mapping, resume=resume, name=name), live)


def _live_classes(bundle: Path, classes: Path | None, resume: bool) -> ClassTable:
    """The class table of a live session: the bundle's when it continues one (a --classes file must
    then agree), else the --classes file."""
    from terra.datasets.folder_io import CLASSES_FILE, read_classes

    given = None
    if classes is not None:
        if classes.name != CLASSES_FILE and not classes.is_dir():
            raise TerraError(f"{classes}: --classes takes a {CLASSES_FILE} file or the dataset folder holding one")
        folder = classes if classes.is_dir() else classes.parent
        given = read_classes(folder)
        if given is None:
            raise TerraError(f"{folder / CLASSES_FILE}: no such file (the class table of a terra-folder dataset)")
    if not resume:
        if given is None:
            raise TerraError(f"{bundle}: a new live map needs its class table: --classes FILE (a classes.json)")
        return given
    recorded = _bundle_classes(bundle)
    if given is not None and given.to_json() != recorded.to_json():
        raise TerraError(f"{classes}: the classes differ from those {bundle} was mapped with; leave --classes out")
    return recorded


def _bundle_classes(bundle: Path) -> ClassTable:
    from terra.bundle import Bundle
    from terra.datasets.base import ClassTable
    from terra.mapping.state import append_base
    from terra.schemas import MapMeta

    base: Bundle = append_base(bundle)
    rows = base.document("map/meta.json", MapMeta).classes
    if not rows:
        raise TerraError(f"{bundle}/map/meta.json: field 'classes' is empty; give the class table with --classes")
    return ClassTable.from_json([row.model_dump() for row in rows])


def _announce(bundle: Path, settings: ServeConfig) -> None:
    """Where it listens (on stderr), with a warning when it is open to the network without a token."""
    host, port = settings.host, settings.port
    if settings.token is None and host not in ("127.0.0.1", "localhost", "::1"):
        typer.echo(
            f"terra serve: warning: listening on {host} without a token; anyone on the network may query", err=True
        )
    typer.echo(f"terra serve: {bundle} on http://{host}:{port} (OpenAPI at /docs; Ctrl-C stops)", err=True)
