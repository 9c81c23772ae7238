"""``python -m etl serve`` (= ``python -m exporter serve``): the CesiumJS viewer and one tileset, streamed either
from an exported directory (``--dir``, the default) or straight from the database (``--db``).

Routes (GET and HEAD; OPTIONS answers CORS preflights):

* ``/`` and ``/index.html`` -> exporter/viewer/index.html
* ``/viewer/<file>``        -> exporter/viewer/
* ``/cesium/<path>``        -> node_modules/cesium/Build/Cesium/ (CesiumJS runs offline from here)
* ``/tiles/<path>``         -> the tileset: files of the tileset directory, or in DB mode ``/tiles/tileset.json``
  and ``/tiles/content/L/X/Y.glb`` built on request by the exporter's own functions (exporter/export.py), the
  same bytes the file export writes, at the same URLs, so the viewer works unchanged in both modes.

Every response carries ``Access-Control-Allow-Origin: *`` so a CesiumJS app on another origin can stream the
tiles. There are no directory listings, and a path that would leave its root (``..``, encoded or not, or a
symlink pointing outside) is refused with 400/404, never served.

DB mode (``DbTileSource``):

* connects as the read-only role ``citylod_reader`` (migration 0011) with ``default_transaction_read_only = on``,
  through a small pool (a psycopg connection is never shared by two threads at once); each answer is read in one
  REPEATABLE READ, READ ONLY transaction;
* keeps built tiles in an in-memory LRU with a byte budget; the database's *generation* (latest successful
  ``meta.pipeline_run`` + dataset sha256) is re-read at most every ``revalidate_s`` seconds and a new one drops
  the cache, so a pipeline re-run is picked up without a restart;
* strong ETags (sha256 of the bytes; ``-gzip`` for the gzip variant), ``If-None-Match`` -> 304; gzip when the
  client accepts it and it saves at least ``GZIP_MIN_SAVING``: it does for tileset.json (to 18-25 %) and for glbs
  too (to 25-34 % of their size on the Liechtenstein and Munich exports: flat shading repeats normals and colours
  per vertex), at about 50 MB/s (level 6; level 1 is twice as fast for 6 % more bytes), once per cached tile,
  and the cache keeps only that variant (Payload);
* a malformed tile address is a 400 and a well-formed one that is not in the tileset a 404, both without touching
  the database; a database that is unreachable, or answers with an error, or holds no current tiles (a stage is
  re-running) is a 503 with one short line, never a traceback.
"""

from __future__ import annotations

import contextlib
import gzip
import hashlib
import json
import os
import queue
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections import OrderedDict
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import Future
from dataclasses import dataclass, replace
from email.utils import formatdate
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from types import FrameType
from typing import IO, TYPE_CHECKING, Any
from urllib.parse import unquote, urlsplit

from . import ATTRIBUTION

if TYPE_CHECKING:  # the DB mode imports psycopg and the exporter lazily: file mode stays stdlib only
    import psycopg

    from .tileset import TileRecord

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

    def __init__(self, tiles: Path | None, viewer: Path = VIEWER_DIR, cesium: Path = CESIUM_DIR) -> None:
        self.tiles, self.viewer, self.cesium = tiles, viewer, cesium  # tiles None: not served from files

    def locate(self, url_path: str) -> Path | None:
        """Map a decoded URL path to a file, None for 404; BadPath for 400."""
        if url_path in ("/", "/index.html"):
            return safe_join(self.viewer, "index.html")
        for prefix, root in (("/viewer/", self.viewer), ("/cesium/", self.cesium), ("/tiles/", self.tiles)):
            if url_path.startswith(prefix):
                return safe_join(root, url_path[len(prefix):]) if root is not None else None
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
    # listen() backlog: socketserver's default of 5 drops the SYNs of a burst of new connections (a page load,
    # a benchmark's 64 clients), which the client only retries after 1 s, then 3 s
    request_queue_size = 128


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


