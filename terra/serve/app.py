"""`terra serve`: the task queries over HTTP for robots and tools, from one warm LoadedBundle.

Endpoints (JSON; bodies are terra.tasks.requests models, responses the same JSON as the CLI's
`--json`; the OpenAPI description is at /openapi.json and /docs):

    GET  /health                       bundle, embedder and sizes
    POST /find     FindRequest         = terra find --json
    POST /monitor  MonitorRequest      = terra monitor --json
    POST /plan     PlanRequest         = terra plan --json
    GET  /nodes/{node}                 = terra node BUNDLE NODE --json (p12, R3, O0, Z0, numeric id)
    GET  /regions/{level}/{index}      = terra node BUNDLE R3 --json for level 1, index 3
    GET  /locate?x=X&y=Y               = terra node BUNDLE --at X Y --json

With `terra serve --live` (create_live_app, terra.serve.live) the service maps as well:

    POST /frames   .npz body            fuse one frame (terra.live.wire; a write)
    POST /cameras  {"cameras": {...}}   calibrations of the cameras the frames name (a write)
    POST /snapshot                      commit what was fused as a version now (a write)
    GET  /live                          frames received, fused, refused by reason; the latest
                                        version and map time; seconds since the last frame
and every answer above adds "version" and "map_time" (s), those of the snapshot it was answered
on; 503 (kind "not_ready") before the first version; a refused frame is 400 (413 for a size)
with kind = the reason it is counted under.

Handlers follow the thin-CLI rule: parse, call the typed task API, serialise with to_json().
Queries only read the loaded bundle and run concurrently in the server's thread pool;
The service is read-only unless started with --allow-writes; then `"save": true` on /find is
serialised and atomic (LoadedBundle.update_graph), and, with a token, needs it like every request.

Errors are one line of JSON, {"error": "...", "kind": "..."}, never a stack trace: 400 bad input
(empty query, unknown terrain, malformed JSON), 401 missing or wrong bearer token, 403 a write
(`"save": true`) to a read-only service, 404 unknown
endpoint or node, 413 body or query count over the limits, 422 a body of the wrong shape
(kind "invalid") or a plan with no path (kind "no_path"), 500 an internal error (logged).
"""

from __future__ import annotations

import contextlib
import hmac
import json
import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, Annotated, Any

from fastapi import Body, FastAPI, Query
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import Request

from terra import __version__
from terra.errors import NoPathError, TerraError
from terra.loaded import LoadedBundle
from terra.serve.config import ServeConfig
from terra.tasks import commands
from terra.tasks.config import TasksConfig
from terra.tasks.lookup import UnknownNode, locate, node_info, region_info
from terra.tasks.requests import FindRequest, MonitorRequest, PlanRequest

if TYPE_CHECKING:  # the live side (and the mapper behind it) loads only for `terra serve --live`
    from terra.serve.live import LiveService

log = logging.getLogger("terra.serve")
FRAMES_PATH = "/frames"


class LimitExceeded(TerraError):
    """A request over the service's size limits (413)."""


def error_response(status: int, kind: str, message: str) -> JSONResponse:
    """The one-line JSON error every failure answers with."""
    return JSONResponse({"error": " ".join(str(message).split()), "kind": kind}, status_code=status)


class ReadOnly(TerraError):
    """A request that would change the bundle, to a service started without --allow-writes."""


def create_app(loaded: LoadedBundle, tasks: TasksConfig | None = None, settings: ServeConfig | None = None) -> FastAPI:
    """The service for `loaded` (loading happens lazily unless the caller warmed it)."""
    app = _new_app(settings)
    app.state.loaded = loaded
    _routes(app, lambda: (loaded, {}), tasks or TasksConfig(), app.state.settings)
    _guard(app, app.state.settings, None)
    return app


