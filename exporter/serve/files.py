"""What the server sends from disk: the viewer (exporter/viewer/), CesiumJS's build (node_modules, so the viewer
runs offline) and, in file mode, the exported tileset directory. One Starlette route per root; a path that would
leave its root is refused by paths.safe_join."""

from __future__ import annotations

from pathlib import Path, PurePath

from starlette.requests import Request
from starlette.responses import FileResponse, PlainTextResponse, Response
from starlette.routing import Route

from exporter.serve.paths import BadPath, decode, safe_join

_PACKAGE = Path(__file__).resolve().parent.parent
VIEWER_DIR = _PACKAGE / "viewer"
CESIUM_DIR = _PACKAGE.parent / "node_modules" / "cesium" / "Build" / "Cesium"

# Explicit table: mimetypes depends on the host's /etc/mime.types and knows neither glb nor ktx2 everywhere.
MEDIA_TYPES: dict[str, str] = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".mjs": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".json": "application/json",
    ".geojson": "application/geo+json",
    ".glb": "model/gltf-binary",
    ".gltf": "model/gltf+json",
    ".b3dm": "application/octet-stream",
    ".i3dm": "application/octet-stream",
    ".pnts": "application/octet-stream",
    ".cmpt": "application/octet-stream",
    ".subtree": "application/octet-stream",
    ".bin": "application/octet-stream",
    ".wasm": "application/wasm",
    ".png": "image/png",
    ".jpg": "image/jpeg",
    ".jpeg": "image/jpeg",
    ".gif": "image/gif",
    ".webp": "image/webp",
    ".svg": "image/svg+xml",
    ".ico": "image/x-icon",
    ".ktx2": "image/ktx2",
    ".woff": "font/woff",
    ".woff2": "font/woff2",
    ".ttf": "font/ttf",
    ".txt": "text/plain; charset=utf-8",
    ".md": "text/plain; charset=utf-8",
    ".xml": "application/xml",
}
DEFAULT_MEDIA_TYPE = "application/octet-stream"
#: Tiles and the viewer change with every export or edit; CesiumJS's build does not.
NO_CACHE = "no-cache"
CESIUM_CACHE = "public, max-age=3600"


def media_type(path: PurePath) -> str:
    return MEDIA_TYPES.get(path.suffix.lower(), DEFAULT_MEDIA_TYPE)


def request_path(request: Request) -> str:
    """The request's path decoded strictly from the bytes the client sent (paths.decode)."""
    return decode(request.scope.get("raw_path") or request.url.path.encode())


def text(status: int, message: str, **headers: str) -> Response:
    """A short plain-text answer (errors: one line, never a traceback)."""
    return PlainTextResponse(message.replace("\n", " ")[:500] + "\n", status, headers or None)


def file_response(root: Path, rel: str, cache_control: str) -> Response:
    try:
        target = safe_join(root, rel)
    except BadPath:
        return text(400, "bad path")
    if target is None:
        return text(404, "not found")
    # FileResponse streams in chunks, answers HEAD without the body and sets Content-Length and Last-Modified.
    return FileResponse(target, media_type=media_type(target), headers={"Cache-Control": cache_control})


def file_route(prefix: str, root: Path, cache_control: str = NO_CACHE) -> Route:
    """GET/HEAD ``<prefix><path>`` -> the file ``<path>`` under ``root`` (no directory listings)."""

    async def endpoint(request: Request) -> Response:
        try:
            rel = request_path(request)[len(prefix) :]
        except BadPath:
            return text(400, "bad path")
        return file_response(root, rel, cache_control)

    return Route(prefix + "{rel:path}", endpoint, methods=["GET"])


def viewer_routes() -> list[Route]:
    """``/`` and ``/index.html`` (the viewer page), ``/viewer/...`` and ``/cesium/...``."""

    async def index(request: Request) -> Response:
        return file_response(VIEWER_DIR, "index.html", NO_CACHE)

    return [
        Route("/", index, methods=["GET"]),
        Route("/index.html", index, methods=["GET"]),
        file_route("/viewer/", VIEWER_DIR),
        file_route("/cesium/", CESIUM_DIR, CESIUM_CACHE),
    ]
