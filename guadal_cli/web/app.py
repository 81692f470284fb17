"""The console's HTTP side: pages, a JSON API, live streams (server-sent events), controls.

Starlette rather than a larger framework: the console is a dozen routes, its input is two
small JSON bodies validated by hand (so every refusal is one sentence), and server-sent events
are a plain streaming response. Uvicorn serves it.

Routes::

    GET  /                          the mission list            GET /runs/{id}        a mission page
    GET  /login, POST /login        the login form              POST /logout
    GET  /api/me                    who is logged in, whether controls are on
    GET  /api/runs?map=&algorithm=&level=&status=               runs, newest first
    GET  /api/runs/stream           SSE: the list, resent when a run is added or changes
    GET  /api/runs/{id}             a run, its mission, its map's nodes
    GET  /api/runs/{id}/stream      SSE: the run's rows, from the start or the Last-Event-ID
    GET  /api/runs/{id}/download/{kind}   csv (zip), geojson, kml, plan (zip)
    POST /api/runs/{id}/control     {"action": pause|resume|abort|hold|release, "vehicle": n}
"""

from __future__ import annotations

import asyncio
import json
import logging
from importlib import resources
from urllib.parse import parse_qs, quote

import anyio
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, RedirectResponse, Response, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from ..db.controls import ControlRefused, request_control
from ..errors import GuadalError
from .reader import ConsoleReader, Cursor
from .security import SESSION_COOKIE, Access

log = logging.getLogger("guadal.serve")
STATIC = resources.files("guadal_cli.web") / "static"
#: how often a live stream looks for new rows: well under the one second a step may take to show
POLL_S = 0.2
#: a comment line this often keeps proxies and the browser from dropping an idle stream
KEEPALIVE_S = 15.0


def _error(status: int, sentence: str) -> JSONResponse:
    return JSONResponse({"error": sentence}, status_code=status)


def _sse(event: str, data, event_id: str | None = None) -> bytes:
    head = f"id: {event_id}\n" if event_id else ""
    return f"{head}event: {event}\ndata: {json.dumps(data, separators=(',', ':'), default=str)}\n\n".encode()