def create_live_app(
    service: LiveService, tasks: TasksConfig | None = None, settings: ServeConfig | None = None
) -> FastAPI:
    """The live service (`terra serve --live`): frames in (terra.live.wire), queries answered on the
    latest committed version, each answer naming it ("version", "map_time"). The update thread runs
    while the app does (its lifespan); stopping commits what was fused since the last version."""

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        service.start()
        try:
            yield
        finally:
            await run_in_threadpool(service.close)

    app = _new_app(settings, lifespan)
    app.state.live = service
    _live_errors(app)

    def current() -> tuple[LoadedBundle, dict]:
        snapshot = service.current()
        return snapshot.bundle, {"version": snapshot.version, "map_time": snapshot.map_time}

    _routes(app, current, tasks or TasksConfig(), app.state.settings, live=True)
    _live_routes(app, service, app.state.settings)
    _guard(app, app.state.settings, service.settings.max_frame_bytes)
    return app


def _live_errors(app: FastAPI) -> None:
    from terra.live.frames import LiveFrameError
    from terra.serve.live import NotReady

    @app.exception_handler(LiveFrameError)  # more specific than TerraError's handler: chosen first
    async def refused(request: Request, exc: LiveFrameError) -> JSONResponse:
        return error_response(413 if exc.reason == "too_large" else 400, exc.reason, str(exc))

    @app.exception_handler(NotReady)
    async def not_ready(request: Request, exc: NotReady) -> JSONResponse:
        return error_response(503, "not_ready", str(exc))


def _new_app(settings: ServeConfig | None, lifespan=None) -> FastAPI:
    app = FastAPI(
        title="Terra",
        version=__version__,
        summary="Task queries on a terrain-aware 3D scene graph",
        description=__doc__ or "",
        lifespan=lifespan,
    )
    app.state.settings = settings or ServeConfig()
    _errors(app)
    return app


def _guard(app: FastAPI, settings: ServeConfig, max_frame_bytes: int | None) -> None:
    limits = {FRAMES_PATH: max_frame_bytes} if max_frame_bytes is not None else {}
    app.add_middleware(Guard, token=settings.token, max_body_bytes=settings.max_body_bytes, raw_bodies=limits)


def _check_texts(texts: list[str | None], settings: ServeConfig) -> None:
    given = [t for t in texts if t is not None]
    if len(given) > settings.max_queries:
        raise LimitExceeded(f"at most {settings.max_queries} queries per request, got {len(given)}")
    for i, text in enumerate(given):
        if len(text) > settings.max_query_chars:
            raise LimitExceeded(f"query {i + 1} has {len(text)} characters; at most {settings.max_query_chars}")


Current = Callable[[], "tuple[LoadedBundle, dict]"]


