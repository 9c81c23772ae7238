"""The soak client: a steady stream of tile requests (200 per second by default) against a running server while
something else happens to the database (a full rebuild, an export), counting what went wrong.

Open loop: requests are issued on a fixed schedule whatever the server's pace (a slow answer does not slow the
client down, as with many independent viewers), from ``threads`` keep-alive connections. The paths are the
tileset's own: tileset.json and every file it names (subtrees, glbs), re-read from the server every few seconds
so that a new generation's files are asked for too. Every 200 is checked against its strong ETag (the sha256 of
the body, exporter/serve/payload.py) and every third request revalidates with If-None-Match.

``python -m tests.support.soak --url http://127.0.0.1:8765/ --seconds 60`` soaks a server already running.
"""

from __future__ import annotations

import argparse
import gzip
import hashlib
import http.client
import json
import queue
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from urllib.parse import urlsplit

import numpy as np

from core.tiles3d import content_uris

#: The issue's load: 200 requests per second.
RATE = 200.0
REFRESH_S = 2.0  # how often the client re-reads tileset.json for the live generation's paths


@dataclass
class SoakResult:
    seconds: float = 0.0
    statuses: Counter[int] = field(default_factory=Counter)
    latencies_ms: list[float] = field(default_factory=list)
    late: int = 0  # requests issued more than 50 ms after their slot (the client fell behind)
    bad_etags: int = 0  # 200 whose body is not what its ETag says
    errors: list[str] = field(default_factory=list)  # transport errors and 5xx, first lines
    generations: int = 0  # distinct tileset.json bodies seen

    @property
    def requests(self) -> int:
        return sum(self.statuses.values())

    @property
    def failures(self) -> int:
        """5xx (503 included) and transport errors: what the soak must not see."""
        return sum(n for s, n in self.statuses.items() if s >= 500 or s < 0)

    def as_dict(self) -> dict[str, object]:
        lat = np.array(self.latencies_ms or [0.0])
        return {"seconds": round(self.seconds, 1), "requests": self.requests,
                "rate": round(self.requests / max(self.seconds, 1e-9), 1),
                "statuses": {str(k): v for k, v in sorted(self.statuses.items())},
                "failures": self.failures, "bad_etags": self.bad_etags, "late": self.late,
                "generations": self.generations,
                "p50_ms": round(float(np.percentile(lat, 50)), 1), "p99_ms": round(float(np.percentile(lat, 99)), 1),
                "max_ms": round(float(lat.max()), 1), "errors": self.errors[:5]}


class _Conn:
    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port
        self.c = http.client.HTTPConnection(host, port, timeout=30)

    def get(self, path: str, headers: dict[str, str]) -> tuple[int, dict[str, str], bytes]:
        for attempt in (1, 2):
            try:
                self.c.request("GET", path, headers=headers)
                r = self.c.getresponse()
                return r.status, {k.lower(): v for k, v in r.getheaders()}, r.read()
            except (http.client.RemoteDisconnected, ConnectionResetError, BrokenPipeError):
                self.c.close()  # a keep-alive connection the server closed: once more on a new one
                if attempt == 2:
                    raise
        raise AssertionError("unreachable")


def soak(base: str, stop: threading.Event, rate: float = RATE, threads: int = 16,
         max_seconds: float = 3600.0) -> SoakResult:
    """Request the tileset at ``base`` (http://host:port/) at ``rate`` per second until ``stop`` is set."""
    u = urlsplit(base)
    host, port = u.hostname or "127.0.0.1", u.port or 80
    res = SoakResult()
    lock = threading.Lock()
    paths: list[str] = ["tileset.json"]
    seen: set[str] = set()
    etags: dict[str, str] = {}
    jobs: queue.Queue[tuple[int, str] | None] = queue.Queue()

    def record(status: int, ms: float, err: str | None = None) -> None:
        with lock:
            res.statuses[status] += 1
            res.latencies_ms.append(ms)
            if err and len(res.errors) < 50:
                res.errors.append(err)

    def refresh(conn: _Conn) -> None:
        status, _, body = conn.get("/tiles/tileset.json", {"Accept-Encoding": "identity"})
        if status != 200:
            return
        digest = hashlib.sha256(body).hexdigest()

        def fetch(uri: str) -> bytes:
            s, _, b = conn.get(f"/tiles/{uri}", {"Accept-Encoding": "identity"})
            if s != 200:
                raise KeyError(uri)
            return b

        try:
            uris = content_uris(json.loads(body), fetch)
        except (KeyError, ValueError):
            return  # the generation changed between the files: the next refresh
        with lock:
            if digest not in seen:
                seen.add(digest)
                res.generations += 1
            paths[:] = ["tileset.json", *uris]

    def worker() -> None:
        conn = _Conn(host, port)
        while (job := jobs.get()) is not None:
            n, path = job
            headers = {"Accept-Encoding": "gzip"}
            if n % 3 == 0 and path in etags:
                headers["If-None-Match"] = etags[path]
            t0 = time.perf_counter()
            try:
                status, hdrs, body = conn.get(f"/tiles/{path}", headers)
            except OSError as e:
                record(-1, (time.perf_counter() - t0) * 1e3, f"{path}: {type(e).__name__}: {e}")
                conn = _Conn(host, port)
                continue
            ms = (time.perf_counter() - t0) * 1e3
            record(status, ms, f"{path}: {status} {body[:120]!r}" if status >= 500 else None)
            if status == 200 and "etag" in hdrs:
                etags[path] = hdrs["etag"]
                raw = gzip.decompress(body) if hdrs.get("content-encoding") == "gzip" else body
                if hashlib.sha256(raw).hexdigest()[:32] != hdrs["etag"].strip('"').removesuffix("-gzip"):
                    with lock:
                        res.bad_etags += 1

    pool = [threading.Thread(target=worker, daemon=True) for _ in range(threads)]
    for t in pool:
        t.start()
    refresh(_Conn(host, port))

    def refresher() -> None:  # on its own thread: reading every subtree must not hold up the schedule
        conn = _Conn(host, port)
        while not stop.wait(REFRESH_S):
            try:
                refresh(conn)
            except OSError:
                conn = _Conn(host, port)

    threading.Thread(target=refresher, daemon=True).start()
    rng = np.random.default_rng(0)
    t_start = time.perf_counter()
    n = 0
    while not stop.is_set() and time.perf_counter() - t_start < max_seconds:
        slot = t_start + n / rate
        now = time.perf_counter()
        if slot > now:
            time.sleep(slot - now)
        elif now - slot > 0.05:
            res.late += 1
        with lock:
            path = paths[int(rng.integers(len(paths)))]
        jobs.put((n, path))
        n += 1
    for _ in pool:
        jobs.put(None)
    for t in pool:
        t.join(timeout=60)
    res.seconds = time.perf_counter() - t_start
    return res


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tests.support.soak", description=__doc__.splitlines()[0])
    p.add_argument("--url", required=True, help="the server's base URL (http://host:port/)")
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--rate", type=float, default=RATE)
    a = p.parse_args(argv)
    stop = threading.Event()
    threading.Timer(a.seconds, stop.set).start()
    print(json.dumps(soak(a.url, stop, a.rate).as_dict(), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
