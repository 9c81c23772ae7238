"""Stage ingest: an OSM extract (.osm.pbf / .osm) into osm.building, osm.reject and osm.building_relation.

etl/ingest/read.py reads the file (two streaming passes with pyosmium) into one row per candidate, COPYed into
osm.building_import; osm.finish_ingest() then builds, repairs and links set-based in SQL. The whole stage is one
transaction: re-running it on the same file gives the same database.

In an update (etl/update/) the file is the OSM state after the change files: the buildings are assembled
exactly as a full ingest would, compared with osm.building, and only the rows that differ are replaced and
listed in osm.building_change (what the run changed, for the stages after it). When the database's last ingest
read the state before the change files, only the candidates those files touched are read again
(``Input.touched``), unless a footprint the change moved reaches the edge of the data (osm.extent_kept: the
working CRS comes from the extent); then every candidate is.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import LiteralString

import psycopg

from core.changes import Changes
from core.progress import Balance, Progress, summary
from core.settings import Settings
from core.stage import Context, Result
from etl.ingest.read import (
    COPY_IMPORT,
    ChangeIds,
    IngestCounts,
    read_building_relations,
    read_buildings,
    reading,
)


@dataclass(frozen=True)
class Input:
    """What ingest reads: the OSM file and its sha256 (the dataset's); in an update the OSM ids the change files
    touched (None: every candidate is read again) and what else to write in its transaction, at its end (the
    update's meta.osm_change rows, given the cursor and the run)."""

    path: Path
    sha256: str | None
    touched: ChangeIds | None = None
    also: Callable[[psycopg.Cursor, int], None] | None = None


def _copy_rows(
    cur: psycopg.Cursor, statement: LiteralString, rows: Iterable[tuple[object, ...]], progress: Progress
) -> None:
    with cur.copy(statement) as copy:
        for row in rows:
            copy.write_row(row)
            progress.update()


def _clear(cur: psycopg.Cursor, update: bool) -> None:
    if update:
        # not TRUNCATE: readers see the rows of before until the commit and never wait for it
        cur.execute("TRUNCATE osm.building_import")  # the staging table, read by nobody else
        cur.execute("DELETE FROM osm.building_relation")  # its members with it (ON DELETE CASCADE)
        return
    # downstream tables hold derived data of the previous dataset; they are rebuilt by later stages
    cur.execute(
        "TRUNCATE osm.building_import, osm.building, osm.building_relation, osm.building_relation_member,"
        " lod.building_mesh, tiles.building_tile, tiles.tile, tiles.grid CASCADE"
    )
    cur.execute("TRUNCATE osm.reject, meta.diagnostic RESTART IDENTITY")
    cur.execute("DELETE FROM meta.osm_change")  # a new base file: no change applied to it yet


def _stage_relations(cur: psycopg.Cursor, path: Path) -> int:
    """Pass A into osm.building_relation and its members; returns the relations."""
    with reading(path):
        rels = list(read_building_relations(path))  # few; needed before parts are linked
    if rels:
        with cur.copy("COPY osm.building_relation (relation_id, name, tags) FROM STDIN") as copy:
            for rid, tags, _ in rels:
                copy.write_row((rid, tags.get("name"), json.dumps(tags, ensure_ascii=False)))
        with cur.copy(
            "COPY osm.building_relation_member (relation_id, seq, member_type, member_id, role) FROM STDIN"
        ) as copy:
            for rid, _, members in rels:
                for seq, (mtype, ref, role) in enumerate(members):
                    copy.write_row((rid, seq, mtype, ref, role))
    return len(rels)


def _stage_candidates(
    cur: psycopg.Cursor, inp: Input, settings: Settings, counts: IngestCounts, partial: bool
) -> tuple[bool, IngestCounts, Progress]:
    """Pass B into osm.building_import: only the candidates the change touched when ``partial``, unless that
    does not keep the extent (then every candidate). Returns (partial still, the counts, the progress)."""
    progress = Progress("ingest", "buildings")
    with reading(inp.path):
        _copy_rows(
            cur, COPY_IMPORT, read_buildings(inp.path, settings, counts, inp.touched if partial else None), progress
        )
    if (
        partial
        and inp.touched is not None
        and not _one(cur, "SELECT osm.extent_kept(%s)", (sorted(inp.touched.ways),))[0]
    ):
        print("  ingest: the change reaches the edge of the data: every candidate is read again", file=sys.stderr)
        partial, counts = False, IngestCounts(building_relations=counts.building_relations)
        cur.execute("TRUNCATE osm.building_import")
        with reading(inp.path):
            _copy_rows(cur, COPY_IMPORT, read_buildings(inp.path, settings, counts), progress)
    return partial, counts, progress


def run(ctx: Context) -> Result:
    """Ingest ``ctx.options`` (an Input) in one transaction. A full ingest starts the database afresh; an update
    replaces only the buildings that differ, lists them in osm.building_change and keeps what is derived from
    the others."""
    inp: Input = ctx.options
    conn, settings, update = ctx.conn, ctx.settings, ctx.update
    if not inp.path.exists():
        raise FileNotFoundError(f"OSM file not found: {inp.path}")
    t0 = time.perf_counter()
    counts = IngestCounts()
    with conn.transaction(), conn.cursor() as cur:
        _clear(cur, update)
        counts.building_relations = _stage_relations(cur, inp.path)
        partial, counts, progress = _stage_candidates(cur, inp, settings, counts, update and inp.touched is not None)
        if update and not partial:
            cur.execute("DELETE FROM osm.reject WHERE stage = 'ingest'")
            cur.execute("DELETE FROM meta.diagnostic WHERE stage = 'ingest'")
        print(
            f"  ingest: read {progress.count:,} candidates in {progress.elapsed:.2f} s, building in SQL…",
            file=sys.stderr,
            flush=True,
        )
        (staged,) = _one(cur, "SELECT count(*) FROM osm.building_import")
        ways = sorted(inp.touched.ways) if partial and inp.touched is not None else None
        cur.execute(
            "CALL osm.finish_ingest(%s, %s, %s, %s, %s)",
            (settings.min_area_m2, str(inp.path), inp.sha256, update, ways),
        )
        figures = _figures(cur)
        changed = Changes(buildings=[int(i) for (i,) in cur.execute("SELECT id FROM osm.building_change")])
        if inp.also is not None:
            inp.also(cur, ctx.run_id)
    if int(staged) != counts.candidates:
        raise RuntimeError(f"ingest lost objects: {counts.candidates} candidates read, {staged} staged")
    result = _result(figures, counts, int(staged), partial, update, time.perf_counter() - t0)
    # a full ingest changed everything: only an update knows what it changed
    return Result(result, changed if update else None)


@dataclass(frozen=True)
class _Figures:
    """What the database holds after osm.finish_ingest, for the counts."""

    loaded: int
    rejected: list[tuple[str, int]]
    by_kind: dict[str, int]
    repaired: int
    srid: tuple[int, str]
    changes: dict[str, int]


def _one(cur: psycopg.Cursor, query: LiteralString, params: tuple = ()) -> tuple:
    row = cur.execute(query, params).fetchone()
    assert row is not None
    return row


def _figures(cur: psycopg.Cursor) -> _Figures:
    return _Figures(
        loaded=int(_one(cur, "SELECT count(*) FROM osm.building")[0]),
        rejected=[
            (r, int(n))
            for r, n in cur.execute(
                "SELECT reason, count(*) FROM osm.reject WHERE stage = 'ingest' GROUP BY reason ORDER BY reason"
            )
        ],
        by_kind={k: int(n) for k, n in cur.execute("SELECT kind, count(*) FROM osm.building GROUP BY kind")},
        repaired=int(_one(cur, "SELECT count(*) FROM osm.building WHERE repaired")[0]),
        srid=(int((s := _one(cur, "SELECT srid, srid_name FROM meta.dataset"))[0]), str(s[1])),
        changes={c: int(n) for c, n in cur.execute("SELECT change, count(*) FROM osm.building_change GROUP BY change")},
    )


def _result(
    f: _Figures, counts: IngestCounts, staged: int, partial: bool, update: bool, seconds: float
) -> dict[str, object]:
    n_rejected = sum(n for _, n in f.rejected)
    # a partial update read only some candidates: the others' rows are as they were, so the balance is the
    # database's (every candidate a building or a reject, as a full ingest checks it)
    n_in = f.loaded + n_rejected if partial else staged
    balance = Balance("buildings and parts", n_in, {"loaded": f.loaded}, n_rejected)
    result: dict[str, object] = {
        **balance.counts(),
        "loaded": f.loaded,
        "repaired": f.repaired,
        "buildings": f.by_kind.get("building", 0),
        "parts": f.by_kind.get("part", 0),
        "from_ways": counts.ways,
        "from_relations": counts.relations,
        "building_relations": counts.building_relations,
        "building_nodes_skipped": counts.nodes_skipped,
        "rejected_by_reason": dict(f.rejected),
        "srid": f.srid[0],
        "seconds": round(seconds, 3),
    }
    if update:
        result["changed"] = {k: f.changes.get(k, 0) for k in ("added", "modified", "deleted")}
        result["partial"] = partial  # only the candidates the change touched were read again
        result["staged"] = staged
    reasons = ", ".join(f"{r} {n}" for r, n in f.rejected) or "none"
    print(f"  working CRS: EPSG:{f.srid[0]} ({f.srid[1]}); rejects: {reasons}", file=sys.stderr)
    summary(
        "ingest",
        balance,
        f"{f.by_kind.get('building', 0):,} buildings, {f.by_kind.get('part', 0):,} parts, {f.repaired:,} repaired",
        seconds,
        n_in,
    )
    return result