def _check_cesium() -> None:
    if not (CESIUM_DIR / "Cesium.js").is_file():
        sys.exit(f"citylod serve: CesiumJS not found at {CESIUM_DIR}; run `make setup` (npm ci)")


ANNOUNCE = "citylod viewer: "  # the one stdout line of a running server, followed by its base URL


@contextlib.contextmanager
def spawned(args: list[str], env: Mapping[str, str] | None = None,
            timeout: float = 30.0) -> Iterator[tuple[str, subprocess.Popen, IO[str]]]:
    """Run ``python -m <args>`` (a serve command, usually with ``--port 0``) and yield (its base URL, the
    process, its stderr as a file); terminated after. The announcement is read on a thread, so a server that
    hangs before announcing raises RuntimeError with its stderr instead of hanging the caller."""
    with tempfile.TemporaryFile(mode="w+") as err:
        proc = subprocess.Popen([sys.executable, "-m", *args], cwd=REPO, env=dict(env or os.environ),
                                stdout=subprocess.PIPE, stderr=err, text=True)
        try:
            lines: queue.Queue[str] = queue.Queue()
            out = proc.stdout
            assert out is not None
            threading.Thread(target=lambda: lines.put(out.readline()), daemon=True).start()
            try:
                line = lines.get(timeout=timeout)
            except queue.Empty:
                line = ""
            if not line.startswith(ANNOUNCE):
                err.seek(0)
                raise RuntimeError(f"python -m {' '.join(args)} did not announce its URL (got {line!r}):\n"
                                   f"{err.read()}")
            yield line[len(ANNOUNCE):].strip(), proc, err
        finally:
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
            if proc.stdout:
                proc.stdout.close()


