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
        return {
            "seconds": round(self.seconds, 1),
            "requests": self.requests,
            "rate": round(self.requests / max(self.seconds, 1e-9), 1),
            "statuses": {str(k): v for k, v in sorted(self.statuses.items())},
            "failures": self.failures,
            "bad_etags": self.bad_etags,
            "late": self.late,
            "generations": self.generations,
            "p50_ms": round(float(np.percentile(lat, 50)), 1),
            "p99_ms": round(float(np.percentile(lat, 99)), 1),
            "max_ms": round(float(lat.max()), 1),
            "errors": self.errors[:5],
        }


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


class _Soak:
    """One soak: the paths the tileset names now, the ETags seen, the jobs of the request threads."""

    def __init__(self, base: str) -> None:
        u = urlsplit(base)
        self.host, self.port = u.hostname or "127.0.0.1", u.port or 80
        self.res = SoakResult()
        self.lock = threading.Lock()
        self.paths: list[str] = ["tileset.json"]
        self.seen: set[str] = set()
        self.etags: dict[str, str] = {}
        self.jobs: queue.Queue[tuple[int, str] | None] = queue.Queue()

    def conn(self) -> _Conn:
        return _Conn(self.host, self.port)

    def record(self, status: int, ms: float, err: str | None = None) -> None:
        with self.lock:
            self.res.statuses[status] += 1
            self.res.latencies_ms.append(ms)
            if err and len(self.res.errors) < 50:
                self.res.errors.append(err)

    def refresh(self, conn: _Conn) -> None:
        """The paths of the generation served now (tileset.json and everything it names, subtrees included)."""
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
        with self.lock:
            if digest not in self.seen:
                self.seen.add(digest)
                self.res.generations += 1
            self.paths[:] = ["tileset.json", *uris]

    def worker(self) -> None:
        """Requests the jobs' paths (every third one conditional on its ETag) and checks every body's ETag."""
        conn = self.conn()
        while (job := self.jobs.get()) is not None:
            n, path = job
            headers = {"Accept-Encoding": "gzip"}
            if n % 3 == 0 and path in self.etags:
                headers["If-None-Match"] = self.etags[path]
            t0 = time.perf_counter()
            try:
                status, hdrs, body = conn.get(f"/tiles/{path}", headers)
            except OSError as e:
                self.record(-1, (time.perf_counter() - t0) * 1e3, f"{path}: {type(e).__name__}: {e}")
                conn = self.conn()
                continue
            ms = (time.perf_counter() - t0) * 1e3
            self.record(status, ms, f"{path}: {status} {body[:120]!r}" if status >= 500 else None)
            if status == 200 and "etag" in hdrs:
                self.check_etag(path, hdrs, body)

    def check_etag(self, path: str, hdrs: dict[str, str], body: bytes) -> None:
        self.etags[path] = hdrs["etag"]
        raw = gzip.decompress(body) if hdrs.get("content-encoding") == "gzip" else body
        if hashlib.sha256(raw).hexdigest()[:32] != hdrs["etag"].strip('"').removesuffix("-gzip"):
            with self.lock:
                self.res.bad_etags += 1

    def refresher(self, stop: threading.Event) -> None:
        """On its own thread: reading every subtree must not hold up the schedule."""
        conn = self.conn()
        while not stop.wait(REFRESH_S):
            try:
                self.refresh(conn)
            except OSError:
                conn = self.conn()

    def schedule(self, stop: threading.Event, rate: float, max_seconds: float) -> float:
        """A job every 1 / ``rate`` s on the clock (a slot missed by 50 ms counts as late), a random path of the
        served generation each; returns when it started (perf_counter)."""
        rng = np.random.default_rng(0)
        t_start = time.perf_counter()
        n = 0
        while not stop.is_set() and time.perf_counter() - t_start < max_seconds:
            slot = t_start + n / rate
            now = time.perf_counter()
            if slot > now:
                time.sleep(slot - now)
            elif now - slot > 0.05:
                self.res.late += 1
            with self.lock:
                path = self.paths[int(rng.integers(len(self.paths)))]
            self.jobs.put((n, path))
            n += 1
        return t_start


def soak(
    base: str, stop: threading.Event, rate: float = RATE, threads: int = 16, max_seconds: float = 3600.0
) -> SoakResult:
    """Request the tileset at ``base`` (http://host:port/) at ``rate`` per second until ``stop`` is set."""
    s = _Soak(base)
    pool = [threading.Thread(target=s.worker, daemon=True) for _ in range(threads)]
    for t in pool:
        t.start()
    s.refresh(s.conn())
    threading.Thread(target=s.refresher, args=(stop,), daemon=True).start()
    t_start = s.schedule(stop, rate, max_seconds)
    for _ in pool:
        s.jobs.put(None)
    for t in pool:
        t.join(timeout=60)
    s.res.seconds = time.perf_counter() - t_start
    return s.res


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
