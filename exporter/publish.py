"""Publishing an exported tileset into the database (pub.*, migration 0027) as a new generation of a named
tileset: the files the export wrote, under their paths, in one transaction, so that ``serve --db`` streams one
whole generation at every moment while the stages rebuild the tables behind it.

Blobs are stored by sha256 and only the ones the database lacks are sent (a re-export that changes a few tiles
sends a few tiles). The last ``keep`` generations of the tileset are kept; an older one goes, with the blobs no
remaining generation names. Publishes take turns (one transaction-scoped advisory lock): generation numbers
then follow commit order, and one publish never deletes a blob another is about to name.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import psycopg
from psycopg.types.json import Jsonb

from core.db import connect

PUBLISH_LOCK = int.from_bytes(b"cpub", "big")
NAME_RE = re.compile(r"^[A-Za-z0-9._-]{1,100}$")


def tileset_name(out: Path) -> str:
    """The name a tileset is published under unless one is given: its export directory's name (``make serve
    DB=1`` serves OUT's), with any character a name may not hold as '-'."""
    return re.sub(r"[^A-Za-z0-9._-]", "-", Path(out).resolve().name)[:100] or "tileset"


def check_name(name: str) -> str:
    if not NAME_RE.match(name):
        raise ValueError(
            f"cannot publish as {name!r}: a tileset name is 1-100 letters, digits, '.', '_' or '-' "
            "(give one with --publish NAME)"
        )
    return name


@dataclass(frozen=True)
class Published:
    generation: int
    files: int
    bytes: int
    new_files: int
    new_bytes: int
    dropped_generations: int
    dropped_blobs: int

    def as_dict(self) -> dict[str, int]:
        return {f"published_{k}": v for k, v in self.__dict__.items()}


def _files(directory: Path) -> Iterator[tuple[str, Path]]:
    for p in sorted(directory.rglob("*")):
        if p.is_file() and not p.name.startswith("."):
            yield p.relative_to(directory).as_posix(), p


def _sha256(path: Path) -> bytes:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").digest()


def publish(
    url: str,
    name: str,
    directory: Path,
    options: dict[str, object],
    run_id: int | None = None,
    keep: int = 2,
    inputs: dict[str, str] | None = None,
) -> Published:
    """Publish the files under ``directory`` as the next generation of tileset ``name``; ``inputs``: path ->
    the fingerprint of what a tile's glb was built from (exporter/reuse.py), recorded with the file."""
    check_name(name)
    if keep < 1:
        raise ValueError(f"publish_keep must be at least 1 (the live generation), not {keep}")
    listing = [(rel, p, _sha256(p)) for rel, p in _files(directory)]
    if not any(rel == "tileset.json" for rel, _, _ in listing):
        raise ValueError(f"{directory} holds no tileset.json: nothing to publish")
    with connect(url) as conn, conn.transaction():
        conn.execute("SELECT pg_advisory_xact_lock(%s)", (PUBLISH_LOCK,))
        shas = list({sha for _, _, sha in listing})
        have = {bytes(s) for (s,) in conn.execute("SELECT sha256 FROM pub.blob WHERE sha256 = ANY(%s)", (shas,))}
        new_files = new_bytes = 0
        with conn.cursor() as cur, cur.copy("COPY pub.blob (sha256, body) FROM STDIN (FORMAT BINARY)") as copy:
            copy.set_types(["bytea", "bytea"])  # binary: the bytes as they are, not twice their size in hex
            for _, p, sha in listing:
                if sha in have:
                    continue
                body = p.read_bytes()
                copy.write_row((sha, body))
                have.add(sha)
                new_files, new_bytes = new_files + 1, new_bytes + len(body)
        total = sum(p.stat().st_size for _, p, _ in listing)
        row = conn.execute(
            "INSERT INTO pub.generation (tileset, run_id, options, n_files, n_bytes, n_new_files, n_new_bytes) "
            "VALUES (%s, %s, %s, %s, %s, %s, %s) RETURNING generation",
            (name, run_id, Jsonb(options), len(listing), total, new_files, new_bytes),
        ).fetchone()
        assert row is not None  # INSERT ... RETURNING: one row
        (generation,) = row
        with (
            conn.cursor() as cur,
            cur.copy("COPY pub.file (generation, path, sha256, input_digest) FROM STDIN") as copy,
        ):
            for rel, _, sha in listing:
                copy.write_row((generation, rel, sha, (inputs or {}).get(rel)))
        dropped, blobs = _drop_old(conn, name, keep)
    return Published(generation, len(listing), total, new_files, new_bytes, dropped, blobs)


def _drop_old(conn: psycopg.Connection, name: str, keep: int) -> tuple[int, int]:
    """Delete the generations of ``name`` beyond the last ``keep`` and the blobs nothing names any more. Plain
    DELETEs: a server reading an old generation at this moment finishes its read from its snapshot."""
    old = [
        g
        for (g,) in conn.execute(
            "SELECT generation FROM pub.generation WHERE tileset = %s ORDER BY generation DESC OFFSET %s", (name, keep)
        )
    ]
    if not old:
        return 0, 0
    shas = [s for (s,) in conn.execute("DELETE FROM pub.file WHERE generation = ANY(%s) RETURNING sha256", (old,))]
    conn.execute("DELETE FROM pub.generation WHERE generation = ANY(%s)", (old,))
    cur = conn.execute(
        "DELETE FROM pub.blob b WHERE b.sha256 = ANY(%s) "
        "AND NOT EXISTS (SELECT 1 FROM pub.file f WHERE f.sha256 = b.sha256)",
        (list(set(shas)),),
    )
    return len(old), cur.rowcount


def live_generation(conn: psycopg.Connection, name: str) -> int | None:
    row = conn.execute("SELECT max(generation) FROM pub.generation WHERE tileset = %s", (name,)).fetchone()
    return row[0] if row else None
