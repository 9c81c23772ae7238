"""How the DB mode reads the database: as the read-only role ``citylod_reader`` (migration 0011), through a
psycopg_pool ConnectionPool, each read one REPEATABLE READ, READ ONLY transaction, any failure DbUnavailable.

psycopg_pool answers a database it cannot reach by retrying in the background while ``getconn`` waits for up
to its timeout, which would hold every request of a stopped database for 30 s. So the pool is only used while
the database is known to be reachable. At start-up, and whenever a pooled connection turns out dead (a restart,
a dropped database, a terminated backend), one direct connection attempt at a time decides: the database is
back (dead idle connections are checked out of the pool, the read goes on), or it is not, and every read is
DbUnavailable at once until the next attempt, at most one per PROBE_INTERVAL_S.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import TypeVar

import psycopg
from psycopg.conninfo import conninfo_to_dict, make_conninfo
from psycopg_pool import ConnectionPool, PoolTimeout

#: The read-only role of migration 0011 that the server connects as.
READER_ROLE = "citylod_reader"
#: Environment variable with the reader's full connection URL (else derived from the pipeline's URL).
READER_URL_ENV = "CITYLOD_READER_URL"
#: Session settings of every server connection: read-only even if the role were not, a bound on each query,
#: no JIT (its compile time dominates short statements), UTC.
#: lock_timeout: a read that would wait behind a stage's lock (a TRUNCATE, a quadtree rebuild: held until the
#: stage commits, minutes) gives up after 100 ms and is answered 503 at once instead of hanging.
READER_SESSION = {
    "default_transaction_read_only": "on",
    "statement_timeout": "30s",
    "lock_timeout": "100ms",
    "jit": "off",
    "TimeZone": "UTC",
}
#: While the database is unreachable, at most one connection attempt per this many seconds; the requests in
#: between are answered at once with the last attempt's error.
PROBE_INTERVAL_S = 1.0
#: How long the pool keeps re-making a connection that died before giving up the slot (it grows again on the
#: next request): short, so that after an outage the pool does not wait out a long back-off.
RECONNECT_TIMEOUT_S = 5.0

T = TypeVar("T")


class DbUnavailable(Exception):
    """The database cannot be reached or answered with an error (answered with 503)."""


class Busy(DbUnavailable):
    """A stage holds a lock on the tables the answer reads (lock_timeout): 503, retry later."""


def reader_url(url: str, environ: Mapping[str, str] | None = None) -> str:
    """The URL the server connects with: CITYLOD_READER_URL when set, else ``url`` (DATABASE_URL or the local
    cluster's, as every stage gets it from core.cluster.ensure) with the user replaced by citylod_reader and no
    password (the local cluster trusts its socket; elsewhere libpq's PGPASSWORD/.pgpass or CITYLOD_READER_URL)."""
    environ = os.environ if environ is None else environ
    if environ.get(READER_URL_ENV):
        return environ[READER_URL_ENV]
    params = {k: v for k, v in conninfo_to_dict(url).items() if k != "password"}
    params["user"] = READER_ROLE
    return make_conninfo("", **params)


def one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0] if text else ''}"


def _conninfo(url: str) -> str:
    params = conninfo_to_dict(url)
    options = " ".join(f"-c {k}={v}" for k, v in READER_SESSION.items())
    params["options"] = f"{params.get('options') or ''} {options}".strip()
    params.setdefault("connect_timeout", "5")
    params.setdefault("application_name", "citylod serve")
    return make_conninfo("", **params)


def _configure(conn: psycopg.Connection) -> None:
    conn.isolation_level = psycopg.IsolationLevel.REPEATABLE_READ  # one snapshot per answer
    conn.read_only = True


class Reader:
    """At most ``size`` pooled connections (``self.pool``), each used by one thread at a time; ``read(fn)`` runs
    ``fn(conn)`` in one read-only transaction."""

    def __init__(self, url: str, size: int, acquire_timeout: float = 30.0) -> None:
        self.conninfo = _conninfo(url)
        self.size = size
        # min_size 1: an idle server keeps one connection, which is also how it notices an outage at once.
        # Opened by the first successful attempt, so that a server that cannot start does not retry in the back.
        self.pool: ConnectionPool[psycopg.Connection] = ConnectionPool(
            self.conninfo,
            min_size=1,
            max_size=size,
            kwargs={"autocommit": True},
            configure=_configure,
            timeout=acquire_timeout,
            reconnect_timeout=RECONNECT_TIMEOUT_S,
            name="citylod-reader",
            open=False,
        )
        self._probe_lock = threading.Lock()
        # (monotonic time of the last failed attempt, its error); -inf: attempt at the next read
        self._down: tuple[float, str] | None = (-math.inf, "not connected yet")
        self._opened = False

    @contextmanager
    def connection(self) -> Iterator[psycopg.Connection]:
        """A pooled connection, once the database is known to be reachable (else DbUnavailable at once)."""
        self._ensure_reachable()
        with self.pool.connection() as conn:
            yield conn

    def read(self, fn: Callable[[psycopg.Connection], T]) -> T:
        for attempt in (1, 2):
            conn: psycopg.Connection | None = None
            try:
                with self.connection() as conn, conn.transaction():
                    return fn(conn)
            except PoolTimeout as e:
                raise DbUnavailable("every database connection is busy") from e
            except psycopg.errors.LockNotAvailable as e:
                raise Busy(one_line(e)) from e
            except psycopg.OperationalError as e:
                if conn is not None and conn.broken:
                    with self._probe_lock:
                        self._down = (-math.inf, one_line(e))
                    if attempt == 1:
                        continue  # a connection that died while idle: once more, if the database is back
                raise DbUnavailable(one_line(e)) from e
            except psycopg.Error as e:
                raise DbUnavailable(one_line(e)) from e
        raise AssertionError("unreachable")

    def _ensure_reachable(self) -> None:
        if self._down is None:  # the usual case, without the lock
            return
        with self._probe_lock:
            if self._down is None:
                return
            since, reason = self._down
            if time.monotonic() - since < PROBE_INTERVAL_S:
                raise DbUnavailable(reason)
            try:
                psycopg.connect(self.conninfo).close()
            except psycopg.Error as e:
                self._down = (time.monotonic(), one_line(e))
                raise DbUnavailable(self._down[1]) from e
            if self._opened:
                self.pool.check()  # drop the idle connections that died with the outage
            else:
                self.pool.open()
                self._opened = True
            self._down = None

    def close(self) -> None:
        self.pool.close()
