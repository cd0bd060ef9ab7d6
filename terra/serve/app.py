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

import hmac
import json
import logging
from collections.abc import Callable
from typing import Any

from fastapi import FastAPI, Query
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
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

log = logging.getLogger("terra.serve")


class LimitExceeded(TerraError):
    """A request over the service's size limits (413)."""


def error_response(status: int, kind: str, message: str) -> JSONResponse:
    """The one-line JSON error every failure answers with."""
    return JSONResponse({"error": " ".join(str(message).split()), "kind": kind}, status_code=status)


class ReadOnly(TerraError):
    """A request that would change the bundle, to a service started without --allow-writes."""


def create_app(loaded: LoadedBundle, tasks: TasksConfig | None = None, settings: ServeConfig | None = None) -> FastAPI:
    """The service for `loaded` (loading happens lazily unless the caller warmed it)."""
    tasks = tasks or TasksConfig()
    settings = settings or ServeConfig()
    app = FastAPI(
        title="Terra",
        version=__version__,
        summary="Task queries on a terrain-aware 3D scene graph",
        description=__doc__ or "",
    )
    app.state.loaded = loaded
    _errors(app)
    _routes(app, loaded, tasks, settings)
    app.add_middleware(Guard, token=settings.token, max_body_bytes=settings.max_body_bytes)
    return app


def _check_texts(texts: list[str | None], settings: ServeConfig) -> None:
    given = [t for t in texts if t is not None]
    if len(given) > settings.max_queries:
        raise LimitExceeded(f"at most {settings.max_queries} queries per request, got {len(given)}")
    for i, text in enumerate(given):
        if len(text) > settings.max_query_chars:
            raise LimitExceeded(f"query {i + 1} has {len(text)} characters; at most {settings.max_query_chars}")


def _routes(app: FastAPI, loaded: LoadedBundle, tasks: TasksConfig, settings: ServeConfig) -> None:
    def answer(result: Any) -> JSONResponse:
        return JSONResponse(result.to_json())

    @app.get("/health", summary="Bundle, embedder and sizes (also a liveness check)")
    def health() -> JSONResponse:
        graph = loaded.graph
        map_info = loaded.bundle.model.components.map
        return JSONResponse(
            {
                "status": "ok",
                "terra": __version__,
                "bundle": str(loaded.path),
                "embedder": loaded.embedder_name,
                "points": (map_info.points if map_info is not None else None) or 0,
                "places": len(graph.places) if graph is not None else 0,
                "regions": [len(level) for level in graph.regions] if graph is not None else [],
            }
        )

    @app.post("/find", summary="Objects for text queries (terra find --json)")
    def find(request: FindRequest) -> JSONResponse:
        _check_texts(list(request.queries), settings)
        if request.save and not settings.allow_writes:
            raise ReadOnly('this service is read-only: "save": true needs `terra serve --allow-writes`')
        return answer(commands.find(loaded, request, tasks))

    @app.post("/monitor", summary="Regions and places to monitor (terra monitor --json)")
    def monitor(request: MonitorRequest) -> JSONResponse:
        _check_texts(list(request.queries), settings)
        return answer(commands.monitor(loaded, request, tasks))

    @app.post("/plan", summary="A terrain-aware path to the object a task names (terra plan --json)")
    def plan(request: PlanRequest) -> JSONResponse:
        _check_texts([request.to, request.from_query], settings)
        return answer(commands.plan(loaded, request, tasks))

    @app.get("/nodes/{node}", summary="A place, region or object (terra node BUNDLE NODE --json)")
    def node(node: str) -> JSONResponse:
        return answer(node_info(loaded.require_graph("node lookups"), node))

    @app.get("/regions/{level}/{index}", summary="Region `index` of `level` (1 = regions of places)")
    def region(level: int, index: int) -> JSONResponse:
        return answer(region_info(loaded.require_graph("region lookups"), level, index))

    @app.get("/locate", summary="The place nearest (x, y) and its regions (terra node BUNDLE --at X Y --json)")
    def where(
        x: float = Query(..., description="metres, map frame"), y: float = Query(..., description="metres, map frame")
    ) -> JSONResponse:
        return answer(locate(loaded.require_graph("locating points"), x, y))


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
    limit, checked before a body is parsed or any work is done."""

    def __init__(self, app: Callable, token: str | None, max_body_bytes: int):
        self.app = app
        self.token = token.encode() if token else None
        self.max_body_bytes = max_body_bytes

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
        declared = headers.get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.max_body_bytes:
            await _send(send, 413, "too_large", f"request body of {int(declared)} bytes; at most {self.max_body_bytes}")
            return
        body, more = b"", True
        while more:  # read the whole (small) body now so a chunked upload cannot exceed the limit
            message = await receive()
            if message["type"] == "http.disconnect":
                return
            body += message.get("body", b"")
            more = message.get("more_body", False)
            if len(body) > self.max_body_bytes:
                await _send(send, 413, "too_large", f"request body over {self.max_body_bytes} bytes")
                return
        if body and not headers.get(b"content-type", b"").startswith(b"application/json"):
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


async def _send(send: Callable, status: int, kind: str, message: str, extra: list | None = None) -> None:
    data = json.dumps({"error": message, "kind": kind}, separators=(",", ":")).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(data)).encode())] + (extra or [])
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": data})
