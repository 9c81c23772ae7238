"""``python -m benchmarks.serve_bench``: throughput and latency of ``python -m etl serve`` under concurrent clients.

``bench_server(url_base, paths, clients=64, rounds=5)`` is the reusable part (``make bench`` calls it): each client
is a thread with one keep-alive HTTP/1.1 connection (as a browser keeps a few per host), all start together, and
every request's latency is recorded. Two shapes:

* warm (default): every client GETs every path ``rounds`` times, each client starting at a different offset so
  they do not march in lockstep; after the first round everything is in the server's cache;
* ``spread=True``: every path is fetched exactly once, the clients taking paths from one queue; on a fresh
  DB-mode server that is the cold cache: each glb is built from the database on its first request.

``measure_db(database_url)`` runs both on a fresh ``python -m etl serve --db --live`` in its own process (so the client
threads do not share the server's GIL) and returns ``{"cold": {...}, "warm": {...}}``. The clients send
``Accept-Encoding: gzip`` as browsers do. Figures are wall clock on loopback; the clients run in Python on the
same machine, so on a small machine they are a lower bound of what the server can do. Tests never assert them.
"""

from __future__ import annotations

import argparse
import http.client
import json
import math
import os
import queue
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any
from urllib.parse import urlsplit

from core.tiles3d import tileset_files
from tests.support.servers import spawned

BROWSER_HEADERS = {"Accept-Encoding": "gzip, deflate, br"}


def _percentile(sorted_values: Sequence[float], q: float) -> float:
    """Nearest-rank percentile (q in 0..1) of already sorted values."""
    if not sorted_values:
        return float("nan")
    return sorted_values[min(len(sorted_values) - 1, max(0, math.ceil(q * len(sorted_values)) - 1))]


def bench_server(
    url_base: str,
    paths: Sequence[str],
    clients: int = 64,
    rounds: int = 5,
    spread: bool = False,
    headers: dict[str, str] | None = None,
    timeout: float = 120.0,
) -> dict[str, Any]:
    """Load ``url_base`` (``http://host:port/``) with ``clients`` concurrent keep-alive clients GETting ``paths``
    (absolute paths such as ``/tiles/content/3/1/2.glb``). Returns tiles_per_s (responses per second of wall
    clock, all clients together), p50_ms, p99_ms, max_ms, requests, errors (non-200 or failed requests), bytes
    (as sent, i.e. compressed when gzip was negotiated), seconds, clients."""
    if not paths:
        raise ValueError("no paths to fetch")
    u = urlsplit(url_base)
    host, port = u.hostname or "127.0.0.1", u.port or 80
    hdrs = dict(BROWSER_HEADERS if headers is None else headers)
    work: queue.SimpleQueue[str] = queue.SimpleQueue()
    if spread:
        for p in paths:
            work.put(p)
    latencies: list[list[float]] = [[] for _ in range(clients)]
    errors = [0] * clients
    nbytes = [0] * clients
    start = threading.Barrier(clients + 1)

    def client(i: int) -> None:
        conn = http.client.HTTPConnection(host, port, timeout=timeout)
        if spread:
            mine: Iterator[str] = iter(lambda: _next(work), None)  # type: ignore[arg-type]
        else:
            k = (i * len(paths)) // clients
            mine = iter([p for _ in range(rounds) for p in (list(paths[k:]) + list(paths[:k]))])
        lat = latencies[i]
        try:
            start.wait()
            for path in mine:
                t0 = time.perf_counter()
                try:
                    conn.request("GET", path, headers=hdrs)
                    r = conn.getresponse()
                    body = r.read()
                    if r.status != 200:
                        errors[i] += 1
                    if r.getheader("Connection", "").lower() == "close":
                        conn.close()
                except (OSError, http.client.HTTPException):
                    errors[i] += 1
                    conn.close()
                    body = b""
                lat.append(time.perf_counter() - t0)
                nbytes[i] += len(body)
        finally:
            conn.close()

    threads = [threading.Thread(target=client, args=(i,), daemon=True) for i in range(clients)]
    for t in threads:
        t.start()
    start.wait()
    t0 = time.perf_counter()
    for t in threads:
        t.join()
    seconds = time.perf_counter() - t0
    every = sorted(x for lat in latencies for x in lat)
    return {
        "tiles_per_s": round(len(every) / seconds, 1) if seconds > 0 else float("inf"),
        "p50_ms": round(_percentile(every, 0.50) * 1e3, 2),
        "p99_ms": round(_percentile(every, 0.99) * 1e3, 2),
        "max_ms": round(every[-1] * 1e3, 2) if every else float("nan"),
        "requests": len(every),
        "errors": sum(errors),
        "bytes": sum(nbytes),
        "seconds": round(seconds, 3),
        "clients": clients,
    }


