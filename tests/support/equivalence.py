"""What an update and a full rebuild must hold alike, and how to compare them: the tables every stage writes,
row for row, and two export directories file for file. The update tests and benchmarks/update_bench.py share it
(the product's tests import nothing of benchmarks/)."""

from __future__ import annotations

import hashlib
import json
import threading
from pathlib import Path
from typing import Any

import psycopg
from psycopg import sql

#: What an update and a full rebuild must hold alike: every table the stages write, compared row for row
#: (identity columns, numbered by insertion order and never exported, and timestamps left out; meta.dataset's
#: source file and sha256 name the file each read)
TABLES = [
    "osm.building",
    "osm.reject",
    "osm.building_relation",
    "osm.building_relation_member",
    "meta.dataset",
    "meta.diagnostic",
    "lod.building_mesh",
    "lm.building",
    "lm.exaggeration",
    "tiles.tile",
    "tiles.building_tile",
    "tiles.grid",
    "tiles.tile_content",
    "gen.footprint",
    "gen.building_mesh",
    "gen.block",
    "gen.unit_input",
    "tex.page",
    "tex.feature_uv",
    "tex.failure",
    "tex.tile_input",
]
IGNORED = {
    "osm.reject": {"reject_id"},
    "meta.diagnostic": {"diagnostic_id"},
    "tex.failure": {"failure_id"},
    "meta.dataset": {"source_file", "source_sha256"},
}


def table_rows(conn: psycopg.Connection, table: str) -> list[str]:
    """The rows of ``table`` as text, sorted (TABLES, IGNORED)."""
    schema, name = table.split(".")
    cols = [
        c
        for (c,) in conn.execute(
            "SELECT column_name FROM information_schema.columns WHERE table_schema = %s AND table_name = %s "
            "AND data_type NOT LIKE 'timestamp%%' ORDER BY ordinal_position",
            (schema, name),
        )
        if c not in IGNORED.get(table, set())
    ]
    query = sql.SQL("SELECT ROW({})::text FROM {}").format(
        sql.SQL(", ").join(map(sql.Identifier, cols)), sql.Identifier(schema, name)
    )
    return sorted(r for (r,) in conn.execute(query))


def differences(a_url: str, b_url: str) -> dict[str, int]:
    """Rows that differ between the two databases, by table (only tables that differ)."""
    out = {}
    with psycopg.connect(a_url) as a, psycopg.connect(b_url) as b:
        for table in TABLES:
            ra, rb = table_rows(a, table), table_rows(b, table)
            if ra != rb:
                out[table] = len(set(ra) ^ set(rb)) or abs(len(ra) - len(rb))
    return out


class Reader:
    """An analyst reading while a run writes: a thread that counts the rows of every table of TABLES and the
    root tile's content (api.buildings_for_tile) over and over, each read giving up after LOCK_TIMEOUT_MS when it
    would wait on a lock. ``report()`` after the ``with``: the reads, those that gave up, the stages seen running,
    and per table the counts seen that are neither the count before nor the count after (a table emptied or
    half written while the run ran)."""

    LOCK_TIMEOUT_MS = 100

    def __init__(self, url: str) -> None:
        self.url = url
        self.queries: dict[str, sql.Composable] = {
            t: sql.SQL("SELECT count(*) FROM {}").format(sql.Identifier(*t.split("."))) for t in TABLES
        }
        self.queries["api.buildings_for_tile(0, 0, 0)"] = sql.SQL(
            "SELECT count(*) FROM api.buildings_for_tile(0, 0, 0)"
        )
        self.seen: dict[str, set[int]] = {name: set() for name in self.queries}
        self.running: set[str] = set()
        self.errors: list[str] = []
        self.rounds = 0
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._poll, name="reader")

    def _counts(self, conn: psycopg.Connection) -> dict[str, int]:
        return {name: conn.execute(q).fetchone()[0] for name, q in self.queries.items()}  # type: ignore[index]

    def _poll(self) -> None:
        with psycopg.connect(self.url, autocommit=True) as conn:
            conn.execute(sql.SQL("SET lock_timeout = {}").format(sql.Literal(f"{self.LOCK_TIMEOUT_MS}ms")))
            while not self._done.is_set():
                try:
                    self.running.update(
                        s for (s,) in conn.execute("SELECT stage FROM meta.pipeline_run WHERE status = 'running'")
                    )
                    for name, n in self._counts(conn).items():
                        self.seen[name].add(n)
                    self.rounds += 1
                except psycopg.Error as e:
                    self.errors.append(f"{type(e).__name__}: {str(e).splitlines()[0]}")

    def __enter__(self) -> Reader:
        with psycopg.connect(self.url, autocommit=True) as conn:
            self.before = self._counts(conn)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()
        self._thread.join()
        with psycopg.connect(self.url, autocommit=True) as conn:
            self.after = self._counts(conn)

    def report(self) -> dict[str, Any]:
        odd = {
            name: sorted(s - {self.before[name], self.after[name]})
            for name, s in self.seen.items()
            if s - {self.before[name], self.after[name]}
        }
        return {
            "rounds": self.rounds,
            "lock_timeouts": sum("LockNotAvailable" in e for e in self.errors),
            "errors": self.errors[:5],
            "running": sorted(self.running),
            "odd_counts": odd,
            "tables": len(TABLES),
        }


def file_hashes(d: Path) -> dict[str, str]:
    return {
        p.relative_to(d).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(d.rglob("*"))
        if p.is_file()
    }


def tileset_differences(a: Path, b: Path) -> list[str]:
    """Files that differ between two export directories; tileset.json without its tilesetVersion (the sha256
    of the OSM file each was built from: a state file made by an update is not the extract's bytes)."""
    fa, fb = file_hashes(a), file_hashes(b)
    fa.pop("tileset.json", None), fb.pop("tileset.json", None)
    differ = sorted(k for k in fa.keys() | fb.keys() if fa.get(k) != fb.get(k))
    ta, tb = (json.loads((d / "tileset.json").read_text()) for d in (a, b))
    ta["asset"].pop("tilesetVersion", None), tb["asset"].pop("tilesetVersion", None)
    return differ + (["tileset.json"] if ta != tb else [])