def create_app(
    reader: ConsoleReader,
    access: Access,
    controls: bool = False,
    tiles: str | None = None,
    allowed_hosts: list[str] | None = None,
    poll_s: float = POLL_S,
) -> Starlette:
    """The console for one database; with ``controls``, logged-in operators may steer running missions."""

    def user(request: Request) -> str | None:
        return access.user_of(request.headers.get("authorization"), request.cookies.get(SESSION_COOKIE))

    def may_view(request: Request) -> bool:
        return access.open_view or user(request) is not None

    def page(name: str):
        async def endpoint(request: Request) -> Response:
            if not may_view(request):
                return RedirectResponse(f"/login?next={quote(request.url.path)}", status_code=303)
            return FileResponse(str(STATIC / name), headers={"Cache-Control": "no-store"})

        return endpoint

    async def login_page(request: Request) -> Response:
        return FileResponse(str(STATIC / "login.html"), headers={"Cache-Control": "no-store"})

    async def login(request: Request) -> Response:
        # the form is urlencoded: parsed here rather than adding a multipart parser for two fields
        form = parse_qs((await request.body()).decode("utf-8", "replace"))
        secret = (form.get("secret") or [""])[0]
        target = (form.get("next") or ["/"])[0]
        if not target.startswith("/") or target.startswith("//"):
            target = "/"
        session = access.login(secret) if access.users else None
        if session is None:
            await asyncio.sleep(0.5)  # slows guessing; the reason is never logged with the secret
            log.warning("failed console login from %s", request.client.host if request.client else "?")
            return RedirectResponse(f"/login?failed=1&next={quote(target)}", status_code=303)
        response = RedirectResponse(target, status_code=303)
        response.set_cookie(SESSION_COOKIE, session, httponly=True, samesite="strict", path="/")
        log.info("operator %s logged in", access.sessions[session])
        return response

    async def logout(request: Request) -> Response:
        access.logout(request.cookies.get(SESSION_COOKIE))
        response = RedirectResponse("/", status_code=303)
        response.delete_cookie(SESSION_COOKIE, path="/")
        return response

    async def me(request: Request) -> Response:
        if not may_view(request):
            return _error(401, "log in to view this console.")
        return JSONResponse(
            {"user": user(request), "controls": controls, "login_available": bool(access.users)}
        )

    async def runs(request: Request) -> Response:
        if not may_view(request):
            return _error(401, "log in to view this console.")
        try:
            found = await anyio.to_thread.run_sync(reader.runs, dict(request.query_params))
        except GuadalError as exc:
            return _error(400, str(exc))
        return JSONResponse({"runs": found})

    async def runs_stream(request: Request) -> Response:
        if not may_view(request):
            return _error(401, "log in to view this console.")

        async def events():
            seen = None
            idle = 0.0
            while True:
                version = await anyio.to_thread.run_sync(reader.runs_version)
                if version != seen:
                    seen = version
                    idle = 0.0
                    yield _sse("runs", {"runs": await anyio.to_thread.run_sync(reader.runs)})
                elif idle >= KEEPALIVE_S:
                    idle = 0.0
                    yield b": keep-alive\n\n"
                await asyncio.sleep(poll_s)
                idle += poll_s

        return StreamingResponse(events(), media_type="text/event-stream", headers=_STREAM_HEADERS)

    async def run_info(request: Request) -> Response:
        if not may_view(request):
            return _error(401, "log in to view this console.")
        run_id = request.path_params["run_id"]
        try:
            info = await anyio.to_thread.run_sync(reader.run, run_id)
        except LookupError:
            info = None
        if info is None:
            return _error(404, f"there is no run {run_id} in this database.")
        info.update(
            user=user(request),
            controls=controls,
            tiles=tiles,
            downloads=[
                {"label": label, "href": f"/api/runs/{run_id}/download/{kind}"}
                for kind, label in DOWNLOADS.items()
            ],
            default_metric=_default_metric(info["metric_columns"]),
        )
        return JSONResponse(info)

    async def run_stream(request: Request) -> Response:
        if not may_view(request):
            return _error(401, "log in to view this console.")
        run_id = request.path_params["run_id"]
        cursor = Cursor.parse(request.headers.get("last-event-id"))
        try:
            first, cursor = await anyio.to_thread.run_sync(reader.changes, run_id, cursor)
        except LookupError:
            return _error(404, f"there is no run {run_id} in this database.")

        async def events():
            nonlocal cursor
            update = first
            idle = 0.0
            while True:
                if update:
                    idle = 0.0
                    yield _sse("update", update, cursor.text())
                elif idle >= KEEPALIVE_S:
                    idle = 0.0
                    yield b": keep-alive\n\n"
                await asyncio.sleep(poll_s)
                idle += poll_s
                update, cursor = await anyio.to_thread.run_sync(reader.changes, run_id, cursor)

        return StreamingResponse(events(), media_type="text/event-stream", headers=_STREAM_HEADERS)

    async def download(request: Request) -> Response:
        if not may_view(request):
            return _error(401, "log in to view this console.")
        run_id, kind = request.path_params["run_id"], request.path_params["kind"]
        if kind not in DOWNLOADS:
            return _error(404, f"no download '{kind}'; downloads are {', '.join(DOWNLOADS)}.")
        from .downloads import build_download

        try:
            name, media, body = await anyio.to_thread.run_sync(build_download, reader.engine, run_id, kind)
        except LookupError:
            return _error(404, f"there is no run {run_id} in this database.")
        except GuadalError as exc:
            return _error(409, str(exc))
        return Response(
            body, media_type=media, headers={"Content-Disposition": f'attachment; filename="{name}"'}
        )

    async def control(request: Request) -> Response:
        who = user(request)
        if who is None:
            return _error(401, "operator controls need a login.")
        if not controls:
            return _error(403, "this console was started without --control; it only shows missions.")
        run_id = request.path_params["run_id"]
        try:
            body = await request.json()
        except (json.JSONDecodeError, UnicodeDecodeError):
            return _error(400, 'the control request must be JSON like {"action": "pause"}.')
        origin = request.client.host if request.client else None
        try:
            record = await anyio.to_thread.run_sync(
                lambda: request_control(reader.engine, run_id, body, who, origin)
            )
        except LookupError:
            return _error(404, f"there is no run {run_id} in this database.")
        except ControlRefused as exc:
            return _error(409, str(exc))
        except GuadalError as exc:
            return _error(400, str(exc))
        log.info("control %s on run %s by %s", record["action"], run_id, who)
        return JSONResponse(record, status_code=202)

    routes = [
        Route("/", page("index.html")),
        Route("/runs/{run_id:int}", page("run.html")),
        Route("/login", login_page, methods=["GET"]),
        Route("/login", login, methods=["POST"]),
        Route("/logout", logout, methods=["POST"]),
        Route("/api/me", me),
        Route("/api/runs", runs),
        Route("/api/runs/stream", runs_stream),
        Route("/api/runs/{run_id:int}", run_info),
        Route("/api/runs/{run_id:int}/stream", run_stream),
        Route("/api/runs/{run_id:int}/download/{kind}", download),
        Route("/api/runs/{run_id:int}/control", control, methods=["POST"]),
        Mount("/static", StaticFiles(directory=str(STATIC)), name="static"),
    ]

    async def unexpected(request: Request, exc: Exception) -> Response:
        log.error("%s %s failed: %s: %s", request.method, request.url.path, type(exc).__name__, exc)
        return _error(500, f"the console could not answer ({type(exc).__name__}); see its log.")

    middleware = [Middleware(TrustedHostMiddleware, allowed_hosts=allowed_hosts)] if allowed_hosts else []
    return Starlette(routes=routes, middleware=middleware, exception_handlers={Exception: unexpected})


_STREAM_HEADERS = {"Cache-Control": "no-store", "X-Accel-Buffering": "no"}
DOWNLOADS = {
    "csv": "run directory (CSV, zip)",
    "geojson": "GeoJSON",
    "kml": "KML",
    "plan": "QGroundControl plans (zip)",
}


def _default_metric(columns: list[str]) -> str | None:
    for name in ("rmse", "mean_std", "coverage"):
        if name in columns:
            return name
    return columns[-1] if columns else None