def _routes(app: FastAPI, current: Current, tasks: TasksConfig, settings: ServeConfig, live: bool = False) -> None:
    """The query endpoints, each answered on the bundle `current()` gives when the request starts
    (with its extra fields: a live service's version and map time)."""

    def answer(make: Callable[[LoadedBundle], Any]) -> JSONResponse:
        loaded, extra = current()
        return JSONResponse({**make(loaded).to_json(), **extra})

    @app.get("/health", summary="Bundle, embedder and sizes (also a liveness check)")
    def health() -> JSONResponse:
        try:
            loaded, extra = current()
        except TerraError as exc:  # a live service before its first version
            if not live:
                raise
            return JSONResponse({"status": "waiting", "terra": __version__, "version": None, "note": str(exc)})
        return JSONResponse({**_health(loaded), **extra})

    @app.post("/find", summary="Objects for text queries (terra find --json)")
    def find(request: FindRequest) -> JSONResponse:
        _check_texts(list(request.queries), settings)
        if request.save and live:
            raise ReadOnly('a live service rebuilds its graph at every update: "save": true is not available')
        if request.save and not settings.allow_writes:
            raise ReadOnly('this service is read-only: "save": true needs `terra serve --allow-writes`')
        return answer(lambda loaded: commands.find(loaded, request, tasks))

    @app.post("/monitor", summary="Regions and places to monitor (terra monitor --json)")
    def monitor(request: MonitorRequest) -> JSONResponse:
        _check_texts(list(request.queries), settings)
        return answer(lambda loaded: commands.monitor(loaded, request, tasks))

    @app.post("/plan", summary="A terrain-aware path to the object a task names (terra plan --json)")
    def plan(request: PlanRequest) -> JSONResponse:
        _check_texts([request.to, request.from_query], settings)
        return answer(lambda loaded: commands.plan(loaded, request, tasks))

    @app.get("/nodes/{node}", summary="A place, region or object (terra node BUNDLE NODE --json)")
    def node(node: str) -> JSONResponse:
        return answer(lambda loaded: node_info(loaded.require_graph("node lookups"), node))

    @app.get("/regions/{level}/{index}", summary="Region `index` of `level` (1 = regions of places)")
    def region(level: int, index: int) -> JSONResponse:
        return answer(lambda loaded: region_info(loaded.require_graph("region lookups"), level, index))

    @app.get("/changes", summary="What changed between two sessions of the map (terra changes --between A B --json)")
    def changes(
        first: int = Query(1, description="the earlier session (1-based)"),
        second: int = Query(2, description="the later session"),
    ) -> JSONResponse:
        from terra.tasks.change_report import report_changes

        return answer(lambda loaded: report_changes(loaded.bundle.path, first, second))

    @app.get("/locate", summary="The place nearest (x, y) and its regions (terra node BUNDLE --at X Y --json)")
    def where(
        x: float = Query(..., description="metres, map frame"), y: float = Query(..., description="metres, map frame")
    ) -> JSONResponse:
        return answer(lambda loaded: locate(loaded.require_graph("locating points"), x, y))


def _health(loaded: LoadedBundle) -> dict:
    graph = loaded.graph
    map_info = loaded.bundle.model.components.map
    return {
        "status": "ok",
        "terra": __version__,
        "bundle": str(loaded.path),
        "embedder": loaded.embedder_name,
        "points": (map_info.points if map_info is not None else None) or 0,
        "places": len(graph.places) if graph is not None else 0,
        "regions": [len(level) for level in graph.regions] if graph is not None else [],
    }


def _live_routes(app: FastAPI, service: LiveService, settings: ServeConfig) -> None:
    """Frames in (writes: --allow-writes, and the token when one is set), status out."""

    def writable(what: str) -> None:
        if not settings.allow_writes:
            raise ReadOnly(f"this service is read-only: {what} needs `terra serve --live --allow-writes`")

    @app.post(FRAMES_PATH, summary="Fuse one frame: an uncompressed .npz body (terra.live.wire)")
    async def frames(request: Request) -> JSONResponse:
        writable("pushing frames")
        body = await request.body()
        fused = await run_in_threadpool(service.add, body)
        return JSONResponse({"fused": fused, "frames": service.session.frames})

    @app.post("/cameras", summary='Camera calibrations for the frames that follow: {"cameras": {"<c>": ...}}')
    def cameras(document: Annotated[dict[str, Any], Body()]) -> JSONResponse:
        writable("setting cameras")
        return JSONResponse({"cameras": service.set_cameras(document)})

    @app.post("/snapshot", summary="Commit the frames fused so far as a new version now")
    def snapshot() -> JSONResponse:
        writable("committing a version")
        service.update()
        latest = service.current()
        return JSONResponse(
            {
                "version": latest.version,
                "map_time": latest.map_time,
                "frames": latest.frames,
                "graph_note": latest.graph_note,
            }
        )

    @app.get("/live", summary="Frames received, fused and refused; the latest version; seconds since the last frame")
    def status() -> JSONResponse:
        return JSONResponse(service.status())


