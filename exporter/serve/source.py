"""The tileset of the DB mode: tileset.json, its subtree files (implicit tiling; built with tileset.json from the
tile records, held in the snapshot) and each tile glb built on request by the exporter's own functions
(exporter/export.py load_records, check_current, tileset_files, tile_glb: the bytes the file export writes),
kept in a ByteLru.

The database's *generation* (the latest successful ``meta.pipeline_run`` and the dataset's sha256) is re-read
at most every ``revalidate_s`` seconds; a new one drops the cache, so a pipeline re-run is picked up without a
restart. A tile is built in the same transaction that checks the generation it was looked up in. ``peek`` is the
event loop's non-blocking path (a fresh snapshot and a cached tile); everything else blocks and runs on worker
threads.
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from dataclasses import dataclass, replace
from typing import Any

import psycopg

from core.tiles3d import content_uris
from exporter.export import TILESET_JSON, check_current, load_records, tile_glb, tileset_files
from exporter.serve.cache import ByteLru
from exporter.serve.paths import TILESET
from exporter.serve.payload import Payload, make_payload
from exporter.serve.reader import DbUnavailable, Reader
from exporter.stream import COMPACT, StreamOptions
from exporter.tileset import TileRecord

GENERATION_SQL = """SELECT (SELECT max(run_id) FROM meta.pipeline_run WHERE status = 'ok'),
                           (SELECT source_sha256 FROM meta.dataset)"""


log = logging.getLogger("citylod.serve")


class NotReady(Exception):
    """The database holds no current tileset: no tiles, stale tiles, generalize not run (answered with 503)."""


class _Changed(Exception):
    """The data changed while a tile was being built: look the tile up again in the new tree."""


@dataclass(frozen=True)
class Snapshot:
    generation: tuple[Any, ...]
    tileset: Payload
    subtrees: dict[str, Payload]  # by URI (implicit tiling), built with tileset.json
    by_uri: dict[str, TileRecord]
    root_region: tuple[float, ...]
    checked: float  # time.monotonic() of the last check against the database


def _generation(conn: psycopg.Connection) -> tuple[Any, ...]:
    row = conn.execute(GENERATION_SQL).fetchone()
    return tuple(row) if row else ()


class DbTileSource:
    """tileset.json and tile glbs from the database at ``url`` (the reader role's), cached."""

    def __init__(
        self,
        url: str,
        lod: int | None = None,
        base_height: float = 0.0,
        cache_bytes: int = 256 << 20,
        stream: StreamOptions = COMPACT,
        pool_size: int | None = None,
        revalidate_s: float = 1.0,
        acquire_timeout: float = 30.0,
    ) -> None:
        if lod not in (None, 1, 2, 3):
            raise ValueError(f"lod must be 1, 2, 3 or None, not {lod}")
        self.lod, self.base_height, self.revalidate_s, self.stream = lod, base_height, revalidate_s, stream
        self.reader = Reader(url, pool_size or max(2, min(8, 2 * (os.cpu_count() or 1))), acquire_timeout)
        self.cache = ByteLru(cache_bytes)
        self._snap: Snapshot | None = None
        self._snap_lock = threading.Lock()
        self._count_lock = threading.Lock()
        self.builds = 0  # glbs built from the database

    def _load(self, old: Snapshot | None) -> Snapshot:
        def read(conn: psycopg.Connection) -> Snapshot:
            generation = _generation(conn)
            if old is not None and generation == old.generation:
                return replace(old, checked=time.monotonic())
            records = load_records(conn)
            try:
                check_current(conn, records, self.lod)
                files = tileset_files(conn, records, self.lod, self.stream)
            except (RuntimeError, ValueError) as e:  # no tiles, stale tiles, generalize not run
                raise NotReady(str(e)) from e
            js = files.pop(TILESET_JSON)
            by_uri = {r.content_uri: r for r in records if r.content_uri}
            uris = set(content_uris(json.loads(js), files.__getitem__))
            if not uris <= by_uri.keys():
                missing = sorted(uris - by_uri.keys())[:3]
                raise NotReady(f"tileset.json references content the tile tree lacks: {missing}")
            root_region = next(r.region for r in records if r.level == 0)
            return Snapshot(
                generation,
                make_payload(js, "application/json"),
                {u: make_payload(b, "application/octet-stream") for u, b in files.items()},
                {u: by_uri[u] for u in uris},
                root_region,
                time.monotonic(),
            )

        snap = self.reader.read(read)
        if old is None or snap.generation != old.generation:
            self.cache.clear()
        return snap

    def snapshot(self) -> Snapshot:
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

    def peek(self, address: str) -> Payload | None:
        """Without blocking: the answer for ``address`` when the snapshot is fresh and the tile cached, else None
        (then ``get`` on a worker thread)."""
        snap = self._snap
        if snap is None or time.monotonic() - snap.checked >= self.revalidate_s:
            return None
        if address == TILESET:
            return snap.tileset
        if address in snap.subtrees:
            return snap.subtrees[address]
        return self.cache.peek((snap.generation, address)) if address in snap.by_uri else None

    def get(self, address: str) -> Payload | None:
        """tileset.json, a subtree file or the glb at ``address`` (content/L/X/Y.glb); None when the tileset has
        no such file. Raises NotReady or DbUnavailable."""
        if address == TILESET:
            return self.tileset()
        if address.startswith("subtrees/"):
            return self.snapshot().subtrees.get(address)
        return self.content(address)

    def tileset(self) -> Payload:
        return self.snapshot().tileset

    def content(self, uri: str) -> Payload | None:
        for _ in range(3):
            snap = self.snapshot()
            rec = snap.by_uri.get(uri)
            if rec is None:
                return None

            def build(snap: Snapshot = snap, rec: TileRecord = rec) -> Payload:
                def read(conn: psycopg.Connection) -> bytes:
                    if _generation(conn) != snap.generation:
                        raise _Changed
                    try:
                        return tile_glb(conn, rec, self.base_height, self.lod, self.stream, snap.root_region)[0]
                    except psycopg.Error:
                        raise
                    except Exception as e:  # noqa: BLE001 - a TRUNCATE is not MVCC-safe: the tables emptied under us
                        log.warning("tile %s could not be built", uri, exc_info=True)
                        raise NotReady(
                            f"the tables changed while tile {uri} was being built ({type(e).__name__}): "
                            "a stage is rebuilding them; serve --db without --live streams the last "
                            "published generation meanwhile"
                        ) from e

                glb = self.reader.read(read)
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
        self.reader.close()
