"""``python -m exporter serve``: a small static server for one tileset and the CesiumJS viewer. Stdlib only.

Routes (GET and HEAD; OPTIONS answers CORS preflights):

* ``/`` and ``/index.html`` -> exporter/viewer/index.html
* ``/viewer/<file>``        -> exporter/viewer/
* ``/cesium/<path>``        -> node_modules/cesium/Build/Cesium/ (CesiumJS runs offline from here)
* ``/tiles/<path>``         -> the tileset directory

Every response carries ``Access-Control-Allow-Origin: *`` so a CesiumJS app on another origin can stream the
tiles. There are no directory listings, and a path that would leave its root (``..``, encoded or not, or a
symlink pointing outside) is refused with 400/404, never served.
"""

from __future__ import annotations

import contextlib
import shutil
import signal
import socket
import sys
from email.utils import formatdate
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from types import FrameType
from urllib.parse import unquote, urlsplit

from . import ATTRIBUTION

REPO = Path(__file__).resolve().parent.parent
VIEWER_DIR = Path(__file__).resolve().parent / "viewer"
CESIUM_DIR = REPO / "node_modules" / "cesium" / "Build" / "Cesium"

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


class BadPath(ValueError):
    """The request path is malformed or tries to leave its root (answered with 400)."""


def media_type(path: Path) -> str:
    return MEDIA_TYPES.get(path.suffix.lower(), DEFAULT_MEDIA_TYPE)


def safe_join(root: Path, rel: str) -> Path | None:
    """The file ``rel`` (already percent-decoded, '/'-separated) under ``root``, or None when there is no such
    regular file. Raises BadPath for '..', NUL and the like, so a traversal attempt is a 400, not a probe."""
    if "\x00" in rel or "\\" in rel:
        raise BadPath(rel)
    parts = [p for p in rel.split("/") if p not in ("", ".")]
    if any(p == ".." for p in parts):
        raise BadPath(rel)
    root = root.resolve()
    try:
        target = root.joinpath(*parts).resolve()
        # resolve() follows symlinks: this refuses a link that points outside the root as well.
        if not target.is_relative_to(root) or not target.is_file():
            return None
    except (OSError, RuntimeError):  # permissions, symlink loops, over-long names
        return None
    return target


class Roots:
    """Where each URL prefix is served from."""

    def __init__(self, tiles: Path, viewer: Path = VIEWER_DIR, cesium: Path = CESIUM_DIR) -> None:
        self.tiles, self.viewer, self.cesium = tiles, viewer, cesium

    def locate(self, url_path: str) -> Path | None:
        """Map a decoded URL path to a file, None for 404; BadPath for 400."""
        if url_path in ("/", "/index.html"):
            return safe_join(self.viewer, "index.html")
        for prefix, root in (("/viewer/", self.viewer), ("/cesium/", self.cesium), ("/tiles/", self.tiles)):
            if url_path.startswith(prefix):
                return safe_join(root, url_path[len(prefix):])
        return None


