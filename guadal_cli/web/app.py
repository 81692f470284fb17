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
from starlette.exceptions import HTTPException
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import ClientDisconnect, Request
from starlette.responses import FileResponse, JSONResponse, RedirectResponse, Response, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from ..db import queries
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
#: the most a request body may hold: a control is ~40 bytes, the login form ~200
MAX_BODY = 16 * 1024


def _error(status: int, sentence: str) -> JSONResponse:
    return JSONResponse({"error": sentence}, status_code=status)


class Refused(Exception):
    """A request refused in one sentence, from wherever it is found wrong."""

    def __init__(self, status: int, sentence: str):
        super().__init__(sentence)
        self.status, self.sentence = status, sentence


async def _body(request: Request) -> bytes:
    """The request's body, read no further than ``MAX_BODY`` bytes."""
    too_big = Refused(413, f"the request body is larger than {MAX_BODY} bytes, the most this console reads.")
    declared = request.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > MAX_BODY:
        raise too_big
    chunks, size = [], 0
    try:
        async for chunk in request.stream():
            size += len(chunk)
            if size > MAX_BODY:
                raise too_big
            chunks.append(chunk)
    except ClientDisconnect:
        raise Refused(
            400, "the request body ended before its declared length (the client went away)."
        ) from None
    return b"".join(chunks)


def _refuse_cross_site(request: Request) -> None:
    """Requests that change something come from the console's own pages (or no browser at all).

    Browsers say where a request comes from in ``Sec-Fetch-Site``; another site, or another port
    of the same host (``same-site``), may not log in, log out or steer a boat with the operator's
    cookie. Clients that are not browsers send no such header and authenticate by secret.
    """
    site = request.headers.get("sec-fetch-site", "same-origin")
    if site not in ("same-origin", "none"):
        raise Refused(403, f"a {site} request may not change anything here; use the console's own pages.")


def _run_id(request: Request) -> int:
    run_id = request.path_params["run_id"]
    if not 0 < run_id <= queries.MAX_ROW_ID:
        raise Refused(404, f"there is no run {run_id} in this database.")
    return run_id


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
        _refuse_cross_site(request)
        # the form is urlencoded: parsed here rather than adding a multipart parser for two fields
        form = parse_qs((await _body(request)).decode("utf-8", "replace"))
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
        _refuse_cross_site(request)
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
        keys = [key for key, _ in request.query_params.multi_items()]
        twice = next((key for key in keys if keys.count(key) > 1), None)
        if twice is not None:
            return _error(400, f"filter '{twice}' is given more than once; give each filter once.")
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
        run_id = _run_id(request)
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
        run_id = _run_id(request)
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
        run_id, kind = _run_id(request), request.path_params["kind"]
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
        _refuse_cross_site(request)
        run_id = _run_id(request)
        kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if kind != "application/json":
            return _error(
                415, 'the control request must be sent as application/json, like {"action": "pause"}.'
            )
        try:
            body = json.loads(await _body(request))
        except (ValueError, RecursionError):  # not JSON, not UTF-8, numbers past 4300 digits, nesting
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

    async def refused(request: Request, exc: Refused) -> Response:
        return _error(exc.status, exc.sentence)

    async def http_error(request: Request, exc: HTTPException) -> Response:
        """The router's own refusals (no such route, wrong method), as sentences like the rest."""
        if exc.status_code == 405:
            allowed = (exc.headers or {}).get("Allow", "GET")
            sentence = f"{request.method} is not allowed on {request.url.path}; it takes {allowed}."
            return JSONResponse({"error": sentence}, status_code=405, headers={"Allow": allowed})
        if exc.status_code == 404:
            return _error(404, f"there is nothing at {request.url.path}; the missions are listed at /.")
        return _error(exc.status_code, f"the request was refused ({exc.detail}).")

    async def unexpected(request: Request, exc: Exception) -> Response:
        log.error("%s %s failed: %s: %s", request.method, request.url.path, type(exc).__name__, exc)
        return _error(500, f"the console could not answer ({type(exc).__name__}); see its log.")

    middleware = [Middleware(TrustedHostMiddleware, allowed_hosts=allowed_hosts)] if allowed_hosts else []
    return Starlette(
        routes=routes,
        middleware=middleware,
        exception_handlers={Refused: refused, HTTPException: http_error, Exception: unexpected},
    )


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
