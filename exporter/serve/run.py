"""Running the server: ``serve`` (file mode) and ``serve_db`` (DB mode) listen, print the one stdout line that
scripts and tests read (ANNOUNCE and the base URL) and run the application on uvicorn until SIGINT/SIGTERM.

uvicorn runs one process with one event loop (uvloop, the httptools parser): every answer but a cache miss is
sent from the loop, and the tile cache lives in that process. The socket is bound here rather than by uvicorn,
so that ``--port 0`` picks a free port whose URL is announced before the first request.
"""

from __future__ import annotations

import logging
import signal
import socket
import sys
from pathlib import Path
from types import FrameType
from typing import Any

import uvicorn

from exporter import ATTRIBUTION
from exporter.serve.app import make_app
from exporter.serve.files import CESIUM_DIR

ANNOUNCE = "citylod viewer: "  # the one stdout line of a running server, followed by its base URL
#: listen() backlog: a short queue drops the SYNs of a burst of new connections (a page load, a benchmark's 64
#: clients), which the client only retries after 1 s, then 3 s
BACKLOG = 1024
#: Idle keep-alive connections are closed after this (uvicorn's default of 5 s makes a browser reconnect
#: between camera moves).
KEEP_ALIVE_S = 75


def listen(host: str, port: int) -> socket.socket:
    """A bound, listening TCP socket; port 0 picks a free port."""
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
        sock.listen(BACKLOG)
    except BaseException:
        sock.close()
        raise
    return sock


def url_of(sock: socket.socket) -> str:
    host, port = sock.getsockname()[:2]
    return f"http://[{host}]:{port}/" if ":" in host else f"http://{host}:{port}/"


def uvicorn_server(app: Any) -> uvicorn.Server:
    """A uvicorn server for ``app``, to be run with ``server.run(sockets=[listen(...)])`` (stops when
    ``server.should_exit`` is set, or on SIGINT/SIGTERM when run in the main thread)."""
    config = uvicorn.Config(
        app,
        loop="uvloop",
        http="httptools",
        interface="asgi3",
        lifespan="off",
        log_config=None,
        access_log=False,  # failures are logged by app.Cors
        proxy_headers=False,
        server_header=False,
        backlog=BACKLOG,
        timeout_keep_alive=KEEP_ALIVE_S,
        timeout_graceful_shutdown=5,
    )
    return uvicorn.Server(config)


def _check_cesium() -> None:
    if not (CESIUM_DIR / "Cesium.js").is_file():
        sys.exit(f"citylod serve: CesiumJS not found at {CESIUM_DIR}; run `make setup` (npm ci)")


def _listen_or_exit(host: str, port: int) -> socket.socket:
    try:
        return listen(host, port)
    except OSError as e:
        sys.exit(f"citylod serve: cannot listen on {host}:{port}: {e}")


def _run(app: Any, sock: socket.socket, notes: list[str]) -> None:
    """Serve until SIGINT/SIGTERM. Prints exactly one line to stdout, ANNOUNCE and the base URL, which scripts
    and tests read to find the port; ``notes`` and failures go to stderr."""
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr, format="citylod serve: %(message)s")

    def stop(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt

    # uvicorn handles both signals while it runs and raises them again once it has shut down gracefully; these
    # handlers turn that (or a signal before uvicorn starts) into a clean exit. SIGINT explicitly too: a shell
    # starts background jobs with SIGINT ignored, and `kill -INT` should work.
    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    print(f"{ANNOUNCE}{url_of(sock)}", flush=True)
    for note in notes:
        print(f"  {note}", file=sys.stderr)
    print(
        f"  data {ATTRIBUTION}: keep this attribution visible wherever the tiles are shown", file=sys.stderr, flush=True
    )
    try:
        uvicorn_server(app).run(sockets=[sock])
    except KeyboardInterrupt:
        pass
    finally:
        sock.close()


def serve(tiles_dir: Path, host: str = "127.0.0.1", port: int = 8765) -> None:
    """Serve ``tiles_dir`` and the viewer until SIGINT/SIGTERM."""
    tiles_dir = Path(tiles_dir).resolve()
    if not (tiles_dir / "tileset.json").is_file():
        sys.exit(
            f"citylod serve: no tileset at {tiles_dir / 'tileset.json'}; "
            f"build one first with `make export` (or `python -m etl export --out {tiles_dir}`)"
        )
    _check_cesium()
    sock = _listen_or_exit(host, port)
    _run(make_app(tiles_dir=tiles_dir), sock, [f"tiles: {tiles_dir}"])


def _serve_source(source: Any, host: str, port: int, describe: Any) -> None:
    """Serve ``source`` (a DbTileSource or PublishedSource) until SIGINT/SIGTERM, once its tileset.json could be
    read; ``describe(source, tileset)`` is the announcement's first line. Refuses to start, in one line, when the
    database cannot be read or holds no tileset to serve."""
    from exporter.serve.reader import READER_ROLE, READER_URL_ENV, DbUnavailable
    from exporter.serve.source import NotReady

    _check_cesium()
    try:
        sock = _listen_or_exit(host, port)
        try:
            tileset = source.tileset()
        except DbUnavailable as e:
            sys.exit(
                f"citylod serve --db: cannot read the database as {READER_ROLE}: {e}\n"
                f"  run `make migrate` (migration 0011 creates the role), or set {READER_URL_ENV}"
            )
        except NotReady as e:
            sys.exit(f"citylod serve --db: {e}")
        try:
            _run(
                make_app(source=source),
                sock,
                [
                    describe(source, tileset),
                    f"cache: {source.cache.budget / 2**20:,.0f} MiB; pool: {source.reader.size} connections",
                ],
            )
        finally:
            sock.close()
    finally:
        source.close()


def serve_db(url: str, host: str = "127.0.0.1", port: int = 8765, **source_options: Any) -> None:
    """Serve the tileset straight from the database at ``url`` (give it reader.reader_url(...)) and the viewer
    until SIGINT/SIGTERM. ``source_options`` go to DbTileSource (lod, base_height, cache_bytes, pool_size,
    revalidate_s). Refuses to start when the database cannot be read or holds no current tileset."""
    from exporter.serve.source import DbTileSource

    lod = source_options.get("lod")
    _serve_source(
        DbTileSource(url, **source_options),
        host,
        port,
        lambda src, tileset: (
            f"tiles: straight from the database ({len(src.snapshot().by_uri):,} glb tiles, "
            f"{'LOD' + str(lod) if lod else 'every LOD'}, tileset.json {len(tileset.body):,} bytes)"
        ),
    )


def serve_published(url: str, name: str, host: str = "127.0.0.1", port: int = 8765, **source_options: Any) -> None:
    """Stream the live generation of the published tileset ``name`` from the database at ``url`` (give it
    reader.reader_url(...)) and the viewer until SIGINT/SIGTERM. ``source_options`` go to PublishedSource
    (cache_bytes, pool_size, revalidate_s). Refuses to start when the database cannot be read or has no such
    tileset."""
    from exporter.serve.published import PublishedSource

    def describe(src: PublishedSource, tileset: Any) -> str:
        listing = src.listing()
        return (
            f"tiles: the published tileset {name!r}, generation {listing.generation} ({len(listing.files):,} "
            f"files, tileset.json {len(tileset.body):,} bytes); a new export is picked up as it commits"
        )

    _serve_source(PublishedSource(url, name, **source_options), host, port, describe)