def _run_forever(server: ThreadingHTTPServer, notes: list[str]) -> None:
    """Serve until SIGINT/SIGTERM. Prints exactly one line to stdout, ANNOUNCE and the base URL, which scripts
    and tests read to find the port (``spawned``); ``notes`` go to stderr."""

    def stop(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt  # unwinds serve_forever() in the main thread

    # SIGINT explicitly too: a shell starts background jobs with SIGINT ignored, and `kill -INT` should work.
    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    print(f"{ANNOUNCE}{server_url(server)}", flush=True)
    for note in notes:
        print(f"  {note}", file=sys.stderr)
    print(f"  data {ATTRIBUTION}: keep this attribution visible wherever the tiles are shown",
          file=sys.stderr, flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()


def serve(tiles_dir: Path, host: str = "127.0.0.1", port: int = 8765) -> None:
    """Serve ``tiles_dir`` and the viewer until SIGINT/SIGTERM (see _run_forever for the one stdout line)."""
    tiles_dir = Path(tiles_dir).resolve()
    if not (tiles_dir / "tileset.json").is_file():
        sys.exit(f"citylod serve: no tileset at {tiles_dir / 'tileset.json'}; "
                 f"build one first with `make export` (or `python -m etl export --out {tiles_dir}`)")
    _check_cesium()
    try:
        server = make_server(tiles_dir, host, port)
    except OSError as e:
        sys.exit(f"citylod serve: cannot listen on {host}:{port}: {e}")
    _run_forever(server, [f"tiles: {tiles_dir}"])


# --- DB mode: the tileset built on request from the database -------------------------------------------------

#: The read-only role of migration 0011 that the server connects as.
READER_ROLE = "citylod_reader"
#: Environment variable with the reader's full connection URL (else derived from the pipeline's URL).
READER_URL_ENV = "CITYLOD_READER_URL"
#: Keep a gzip variant only when it is at least this much smaller than the bytes (else gzip costs the client
#: CPU for nothing).
GZIP_MIN_SAVING = 0.10
GZIP_LEVEL = 6
#: Session settings of every server connection: read-only even if the role were not, a bound on each query,
#: no JIT (its compile time dominates short statements), UTC.
READER_SESSION = {"default_transaction_read_only": "on", "statement_timeout": "30s", "jit": "off",
                  "TimeZone": "UTC"}
#: The quadtree never goes deeper than this (settings.tile_max_level is 16); deeper addresses are 404s.
MAX_TILE_LEVEL = 30
_INT = r"(0|[1-9][0-9]{0,9})"  # canonical: no sign, no leading zeros, at most 10 digits
_CONTENT_RE = re.compile(rf"content/{_INT}/{_INT}/{_INT}\.glb")
TILESET = "tileset.json"
GENERATION_SQL = """SELECT (SELECT max(run_id) FROM meta.pipeline_run WHERE status = 'ok'),
                           (SELECT source_sha256 FROM meta.dataset)"""


class DbUnavailable(Exception):
    """The database cannot be reached or answered with an error (answered with 503)."""


class NotReady(Exception):
    """The database holds no current tileset: no tiles, stale tiles, generalize not run (answered with 503)."""


class _Changed(Exception):
    """The data changed while a tile was being built: look the tile up again in the new tree."""


def reader_url(url: str, environ: Mapping[str, str] | None = None) -> str:
    """The URL the server connects with: CITYLOD_READER_URL when set, else ``url`` (DATABASE_URL or the local
    cluster's, as every stage gets it from core.cluster.ensure) with the user replaced by citylod_reader and no
    password (the local cluster trusts its socket; elsewhere libpq's PGPASSWORD/.pgpass or CITYLOD_READER_URL)."""
    from psycopg.conninfo import conninfo_to_dict, make_conninfo

    environ = os.environ if environ is None else environ
    if environ.get(READER_URL_ENV):
        return environ[READER_URL_ENV]
    params = {k: v for k, v in conninfo_to_dict(url).items() if k != "password"}
    params["user"] = READER_ROLE
    return make_conninfo(**params)


def tile_address(rel: str) -> str | None:
    """Classify what follows ``/tiles/`` (percent-decoded): ``tileset.json`` or a canonical
    ``content/L/X/Y.glb``; None for an address that cannot exist (404). Raises BadPath (400) for anything
    malformed: '..', NUL, backslashes, a content path that is not three non-negative decimal integers."""
    if "\x00" in rel or "\\" in rel or ".." in rel.split("/"):
        raise BadPath(rel)
    if rel == TILESET:
        return rel
    if not rel.startswith("content/"):
        return None
    m = _CONTENT_RE.fullmatch(rel)
    if m is None:
        raise BadPath(rel)
    level, x, y = (int(g) for g in m.groups())
    if level > MAX_TILE_LEVEL or x >= 1 << level or y >= 1 << level:
        return None
    return rel


@dataclass(frozen=True)
class Payload:
    """One cached answer, stored once: gzip-compressed when that pays (browsers all accept gzip; a client that
    does not gets it decompressed per request), else as is; strong ETags for both encodings. Storing one variant
    keeps a city's tiles in the cache budget: the Liechtenstein tileset is 234 MB raw but 65 MB gzipped, and a
    cache smaller than what a client cycles through turns every "warm" request into a rebuild (LRU thrash)."""

    stored: bytes
    gzipped: bool
    etag: str
    media_type: str

    @property
    def gzip_etag(self) -> str:
        return self.etag[:-1] + '-gzip"'

    @property
    def gzip(self) -> bytes | None:
        return self.stored if self.gzipped else None

    @property
    def body(self) -> bytes:
        return gzip.decompress(self.stored) if self.gzipped else self.stored

    @property
    def size(self) -> int:
        return len(self.stored) + 200


def make_payload(body: bytes, media: str, min_saving: float = GZIP_MIN_SAVING) -> Payload:
    packed = gzip.compress(body, GZIP_LEVEL, mtime=0)
    keep = len(packed) <= (1.0 - min_saving) * len(body)
    return Payload(packed if keep else body, keep, f'"{hashlib.sha256(body).hexdigest()[:32]}"', media)


def accepts_gzip(header: str | None) -> bool:
    """Accept-Encoding allows gzip (explicitly, or through ``*``) with q > 0."""
    if not header:
        return False
    q_gzip = q_star = None
    for item in header.split(","):
        name, _, params = item.partition(";")
        name = name.strip().lower()
        q = 1.0
        for p in params.split(";"):
            k, _, v = p.partition("=")
            if k.strip().lower() == "q":
                try:
                    q = float(v)
                except ValueError:
                    q = 0.0
        if name in ("gzip", "x-gzip"):
            q_gzip = q
        elif name == "*":
            q_star = q
    q = q_gzip if q_gzip is not None else q_star
    return q is not None and q > 0


def etag_matches(header: str | None, etag: str) -> bool:
    """If-None-Match (weak comparison, RFC 9110 13.1.2) against our strong ETag."""
    if not header:
        return False
    tags = [t.strip() for t in header.split(",")]
    return any(t == "*" or t.removeprefix("W/") == etag for t in tags)


class ByteLru:
    """A thread-safe LRU of Payloads bounded by their total size, with single flight: concurrent misses of
    one key build it once and share the result (or the exception)."""

    def __init__(self, budget: int) -> None:
        self.budget = budget
        self._items: OrderedDict[Any, Payload] = OrderedDict()
        self._inflight: dict[Any, Future[Payload]] = {}
        self._bytes = 0
        self._lock = threading.Lock()
        self.hits = self.misses = self.evictions = 0

    def get_or_build(self, key: Any, build: Callable[[], Payload]) -> Payload:
        with self._lock:
            item = self._items.get(key)
            if item is not None:
                self._items.move_to_end(key)
                self.hits += 1
                return item
            fut = self._inflight.get(key)
            owner = fut is None
            if fut is None:
                fut = self._inflight[key] = Future()
                self.misses += 1
        if not owner:
            return fut.result()
        try:
            value = build()
        except BaseException as e:
            with self._lock:
                del self._inflight[key]
            fut.set_exception(e)
            raise
        with self._lock:
            del self._inflight[key]
            self._put(key, value)
        fut.set_result(value)
        return value

    def _put(self, key: Any, value: Payload) -> None:
        if value.size > self.budget:
            return  # larger than the whole budget: served, never kept
        old = self._items.pop(key, None)
        if old is not None:
            self._bytes -= old.size
        self._items[key] = value
        self._bytes += value.size
        while self._bytes > self.budget:
            _, dropped = self._items.popitem(last=False)
            self._bytes -= dropped.size
            self.evictions += 1

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self._bytes = 0

    def stats(self) -> dict[str, int]:
        with self._lock:
            return {"entries": len(self._items), "bytes": self._bytes, "budget": self.budget, "hits": self.hits,
                    "misses": self.misses, "evictions": self.evictions}


class ReaderPool:
    """At most ``size`` connections, each used by one thread at a time (psycopg connections must not be shared
    concurrently); idle ones are kept, broken ones dropped. Every connection runs READER_SESSION and
    REPEATABLE READ, READ ONLY transactions."""

    def __init__(self, url: str, size: int, acquire_timeout: float = 30.0) -> None:
        self.url, self.size, self.acquire_timeout = url, size, acquire_timeout
        self._slots = threading.BoundedSemaphore(size)
        self._idle: list[psycopg.Connection] = []
        self._lock = threading.Lock()
        self._closed = False

    def _connect(self) -> psycopg.Connection:
        import psycopg
        from psycopg.conninfo import conninfo_to_dict, make_conninfo

        params = conninfo_to_dict(self.url)
        options = " ".join(f"-c {k}={v}" for k, v in READER_SESSION.items())
        params["options"] = f"{params.get('options') or ''} {options}".strip()
        params.setdefault("connect_timeout", "5")
        params.setdefault("application_name", "citylod serve")
        conn = psycopg.connect(make_conninfo(**params), autocommit=True)
        conn.isolation_level = psycopg.IsolationLevel.REPEATABLE_READ  # one snapshot per answer
        conn.read_only = True
        return conn

    @contextlib.contextmanager
    def connection(self) -> Iterator[tuple[psycopg.Connection, bool]]:
        """(connection, reused): reused is True for a connection that had been idle in the pool."""
        from psycopg.pq import TransactionStatus

        if not self._slots.acquire(timeout=self.acquire_timeout):
            raise DbUnavailable("every database connection is busy")
        conn = None
        try:
            with self._lock:
                if self._closed:
                    raise DbUnavailable("the server is shutting down")
                conn = self._idle.pop() if self._idle else None
            reused = conn is not None
            if conn is None:
                conn = self._connect()
            yield conn, reused
        except BaseException:
            if conn is not None and (conn.closed or conn.broken
                                     or conn.info.transaction_status != TransactionStatus.IDLE):
                conn.close()
                conn = None
            raise
        finally:
            if conn is not None:
                with self._lock:
                    if self._closed or conn.closed:
                        conn.close()
                    else:
                        self._idle.append(conn)
            self._slots.release()

    def close(self) -> None:
        with self._lock:
            self._closed = True
            idle, self._idle = self._idle, []
        for c in idle:
            c.close()


@dataclass(frozen=True)
class _Snapshot:
    generation: tuple[Any, ...]
    tileset: Payload
    by_uri: dict[str, TileRecord]
    checked: float  # time.monotonic() of the last check against the database


def content_uris(tileset: dict[str, Any]) -> set[str]:
    """Every content URI a tileset dict references."""
    out: set[str] = set()
    stack = [tileset["root"]]
    while stack:
        t = stack.pop()
        if "content" in t:
            out.add(t["content"]["uri"])
        stack.extend(t.get("children", []))
    return out


class DbTileSource:
    """tileset.json and tile glbs built on request by exporter/export.py (load_records, check_current,
    tileset_bytes, tile_glb: the bytes the file export writes), cached, for the DB mode's handler."""

    def __init__(self, url: str, lod: int | None = None, base_height: float = 0.0, cache_bytes: int = 256 << 20,
                 pool_size: int | None = None, revalidate_s: float = 1.0, acquire_timeout: float = 30.0) -> None:
        if lod not in (None, 1, 2, 3):
            raise ValueError(f"lod must be 1, 2, 3 or None, not {lod}")
        self.lod, self.base_height, self.revalidate_s = lod, base_height, revalidate_s
        self.pool = ReaderPool(url, pool_size or max(2, min(8, 2 * (os.cpu_count() or 1))), acquire_timeout)
        self.cache = ByteLru(cache_bytes)
        self._snap: _Snapshot | None = None
        self._snap_lock = threading.Lock()
        self._count_lock = threading.Lock()
        self.builds = 0  # glbs built from the database

    # -- database access: one REPEATABLE READ, READ ONLY transaction per call; psycopg errors -> DbUnavailable
    def _read(self, fn: Callable[[psycopg.Connection], Any]) -> Any:
        import psycopg

        for attempt in (1, 2):
            conn, reused = None, False
            try:
                with self.pool.connection() as (conn, reused), conn.transaction():
                    return fn(conn)
            except psycopg.OperationalError as e:
                # an idle pooled connection may have died with its server backend (restart, terminated):
                # one retry on a fresh connection
                if attempt == 1 and reused and conn is not None and conn.broken:
                    continue
                raise DbUnavailable(_one_line(e)) from e
            except psycopg.Error as e:
                raise DbUnavailable(_one_line(e)) from e
        raise AssertionError("unreachable")

    @staticmethod
    def _generation(conn: psycopg.Connection) -> tuple[Any, ...]:
        row = conn.execute(GENERATION_SQL).fetchone()
        return tuple(row) if row else ()

    def _load(self, old: _Snapshot | None) -> _Snapshot:
        from .export import check_current, load_records, tileset_bytes

        def read(conn: psycopg.Connection) -> _Snapshot:
            generation = self._generation(conn)
            if old is not None and generation == old.generation:
                return replace(old, checked=time.monotonic())
            records = load_records(conn)
            try:
                check_current(conn, records, self.lod)
                js = tileset_bytes(conn, records, self.lod)
            except (RuntimeError, ValueError) as e:  # no tiles, stale tiles, generalize not run
                raise NotReady(str(e)) from e
            by_uri = {r.content_uri: r for r in records if r.content_uri}
            uris = content_uris(json.loads(js))
            if not uris <= by_uri.keys():
                missing = sorted(uris - by_uri.keys())[:3]
                raise NotReady(f"tileset.json references content the tile tree lacks: {missing}")
            return _Snapshot(generation, make_payload(js, "application/json"), {u: by_uri[u] for u in uris},
                             time.monotonic())

        snap = self._read(read)
        if old is None or snap.generation != old.generation:
            self.cache.clear()
        return snap

    def snapshot(self) -> _Snapshot:
        """The current tile tree and tileset.json, checked against the database every ``revalidate_s``."""
        snap = self._snap
        if snap is not None and time.monotonic() - snap.checked < self.revalidate_s:
            return snap
        with self._snap_lock:  # one thread checks; the others wait for its answer
            snap = self._snap
            if snap is None or time.monotonic() - snap.checked >= self.revalidate_s:
                snap = self._snap = self._load(snap)
            return snap

    def _expire(self) -> None:
        with self._snap_lock:
            if self._snap is not None:
                self._snap = replace(self._snap, checked=float("-inf"))

    def tileset(self) -> Payload:
        return self.snapshot().tileset

    def content(self, uri: str) -> Payload | None:
        """The glb at ``uri`` (content/L/X/Y.glb), None when the tileset has no such content."""
        from .export import tile_glb

        for _ in range(3):
            snap = self.snapshot()
            rec = snap.by_uri.get(uri)
            if rec is None:
                return None

            def build(snap: _Snapshot = snap, rec: TileRecord = rec) -> Payload:
                def read(conn: psycopg.Connection) -> bytes:
                    if self._generation(conn) != snap.generation:
                        raise _Changed
                    return tile_glb(conn, rec, self.base_height, self.lod)[0]

                glb = self._read(read)
                with self._count_lock:
                    self.builds += 1
                return make_payload(glb, "model/gltf-binary")  # compressed outside the transaction

            try:
                return self.cache.get_or_build((snap.generation, uri), build)
            except _Changed:
                self._expire()
        raise DbUnavailable("the tiles kept changing while being read")

    def stats(self) -> dict[str, Any]:
        return {**self.cache.stats(), "builds": self.builds}

    def close(self) -> None:
        self.pool.close()


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0] if text else ''}"


