"""The tileset of ``serve --db``: the live generation of a tileset the export published (pub.*, exporter/publish.py).

The server reads nothing but pub.*, which no stage locks or empties: while ingest ... textures rebuild the stage
tables, it streams the generation the last export published, whole, and switches to the next one when an
export commits it (checked at most every ``revalidate_s``). A file is looked up by path in the generation's
listing (held in memory: a path and a sha256 per file) and its bytes are cached by sha256, so a tile that a new
generation did not change stays cached and keeps its ETag. A blob that retention deleted after the listing was
read (the generation is no longer live) sends the lookup to the new listing.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, replace
from pathlib import PurePosixPath
from typing import Any

import psycopg

from exporter.serve.cache import ByteLru
from exporter.serve.files import media_type
from exporter.serve.payload import Payload, make_payload
from exporter.serve.reader import DbUnavailable, Reader
from exporter.serve.source import NotReady

_LIVE = "SELECT max(generation) FROM pub.generation WHERE tileset = %s"
_LISTING = "SELECT path, sha256 FROM pub.file WHERE generation = %s"
_BODY = "SELECT body FROM pub.blob WHERE sha256 = %s"


class _Gone(Exception):
    """The blob was deleted with its generation: read the live listing again."""


@dataclass(frozen=True)
class Listing:
    generation: int
    files: dict[str, bytes]  # path -> sha256
    checked: float  # time.monotonic() of the last check against the database


class PublishedSource:
    """The files of the live generation of tileset ``name``, from the database at ``url`` (the reader role's)."""

    def __init__(
        self,
        url: str,
        name: str,
        cache_bytes: int = 256 << 20,
        pool_size: int | None = None,
        revalidate_s: float = 1.0,
        acquire_timeout: float = 30.0,
    ) -> None:
        self.name, self.revalidate_s = name, revalidate_s
        self.reader = Reader(url, pool_size or 4, acquire_timeout)
        self.cache = ByteLru(cache_bytes)
        self._listing: Listing | None = None
        self._lock = threading.Lock()
        self._count_lock = threading.Lock()
        self.reads = 0  # blobs read from the database

    def _load(self, old: Listing | None) -> Listing:
        def read(conn: psycopg.Connection) -> Listing:
            row = conn.execute(_LIVE, (self.name,)).fetchone()
            assert row is not None  # an aggregate: one row (NULL when nothing is published)
            (generation,) = row
            if generation is None:
                raise NotReady(
                    f"no tileset named {self.name!r} is published in the database: export it first "
                    f"(make export OUT=build/tiles/{self.name}, or python -m etl export --publish "
                    f"{self.name})"
                )
            if old is not None and generation == old.generation:
                return replace(old, checked=time.monotonic())
            files = {path: bytes(sha) for path, sha in conn.execute(_LISTING, (generation,))}
            return Listing(generation, files, time.monotonic())

        return self.reader.read(read)

    def listing(self) -> Listing:
        """The live generation's listing, checked against the database every ``revalidate_s``."""
        cur = self._listing
        if cur is not None and time.monotonic() - cur.checked < self.revalidate_s:
            return cur
        with self._lock:  # one thread checks; the others wait for its answer
            cur = self._listing
            if cur is None or time.monotonic() - cur.checked >= self.revalidate_s:
                cur = self._listing = self._load(cur)
            return cur

    def _expire(self) -> None:
        with self._lock:
            if self._listing is not None:
                self._listing = replace(self._listing, checked=float("-inf"))

    def peek(self, address: str) -> Payload | None:
        """Without blocking: the cached answer when the listing is fresh, else None (then ``get``)."""
        cur = self._listing
        if cur is None or time.monotonic() - cur.checked >= self.revalidate_s:
            return None
        sha = cur.files.get(address)
        return None if sha is None else self.cache.peek(sha)

    def get(self, address: str) -> Payload | None:
        """The file at ``address`` in the live generation, or None when it has none. Raises NotReady (nothing
        published under this name) or DbUnavailable."""
        for _ in range(3):
            sha = self.listing().files.get(address)
            if sha is None:
                return None

            def build(sha: bytes = sha) -> Payload:
                def read(conn: psycopg.Connection) -> bytes:
                    row = conn.execute(_BODY, (sha,)).fetchone()
                    if row is None:
                        raise _Gone
                    return bytes(row[0])

                body = self.reader.read(read)
                with self._count_lock:
                    self.reads += 1
                return make_payload(body, media_type(PurePosixPath(address)))

            try:
                return self.cache.get_or_build(sha, build)
            except _Gone:
                self._expire()
        raise DbUnavailable("the published tileset kept changing while being read")

    def tileset(self) -> Payload:
        p = self.get("tileset.json")
        if p is None:
            raise NotReady(f"the published tileset {self.name!r} has no tileset.json")
        return p

    def stats(self) -> dict[str, Any]:
        return {**self.cache.stats(), "reads": self.reads}

    def close(self) -> None:
        self.reader.close()