def _errors(app: FastAPI) -> None:
    @app.exception_handler(TerraError)
    async def terra_error(request: Request, exc: TerraError) -> JSONResponse:
        if isinstance(exc, ReadOnly):
            return error_response(403, "read_only", str(exc))
        if isinstance(exc, LimitExceeded):
            return error_response(413, "too_large", str(exc))
        if isinstance(exc, NoPathError):
            return error_response(422, "no_path", str(exc))
        if isinstance(exc, UnknownNode):
            return error_response(404, "not_found", str(exc))
        return error_response(400, "bad_request", str(exc))

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        err = exc.errors()[0] if exc.errors() else {"loc": (), "msg": "invalid request", "type": ""}
        where = ".".join(str(p) for p in err.get("loc", ()))
        if err.get("type") == "json_invalid":
            return error_response(
                400, "bad_request", f"malformed JSON body: {err.get('ctx', {}).get('error', err['msg'])}"
            )
        return error_response(422, "invalid", f"{where}: {err['msg']}")

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        if exc.status_code == 404:
            return error_response(404, "not_found", f"no endpoint {request.method} {request.url.path}; see /docs")
        if exc.status_code == 405:
            return error_response(405, "method_not_allowed", f"{request.method} is not allowed on {request.url.path}")
        return error_response(exc.status_code, "http", str(exc.detail))

    @app.exception_handler(Exception)
    async def internal(request: Request, exc: Exception) -> JSONResponse:
        log.error("internal error answering %s %s", request.method, request.url.path, exc_info=exc)
        return error_response(500, "internal", f"internal error ({type(exc).__name__}); see the server log")


class Guard:
    """ASGI middleware in front of every route: the bearer token (when set) and the body size
    limit, checked before a body is parsed or any work is done. `raw_bodies`: paths whose bodies
    are not JSON (POST /frames), with their own size limits."""

    def __init__(self, app: Callable, token: str | None, max_body_bytes: int, raw_bodies: dict | None = None):
        self.app = app
        self.token = token.encode() if token else None
        self.max_body_bytes = max_body_bytes
        self.raw_bodies: dict[str, int] = dict(raw_bodies or {})

    async def __call__(self, scope: dict, receive: Callable, send: Callable) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.lower(): v for k, v in scope.get("headers", [])}
        if self.token is not None:
            scheme, _, given = headers.get(b"authorization", b"").partition(b" ")
            if scheme.lower() != b"bearer" or not hmac.compare_digest(given.strip(), self.token):
                await _send(
                    send,
                    401,
                    "unauthorized",
                    "missing or wrong bearer token (Authorization: Bearer TOKEN)",
                    [(b"www-authenticate", b"Bearer")],
                )
                return
        raw = scope.get("path") in self.raw_bodies
        limit = self.raw_bodies[scope["path"]] if raw else self.max_body_bytes
        declared = headers.get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > limit:
            await _send(send, 413, "too_large", f"request body of {int(declared)} bytes; at most {limit}")
            return
        body = await _read_body(receive, limit)
        if body is None:  # the client went away
            return
        if len(body) > limit:
            await _send(send, 413, "too_large", f"request body over {limit} bytes")
            return
        if body and not raw and not headers.get(b"content-type", b"").startswith(b"application/json"):
            # Every body here is JSON: `curl -d '{...}'` (form content type) or a bare client
            # should get the JSON parsed, not a form error.
            scope = dict(
                scope,
                headers=[(k, v) for k, v in scope["headers"] if k.lower() != b"content-type"]
                + [(b"content-type", b"application/json")],
            )
        replayed = False

        async def replay() -> dict:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()

        await self.app(scope, replay, send)


async def _read_body(receive: Callable, limit: int) -> bytes | None:
    """The whole body, read now so a chunked upload cannot exceed `limit` bytes (reading stops at the
    first chunk past it); None when the client went away."""
    chunks, size, more = [], 0, True
    while more and size <= limit:
        message = await receive()
        if message["type"] == "http.disconnect":
            return None
        chunks.append(message.get("body", b""))
        size += len(chunks[-1])
        more = message.get("more_body", False)
    return b"".join(chunks)


async def _send(send: Callable, status: int, kind: str, message: str, extra: list | None = None) -> None:
    data = json.dumps({"error": message, "kind": kind}, separators=(",", ":")).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(data)).encode())] + (extra or [])
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": data})
