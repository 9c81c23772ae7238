"""Stage lod: every building and part as LOD1 (block), LOD2 (roof:shape roof) and LOD3 (LOD2 + windows and
doors) solids in lod.building_mesh, one row per building and LOD.

Streams osm.building through a server-side cursor in batches; heights are resolved for a whole batch with
numpy (etl/lod/heights.py). LOD1 and the flat LOD2 roofs (most buildings) are extruded for the whole batch at
once (etl/geom/extrude.py); pitched roofs are built per footprint from the straight skeleton SFCGAL computes
in the same query (lod.straight_skeleton, etl/lod/roofs.py); LOD3 adds windows and doors for the whole batch
(etl/geom/facade.py). Every LOD2 solid is measured (closed, consistently wound, volume > 0,
etl/geom/check.py) and failures are recorded. Meshes are COPYed as POLYHEDRALSURFACE Z EWKB with one
surface-semantic byte per triangle. The batches are built as Dask tasks (core/workers.py; settings.lod_workers),
a few in flight, while one thread COPYs the built ones in input order; a batch whose worker hangs or dies on
every attempt becomes rejects (lod_hung / lod_crashed), never a stopped run.

Outlines whose parts cover them (settings.outline_part_coverage, the S3DB outline rule) are not drawn: their
parts are, and the outline gets an ``outline_hidden_by_parts`` diagnostic. When parts cover less, only what
they leave uncovered is drawn (lod.outline_remainder, diagnostic ``outline_reduced_by_parts``), so outline
and parts never overlap. An outline that is itself tagged building:part=* is a part too (S3DB) and is
always drawn whole. building:part=roof / building=roof is a roof without walls: a slab of ROOF_SLAB_M
(etl/lod/batch.py, which builds the meshes of a batch) under the roof. in = buildings drawn + outlines hidden
by parts + rejects (osm.reject, stage lod), checked at the end.
"""

from __future__ import annotations

import collections
import os
import queue
import threading
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, LiteralString

import psycopg
from psycopg.rows import dict_row

from core.changes import Changes
from core.db import analyze, connect, working_srid
from core.progress import Balance, Progress, summary
from core.settings import Settings
from core.stage import Context, Result
from core.workers import Lost, imap_isolated, worker_count
from etl.lod import roofs
from etl.lod.batch import Batch, build_batch, hidden_outline

LODS = (1, 2, 3)
_SKELETON_VALUES = sorted(roofs.NEEDS_SKELETON | {k for k, v in roofs.ALIASES.items() if v in roofs.NEEDS_SKELETON})

# The input is lod.building_input (sql/lod/building_input.sql: outlines hidden by their parts left out, an
# outline with parts drawn as what they leave uncovered, the roof footprint and straight skeleton where the roof
# shape needs them), an inlined SQL function streamed by a server-side cursor and read by column name. Hidden
# outlines get their diagnostics from lod.diagnose_hidden_outlines, rejects go to osm.reject through
# lod.store_rejects.
COLUMNS = (
    "building_id",
    "lod",
    "geom",
    "n_triangles",
    "min_height",
    "height",
    "height_source",
    "volume_m3",
    "semantics",
    "roof_shape",
    "roof_height",
    "roof_engine",
    "ground_area_m2",
    "wall_area_m2",
    "roof_area_m2",
    "opening_area_m2",
    "n_windows",
    "n_doors",
    "watertight",
    "winding_consistent",
)
# binary COPY: no hex encoding and half the bytes; EWKB goes to geometry_recv as it is
COPY_TYPES = (
    "int8",
    "int2",
    "bytea",
    "int4",
    "float4",
    "float4",
    "text",
    "float8",
    "bytea",
    "text",
    "float4",
    "text",
    "float8",
    "float8",
    "float8",
    "float8",
    "int4",
    "int4",
    "bool",
    "bool",
)


def _build(item: tuple[list[dict[str, Any]], Settings, int]) -> Batch:
    return build_batch(*item)


def _lost_batch(rows: list[dict[str, Any]], lost: Lost) -> Batch:
    """A batch whose worker hung or died on it: its buildings become rejects with the reason, so none is lost
    (the outlines without a footprint are drawn by their parts, as build_batch would say)."""
    out = Batch()
    for r in rows:
        if r["footprint"] is None:
            hidden_outline(out, r)
        else:
            out.rejects.append(
                (r["osm_type"], r["osm_id"], f"lod_{lost.reason}", f"its batch of {len(rows)} buildings: {lost.detail}")
            )
    return out