def _next(work: queue.SimpleQueue[str]) -> str | None:
    try:
        return work.get_nowait()
    except queue.Empty:
        return None


def tile_paths(url_base: str, tileset: str = "/tiles/tileset.json") -> list[str]:
    """``tileset`` and the absolute path of every file it needs (content, and an implicit tileset's subtrees;
    relative URIs resolved against it)."""
    u = urlsplit(url_base)
    base = tileset.rsplit("/", 1)[0]

    def get(path: str) -> bytes:
        conn = http.client.HTTPConnection(u.hostname or "127.0.0.1", u.port or 80, timeout=120)
        try:
            conn.request("GET", path)
            r = conn.getresponse()
            body = r.read()
            if r.status != 200:
                raise RuntimeError(f"GET {path}: {r.status} {body[:200]!r}")
            return body
        finally:
            conn.close()

    files = tileset_files(json.loads(get(tileset)), lambda uri: get(f"{base}/{uri}"))
    return [tileset] + [f"{base}/{uri}" for uri in files]


@contextmanager
def served_db(database_url: str | None = None, extra_args: Sequence[str] = (), timeout: float = 120.0) -> Iterator[str]:
    """A fresh ``python -m etl serve --db --live --port 0`` subprocess (DATABASE_URL = ``database_url`` when given);
    yields its base URL; terminated after."""
    env = dict(os.environ)
    if database_url:
        env["DATABASE_URL"] = database_url
    with spawned(["etl", "serve", "--db", "--live", "--port", "0", *extra_args], env, timeout) as (base, _, _err):
        yield base


def measure_db(
    database_url: str | None = None, clients: int = 64, rounds: int = 5, extra_args: Sequence[str] = ()
) -> dict[str, Any]:
    """Cold then warm figures of ``serve --db`` on the database at ``database_url`` (else DATABASE_URL / the local
    cluster): a fresh server; cold = every glb fetched once (built from the database), warm = every client
    fetching every path ``rounds`` times from the cache."""
    with served_db(database_url, extra_args) as base:
        paths = tile_paths(base)  # tileset.json is built here, outside the cold figure
        cold = bench_server(base, paths[1:], clients=clients, spread=True)
        warm = bench_server(base, paths, clients=clients, rounds=rounds)
    return {"tiles": len(paths) - 1, "cold": cold, "warm": warm}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.serve_bench",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--url", help="benchmark this running server (http://host:port/) instead of starting serve --db")
    p.add_argument("--database-url", help="DATABASE_URL for the serve --db it starts (default: the environment's)")
    p.add_argument("--lod", type=int, choices=(1, 2, 3), help="serve --db --lod")
    p.add_argument("--clients", type=int, default=64)
    p.add_argument("--rounds", type=int, default=5)
    args = p.parse_args(argv)
    if args.url:
        paths = tile_paths(args.url)
        res: dict[str, Any] = {
            "tiles": len(paths) - 1,
            "warm": bench_server(args.url, paths, clients=args.clients, rounds=args.rounds),
        }
    else:
        extra = ["--lod", str(args.lod)] if args.lod else []
        res = measure_db(args.database_url, clients=args.clients, rounds=args.rounds, extra_args=extra)
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