class DbHandler(Handler):
    """Handler of the DB mode: ``/tiles/`` from a DbTileSource, everything else as in file mode."""

    source: DbTileSource  # set on the subclass made by make_db_server()

    def _serve(self, body: bool) -> None:
        try:
            path = unquote(urlsplit(self.path).path, errors="strict")
        except (UnicodeDecodeError, ValueError):
            self.send_error(HTTPStatus.BAD_REQUEST, "bad path")
            return
        if not path.startswith("/tiles/"):
            super()._serve(body)
            return
        try:
            address = tile_address(path[len("/tiles/"):])
        except BadPath:
            self.send_error(HTTPStatus.BAD_REQUEST, "bad tile address")
            return
        if address is None:
            self.send_error(HTTPStatus.NOT_FOUND)
            return
        try:
            payload = self.source.tileset() if address == TILESET else self.source.content(address)
        except NotReady as e:
            self.log_message("no current tileset in the database: %s", e)
            self._plain(HTTPStatus.SERVICE_UNAVAILABLE, f"no current tileset in the database: {e}", body)
            return
        except DbUnavailable as e:
            self.log_message("database unavailable: %s", e)  # the detail stays in the server's log
            self._plain(HTTPStatus.SERVICE_UNAVAILABLE, "database unavailable, retry later", body)
            return
        except Exception:  # a bug: its traceback goes to the server's stderr, never to the client
            traceback.print_exc()
            self._plain(HTTPStatus.INTERNAL_SERVER_ERROR, "internal error", body)
            return
        if payload is None:
            self.send_error(HTTPStatus.NOT_FOUND)
            return
        self._send_payload(payload, body)

    def _send_payload(self, p: Payload, body: bool) -> None:
        use_gzip = p.gzip is not None and accepts_gzip(self.headers.get("Accept-Encoding"))
        etag = p.gzip_etag if use_gzip else p.etag
        if etag_matches(self.headers.get("If-None-Match"), etag):
            self.send_response(HTTPStatus.NOT_MODIFIED)
            self._validators(etag)
            self.end_headers()
            return
        data = p.stored if use_gzip else p.body
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", p.media_type)
        self.send_header("Content-Length", str(len(data)))
        if use_gzip:
            self.send_header("Content-Encoding", "gzip")
        self._validators(etag)
        self.end_headers()
        if body:
            with contextlib.suppress(BrokenPipeError, ConnectionResetError):
                self.wfile.write(data)

    def _validators(self, etag: str) -> None:
        self.send_header("ETag", etag)
        self.send_header("Cache-Control", "no-cache")  # revalidate every time: the database may change
        self.send_header("Vary", "Accept-Encoding")

    def _plain(self, status: HTTPStatus, text: str, body: bool) -> None:
        data = (text.replace("\n", " ")[:500] + "\n").encode()
        self.send_response(status)
        self.send_header("Content-Type", "text/plain; charset=utf-8")
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        if status == HTTPStatus.SERVICE_UNAVAILABLE:
            self.send_header("Retry-After", "5")
        self.end_headers()
        if body:
            with contextlib.suppress(BrokenPipeError, ConnectionResetError):
                self.wfile.write(data)


