"""Database connections. One DSN: DATABASE_URL, else the local cluster (core/cluster.py)."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import psycopg
from psycopg import sql

from core import cluster
from core.settings import Settings


def connect(url: str | None = None, autocommit: bool = False, settings: Settings | None = None) -> psycopg.Connection:
    """Connect to the city database, starting the local cluster first when no DATABASE_URL is set."""
    dsn = url or cluster.ensure(settings)
    conn = psycopg.connect(dsn, autocommit=autocommit)
    # UTC timestamps; no JIT: its compile time (~0.25 s a statement) dominates the short set-based statements
    # of the stages, and PostGIS functions are not inlined anyway.
    conn.execute("SET TIME ZONE 'UTC'")
    conn.execute("SET jit = off")
    if not autocommit:
        conn.commit()
    return conn


def working_srid(conn: psycopg.Connection) -> int:
    """The dataset's metric working CRS (meta.working_srid); a clear error before anything was ingested."""
    row = conn.execute("SELECT meta.working_srid()").fetchone()
    if not row or row[0] is None:
        raise RuntimeError("no dataset loaded: run the ingest stage first (make ingest)")
    return int(row[0])


#: a run that wrote fewer rows than this share of a table's leaves its statistics to autovacuum (analyze)
SMALL_WRITE = 0.1


def analyze(cur: psycopg.Cursor, table: str, written: int | None = None) -> bool:
    """ANALYZE ``table`` ("schema.name") for the plans of the statements that read it next, unless ``written``
    (the rows the caller wrote to it; None: a full run, always) is under SMALL_WRITE of the rows its statistics
    count: those still hold, and autovacuum analyzes the table as its rows drift. An ANALYZE samples 30,000
    rows, 0.1 to 0.4 s a table of meshes on the benchmark extract, which an update of a few buildings paid for
    every table of every stage. Returns whether it ran."""
    if written is not None:
        row = cur.execute("SELECT reltuples FROM pg_class WHERE oid = %s::regclass", (table,)).fetchone()
        if row is not None and row[0] > 0 and written < SMALL_WRITE * row[0]:
            return False
    cur.execute(sql.SQL("ANALYZE {}").format(sql.Identifier(*table.split("."))))
    return True


T = TypeVar("T")
R = TypeVar("R")


def shares(items: list[T], n: int) -> list[list[T]]:
    """``items`` dealt round into at most ``n`` non-empty shares: even ones when the items come largest first
    (one statement per share and connection, with thread_map)."""
    return [s for s in (items[i::n] for i in range(n)) if s]


@contextlib.contextmanager
def thread_map(
    url: str, fn: Callable[[psycopg.Connection, T], R], items: Iterable[T], workers: int
) -> Iterator[Iterator[R]]:
    """``fn(conn, item)`` for every item, in order, by ``workers`` threads that each open a connection of their
    own (the SQL runs in separate backends, and numpy releases the GIL); the threads stop and the connections
    close when the block ends, consumed or not. The work starts at once, so the block may do something else
    meanwhile (generalize reads its decimation digests beside the footprint step); a block that fails cancels the
    statements still running, which it would otherwise wait for."""
    local = threading.local()
    conns: list[psycopg.Connection] = []

    def one(item: T) -> R:
        if not hasattr(local, "conn"):
            local.conn = connect(url)
            conns.append(local.conn)
        return fn(local.conn, item)

    pool = ThreadPoolExecutor(max_workers=workers)
    try:
        yield pool.map(one, items)
    except BaseException:
        for c in list(conns):
            with contextlib.suppress(Exception):
                c.cancel_safe()
        raise
    finally:
        pool.shutdown(cancel_futures=True)
        for c in conns:
            c.close()
