"""Database connections. One DSN: DATABASE_URL, else the local cluster (core/cluster.py)."""

from __future__ import annotations

import psycopg

from . import cluster
from .settings import Settings


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