def _built(
    src: psycopg.ServerCursor[dict[str, Any]], settings: Settings, srid: int, failure: list[BaseException]
) -> Iterator[tuple[list[dict[str, Any]], Batch]]:
    """(rows, their Batch) for every batch of the input, in input order: built here with one worker, else as
    Dask tasks (core/workers.py) with a few batches in flight, so the city is never held whole."""
    batches = iter(lambda: [] if failure else src.fetchmany(settings.lod_batch_size), [])
    # the database COPYs the meshes while they are built: it keeps a core (on 2 cores the stage's own process
    # and the COPY thread were faster than 2 Dask workers: 15 s against 21 s on Liechtenstein x6, measured)
    workers = worker_count(settings.lod_workers, min(4, max(1, (os.cpu_count() or 1) - 1)))
    if workers <= 1:
        for rows in batches:
            yield rows, build_batch(rows, settings, srid)
        return
    flight: collections.deque[list[dict[str, Any]]] = collections.deque()

    def items() -> Iterator[tuple[list[dict[str, Any]], Settings, int]]:
        for rows in batches:
            flight.append(rows)
            yield rows, settings, srid

    for out in imap_isolated(_build, items(), workers, settings.lod_batch_timeout_s, window=2 * workers):
        rows = flight.popleft()
        yield rows, (_lost_batch(rows, out) if isinstance(out, Lost) else out)


@dataclass
class _Tally:
    """What the batches drawn so far add up to: the counts of the result, seconds by step, hidden outlines."""

    counts: dict[str, int] = field(
        default_factory=lambda: {
            "buildings": 0,
            "meshes": 0,
            "rejected": 0,
            "pitched_roofs": 0,
            "lod2_not_closed": 0,
            "triangles_lod1": 0,
            "triangles_lod2": 0,
            "triangles_lod3": 0,
        }
    )
    seconds: dict[str, float] = field(
        default_factory=lambda: {"lod1": 0.0, "lod2": 0.0, "lod3": 0.0, "encode": 0.0, "copy": 0.0}
    )
    hidden: int = 0

    def add(self, b: Batch) -> None:
        """Count batch ``b`` in."""
        for key, v in b.seconds.items():
            self.seconds[key] += v
        self.counts["buildings"] += b.drawn
        self.counts["meshes"] += len(b.meshes)
        self.counts["rejected"] += len(b.rejects)
        self.counts["pitched_roofs"] += b.pitched
        self.counts["lod2_not_closed"] += b.not_closed
        for lod in LODS:
            self.counts[f"triangles_lod{lod}"] += b.triangles[lod]
        self.hidden += b.hidden


def _scalar(cur: psycopg.Cursor[Any], query: LiteralString, params: tuple[Any, ...]) -> Any:
    """The first column of the one row ``query`` returns."""
    row = cur.execute(query, params).fetchone()
    assert row is not None
    return row[0]


def _clear_affected(cur: psycopg.Cursor[Any], buildings: Iterable[int]) -> list[int]:
    """The buildings an update draws again (the changed ones with their outlines and parts), their meshes,
    rejects and diagnostics of this stage deleted."""
    only = [i for (i,) in cur.execute("SELECT id FROM lod.affected_buildings(%s)", (sorted(set(buildings)),))]
    keys = [("W" if i > 0 else "R", abs(i)) for i in only]  # osm2pgsql ids: way id, or minus the relation's
    cur.execute("DELETE FROM lod.building_mesh WHERE building_id = ANY(%s) AND lod = ANY(%s)", (only, list(LODS)))
    for table in ("osm.reject", "meta.diagnostic"):
        cur.execute(
            f"DELETE FROM {table} WHERE stage = 'lod' AND (osm_type, osm_id) IN "  # noqa: S608
            "(SELECT * FROM unnest(%s::text[], %s::bigint[]))",
            ([k[0] for k in keys], [k[1] for k in keys]),
        )
    return only


def _clear_all(cur: psycopg.Cursor[Any]) -> None:
    """Every mesh, reject and diagnostic of this stage deleted, and what later stages built from the meshes."""
    # TRUNCATE when the table holds nothing but this stage's LODs: with wal_level=minimal (the local
    # cluster) PostgreSQL then writes the COPY without WAL, ~300 MB less on a 20k-building city
    others = _scalar(cur, "SELECT EXISTS (SELECT 1 FROM lod.building_mesh WHERE lod <> ALL(%s))", (list(LODS),))
    if others:
        cur.execute("DELETE FROM lod.building_mesh WHERE lod = ANY(%s)", (list(LODS),))
    else:
        cur.execute("TRUNCATE lod.building_mesh")
    # the tile tree and its generalized content were built from the old meshes; keeping them would let
    # export drop or miss buildings
    cur.execute(
        "TRUNCATE gen.block, gen.building_mesh, gen.footprint, tiles.building_tile, "
        "tiles.tile_content, tex.page, tex.feature_uv, tex.failure, tiles.tile, tiles.grid "
        "RESTART IDENTITY"
    )
    cur.execute("DELETE FROM osm.reject WHERE stage = 'lod'")
    cur.execute("DELETE FROM meta.diagnostic WHERE stage = 'lod'")


def _copy_batch(cur: psycopg.Cursor[Any], b: Batch) -> None:
    """A built batch into the database: its meshes, rejects and diagnostics."""
    with cur.copy(f"COPY lod.building_mesh ({', '.join(COLUMNS)}) FROM STDIN (FORMAT BINARY)") as copy:
        copy.set_types(list(COPY_TYPES))
        for m in b.meshes:
            copy.write_row(m)
    if b.rejects:  # few: with their tags and footprint, so nothing is lost
        cur.execute("CALL lod.store_rejects(%s, %s, %s, %s)", [list(c) for c in zip(*b.rejects, strict=True)])
    if b.diagnostics:
        with cur.copy("COPY meta.diagnostic (stage, osm_type, osm_id, code, detail) FROM STDIN") as copy:
            for d in b.diagnostics:
                copy.write_row(("lod", *d))


