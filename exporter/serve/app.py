"""The ASGI application: Starlette routes for the viewer and the tileset, behind a CORS layer.

* file mode: ``/tiles/<path>`` are the files of the exported tileset directory (files.file_route);
* DB mode: ``/tiles/tileset.json``, ``/tiles/subtrees/...`` and ``/tiles/content/L/X/Y.glb`` come from a
  PublishedSource (the live generation an export published) or, ``--live``, a DbTileSource. The address is
  checked first (paths.tile_address: 400 malformed, 404 cannot exist), without touching the database. A cached
  tile is answered on the event loop. A miss or a revalidation blocks, so it runs on a worker thread, at most
  TILE_THREADS at a time and apart from the threads Starlette reads files on (and decompresses for a client
  without gzip): a burst of cold tiles queued behind the database does not hold up the viewer's files. Strong
  ETags (If-None-Match -> 304), gzip when the client accepts it, and a database that is down or holds no
  current tiles is a 503 with one short line.

Every response carries ``Access-Control-Allow-Origin: *`` (errors too: a cross-origin CesiumJS app must be able
to read a 404), and OPTIONS, the CORS preflight, is answered on any path. Starlette's CORSMiddleware does
neither for a request without an Origin header, hence the small layer here.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import anyio
from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import Route
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from exporter.serve.files import file_route, request_path, text, viewer_routes
from exporter.serve.paths import BadPath, tile_address
from exporter.serve.payload import Payload, accepts_gzip, etag_matches

if TYPE_CHECKING:  # file mode does not import the exporter's database side
    from exporter.serve.published import PublishedSource
    from exporter.serve.source import DbTileSource

log = logging.getLogger("citylod.serve")

#: Tile requests that may wait for the database at once (the others queue on the event loop); more than the
#: connection pool, so that a thread decompressing or compressing a tile does not keep the database idle.
TILE_THREADS = 32
_ALLOW_ORIGIN = (b"access-control-allow-origin", b"*")
_PREFLIGHT = [
    _ALLOW_ORIGIN,
    (b"access-control-allow-methods", b"GET, HEAD, OPTIONS"),
    (b"access-control-allow-headers", b"*"),
    (b"access-control-max-age", b"86400"),
    (b"content-length", b"0"),
]


class Cors:
    """Adds Access-Control-Allow-Origin to every response, answers OPTIONS with 204 and logs failures (only
    those: a tileset load is hundreds of requests, which would drown the useful lines)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        if scope["method"] == "OPTIONS":
            await send({"type": "http.response.start", "status": 204, "headers": _PREFLIGHT})
            await send({"type": "http.response.body", "body": b""})
            return

        async def send_with_cors(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", ()), _ALLOW_ORIGIN]
                if message["status"] >= 400:
                    client = scope.get("client") or ("-",)
                    log.warning(
                        '%s "%s %s" %d',
                        client[0],
                        scope["method"],
                        scope.get("raw_path", b"").decode("latin-1"),
                        message["status"],
                    )
            await send(message)

        await self.app(scope, receive, send_with_cors)


def _unavailable(message: str) -> Response:
    return text(503, message, **{"Cache-Control": "no-store", "Retry-After": "5"})


async def _send_payload(request: Request, p: Payload) -> Response:
    use_gzip = p.gzipped and accepts_gzip(request.headers.get("accept-encoding"))
    etag = p.gzip_etag if use_gzip else p.etag
    # revalidate every time (the database may change); the encoding is part of the answer
    headers = {"ETag": etag, "Cache-Control": "no-cache", "Vary": "Accept-Encoding"}
    if etag_matches(request.headers.get("if-none-match"), etag):
        return Response(status_code=304, headers=headers)
    if use_gzip:
        headers["Content-Encoding"] = "gzip"
        data = p.stored
    else:
        data = p.stored if not p.gzipped else await run_in_threadpool(lambda: p.body)
    return Response(data, 200, headers, p.media_type)


def db_tiles_route(source: DbTileSource | PublishedSource) -> Route:
    from exporter.serve.reader import Busy, DbUnavailable
    from exporter.serve.source import NotReady

    limiter = anyio.CapacityLimiter(TILE_THREADS)

    async def tiles(request: Request) -> Response:
        try:
            address = tile_address(request_path(request)[len("/tiles/") :])
        except BadPath:
            return text(400, "bad tile address")
        if address is None:
            return text(404, "not found")
        payload = source.peek(address)
        if payload is None:
            try:
                payload = await anyio.to_thread.run_sync(source.get, address, limiter=limiter)
            except NotReady as e:
                log.warning("no current tileset in the database: %s", e)
                return _unavailable(f"no current tileset in the database: {e}")
            except Busy as e:
                log.warning("a stage holds the tables: %s", e)
                return _unavailable(
                    "a stage is rebuilding the tables, retry later (serve --db without --live "
                    "streams the published tileset meanwhile)"
                )
            except DbUnavailable as e:
                log.warning("database unavailable: %s", e)  # the detail stays in the server's log
                return _unavailable("database unavailable, retry later")
            if payload is None:
                return text(404, "not found")
        return await _send_payload(request, payload)

    return Route("/tiles/{rel:path}", tiles, methods=["GET"])


def make_app(tiles_dir: Path | None = None, source: DbTileSource | PublishedSource | None = None) -> ASGIApp:
    """The viewer plus the tileset: the files of ``tiles_dir`` (file mode) or ``source`` (DB mode)."""
    if source is not None and tiles_dir is None:
        tiles = db_tiles_route(source)
    elif tiles_dir is not None and source is None:
        tiles = file_route("/tiles/", tiles_dir)
    else:
        raise ValueError("give exactly one of tiles_dir and source")
    app = Starlette(routes=[*viewer_routes(), tiles])
    app.router.redirect_slashes = False  # /viewer is a 404 like any other unknown path, not a redirect
    return Cors(app)