class _DbServer(_Server):
    source: DbTileSource

    def server_close(self) -> None:
        super().server_close()
        self.source.close()


class _DbServer6(_DbServer):
    address_family = socket.AF_INET6


def make_db_server(url: str, host: str = "127.0.0.1", port: int = 8765, **source_options: Any) -> _DbServer:
    """A bound (not yet serving) DB-mode server reading through ``url`` (give it reader_url(...)); port 0 picks a
    free port. ``source_options`` go to DbTileSource (lod, base_height, cache_bytes, pool_size, revalidate_s).
    server.source is the DbTileSource; server_close() closes its connections."""
    source = DbTileSource(url, **source_options)
    handler = type("CitylodDbHandler", (DbHandler,), {"roots": Roots(None), "source": source})
    cls = _DbServer6 if ":" in host else _DbServer
    try:
        server = cls((host, port), handler)
    except BaseException:
        source.close()
        raise
    server.source = source
    return server


def serve_db(url: str, host: str = "127.0.0.1", port: int = 8765, **source_options: Any) -> None:
    """Serve the tileset straight from the database at ``url`` (the reader role's) and the viewer until
    SIGINT/SIGTERM. Refuses to start when the database cannot be read or holds no current tileset."""
    _check_cesium()
    try:
        server = make_db_server(url, host, port, **source_options)
    except OSError as e:
        sys.exit(f"citylod serve: cannot listen on {host}:{port}: {e}")
    try:
        tileset = server.source.tileset()
    except DbUnavailable as e:
        server.server_close()
        sys.exit(f"citylod serve --db: cannot read the database as {READER_ROLE}: {e}\n"
                 f"  run `make migrate` (migration 0011 creates the role), or set {READER_URL_ENV}")
    except NotReady as e:
        server.server_close()
        sys.exit(f"citylod serve --db: {e}")
    lod = source_options.get("lod")
    _run_forever(server, [
        f"tiles: straight from the database ({len(server.source.snapshot().by_uri):,} glb tiles, "
        f"{'LOD' + str(lod) if lod else 'every LOD'}, tileset.json {len(tileset.body):,} bytes)",
        f"cache: {server.source.cache.budget / 2**20:,.0f} MiB; pool: {server.source.pool.size} connections"])