def _write(
    cur: psycopg.Cursor[Any],
    pending: queue.Queue[Batch | None],
    failure: list[BaseException],
    seconds: dict[str, float],
) -> None:
    """The COPY thread: every batch ``pending`` hands over until None, into the database; a failure goes to
    ``failure`` for the main thread, the queue still drained so the producer never blocks."""
    try:
        while (b := pending.get()) is not None:
            tc = time.perf_counter()
            _copy_batch(cur, b)
            seconds["copy"] += time.perf_counter() - tc
    except BaseException as e:  # noqa: BLE001 - handed to the main thread
        failure.append(e)
        while pending.get() is not None:  # drain so the producer never blocks
            pass


def _draw(
    cur: psycopg.Cursor[Any],
    src: psycopg.ServerCursor[dict[str, Any]],
    settings: Settings,
    srid: int,
    tally: _Tally,
    progress: Progress,
) -> None:
    """Every batch of ``src`` built and COPYed: the database parses and indexes a batch (COPY, on a thread of
    its own) while Python builds the next, two cores busy. Raises what the COPY thread failed with."""
    pending: queue.Queue[Batch | None] = queue.Queue(maxsize=2)
    failure: list[BaseException] = []
    writer = threading.Thread(target=_write, args=(cur, pending, failure, tally.seconds), name="lod-copy")
    writer.start()
    try:
        for rows, b in _built(src, settings, srid, failure):
            tally.add(b)
            pending.put(b)
            progress.update(len(rows))
    finally:
        pending.put(None)
        writer.join()
    if failure:
        raise failure[0]


def run(ctx: Context) -> Result:
    """Draw every building; in an update that knows what changed since the last run, only the buildings it
    changed, with their outlines and parts (lod.affected_buildings), keeping every other building's meshes."""
    conn, url, settings = ctx.conn, ctx.url, ctx.settings
    changed = ctx.update and ctx.changed is not None
    t0 = time.perf_counter()
    srid = working_srid(conn)
    coverage = settings.outline_part_coverage
    tally = _Tally()
    progress = Progress("lod", "buildings")
    # One connection streams the input, this one writes: all output lands in a single transaction.
    with connect(url) as reader, conn.transaction(), conn.cursor() as cur:
        only: list[int] | None = None
        if changed:
            assert ctx.changed is not None
            only = _clear_affected(cur, ctx.changed.buildings)
        else:
            _clear_all(cur)
        total = _scalar(
            cur, "SELECT count(*) FROM osm.building WHERE %s::bigint[] IS NULL OR id = ANY(%s)", (only, only)
        )
        tally.hidden = _scalar(cur, "CALL lod.diagnose_hidden_outlines(%s, NULL, %s)", (coverage, only))
        progress.total = total - tally.hidden
        with reader.cursor(name="lod_input", row_factory=dict_row) as src:
            src.itersize = settings.lod_batch_size
            src.execute("SELECT * FROM lod.building_input(%s, %s, %s)", (coverage, _SKELETON_VALUES, only))
            _draw(cur, src, settings, srid, tally, progress)
        analyze(cur, "lod.building_mesh", tally.counts["meshes"] if changed else None)
    return _result(tally, total, changed, time.perf_counter() - t0)


def _result(tally: _Tally, total: int, changed: bool, wall: float) -> Result:
    """The stage's result and summary line: the balance of buildings in and drawn, triangles, timings."""
    counts, seconds, hidden = tally.counts, tally.seconds, tally.hidden
    balance = Balance(
        "buildings and parts",
        total,
        {"drawn": counts["buildings"], "outlines drawn by their parts": hidden},
        counts["rejected"],
    )
    nb = max(counts["buildings"], 1)
    result: dict[str, object] = {
        **counts,
        **balance.counts(),
        "hidden_by_parts": hidden,
        "seconds": round(wall, 3),
        "changed_only": changed,
        "seconds_by_step": {k: round(v, 3) for k, v in seconds.items()},
        **{f"triangles_per_building_lod{lod}": round(counts[f"triangles_lod{lod}"] / nb, 1) for lod in LODS},
        "lod2_closed_pct": round(100.0 * (1 - counts["lod2_not_closed"] / nb), 3),
    }
    summary(
        "lod",
        balance,
        f"{counts['pitched_roofs']:,} pitched roofs, LOD2 closed {result['lod2_closed_pct']}% | triangles LOD1 "
        f"{counts['triangles_lod1']:,}, LOD2 {counts['triangles_lod2']:,}, LOD3 {counts['triangles_lod3']:,}",
        wall,
        total,
    )
    # an update: only the buildings ingest recorded (and their kin, reached through their group)
    return Result(result, Changes() if changed else None)