class Handler(BaseHTTPRequestHandler):
    server_version = "citylod"
    protocol_version = "HTTP/1.1"  # keep-alive: CesiumJS fetches many tiles from one host
    roots: Roots  # set on the subclass made by make_server()

    def end_headers(self) -> None:
        # On every response, errors included: a cross-origin client must be able to read a 404 too.
        self.send_header("Access-Control-Allow-Origin", "*")
        super().end_headers()

    def do_OPTIONS(self) -> None:  # noqa: N802 (http.server naming)
        self.send_response(HTTPStatus.NO_CONTENT)
        self.send_header("Access-Control-Allow-Methods", "GET, HEAD, OPTIONS")
        self.send_header("Access-Control-Allow-Headers", "*")
        self.send_header("Access-Control-Max-Age", "86400")
        self.send_header("Content-Length", "0")
        self.end_headers()

    def do_HEAD(self) -> None:  # noqa: N802
        self._serve(body=False)

    def do_GET(self) -> None:  # noqa: N802
        self._serve(body=True)

    def _serve(self, body: bool) -> None:
        try:
            path = unquote(urlsplit(self.path).path, errors="strict")
            target = self.roots.locate(path)
        except (BadPath, UnicodeDecodeError, ValueError):
            self.send_error(HTTPStatus.BAD_REQUEST, "bad path")
            return
        if target is None:
            self.send_error(HTTPStatus.NOT_FOUND)
            return
        try:
            f = target.open("rb")
        except OSError:
            self.send_error(HTTPStatus.NOT_FOUND)
            return
        with f:
            st = target.stat()
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", media_type(target))
            self.send_header("Content-Length", str(st.st_size))
            self.send_header("Last-Modified", formatdate(st.st_mtime, usegmt=True))
            # Tiles and the viewer change with every export/edit; CesiumJS's build does not.
            cache = "public, max-age=3600" if path.startswith("/cesium/") else "no-cache"
            self.send_header("Cache-Control", cache)
            self.end_headers()
            if body:
                # The client may go away mid-file (CesiumJS cancels requests for tiles it no longer needs).
                with contextlib.suppress(BrokenPipeError, ConnectionResetError):
                    shutil.copyfileobj(f, self.wfile, 1 << 20)

    def log_request(self, code: int | str = "-", size: int | str = "-") -> None:
        # Only failures: a tileset load is hundreds of requests, which would drown the useful lines.
        if isinstance(code, HTTPStatus):
            code = code.value
        if str(code).isdigit() and int(code) >= 400:
            super().log_request(code, size)


class _Server(ThreadingHTTPServer):
    daemon_threads = True  # do not wait for keep-alive connections at shutdown


class _Server6(_Server):
    address_family = socket.AF_INET6


def make_server(tiles_dir: Path, host: str = "127.0.0.1", port: int = 8765) -> ThreadingHTTPServer:
    """A bound (not yet serving) server; port 0 picks a free port (see server.server_address)."""
    handler = type("CitylodHandler", (Handler,), {"roots": Roots(tiles_dir)})
    cls = _Server6 if ":" in host else _Server
    return cls((host, port), handler)


def server_url(server: ThreadingHTTPServer) -> str:
    host, port = server.server_address[:2]
    host = str(host)
    return f"http://[{host}]:{port}/" if ":" in host else f"http://{host}:{port}/"


def serve(tiles_dir: Path, host: str = "127.0.0.1", port: int = 8765) -> None:
    """Serve ``tiles_dir`` and the viewer until SIGINT/SIGTERM. Prints exactly one line to stdout,
    ``citylod viewer: http://HOST:PORT/``, which scripts and the e2e test read to find the port."""
    tiles_dir = Path(tiles_dir).resolve()
    if not (tiles_dir / "tileset.json").is_file():
        sys.exit(f"citylod serve: no tileset at {tiles_dir / 'tileset.json'}; "
                 f"build one first with `make export` (or `python -m etl export --out {tiles_dir}`)")
    if not (CESIUM_DIR / "Cesium.js").is_file():
        sys.exit(f"citylod serve: CesiumJS not found at {CESIUM_DIR}; run `make setup` (npm ci)")
    try:
        server = make_server(tiles_dir, host, port)
    except OSError as e:
        sys.exit(f"citylod serve: cannot listen on {host}:{port}: {e}")

    def stop(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt  # unwinds serve_forever() in the main thread

    # SIGINT explicitly too: a shell starts background jobs with SIGINT ignored, and `kill -INT` should work.
    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    print(f"citylod viewer: {server_url(server)}", flush=True)
    print(f"  tiles: {tiles_dir}", file=sys.stderr)
    print(f"  data {ATTRIBUTION}: keep this attribution visible wherever the tiles are shown",
          file=sys.stderr, flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
