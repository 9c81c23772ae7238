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
  and is no slower for it (what it costs: the comment at KTX2 settings below).
* a LOD2 tile and the leaves below it are one unit of work sharing a chart cache: the leaves' walls and
  roofs are the LOD2 tile's, at the same resolution wherever the LOD2 tile's rule reaches the cap (on
  Liechtenstein, all of them), so they are copied, and downsampled through OpenImageIO when the parent
  needs fewer texels. Units are independent and run in a few worker processes, each with its own connection.

One broken feature never stops the run: a tile that fails is textured again without the features that fail
alone, and those are listed in tex.failure (they keep their vertex colours). A unit whose worker hangs (past
tex_unit_timeout_s) or dies in native code is lost alone: its features go to tex.failure as texturing_hung or
texturing_crashed, and its stacks to stderr (core/workers.py). A page the KTX2 encoder refuses (exit, time-out,
no KTX2 written) keeps its WebP; its features are listed in tex.failure as ktx2_encode_failed and drawn with
vertex colours in KTX2 exports. Features in = textured + textured in WebP only + failed.
"""

from __future__ import annotations

import atexit
import itertools
import math
import os
import time
import traceback
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import psycopg
from psycopg.rows import class_row, dict_row

from core.camera import distance_for_pixels
from core.changes import Changes, reach
from core.db import analyze, connect, shares, thread_map
from core.fingerprint import run_seed
from core.progress import Balance, Progress, summary
from core.reuse import plan
from core.semantics import SEM_DOOR, SEM_WINDOW
from core.settings import Settings
from core.stage import Context, Result
from core.wkb import decode_triangles
from core.workers import Lost, imap_isolated
from etl.textures import atlas as A
from etl.textures import ktx2 as K
from etl.textures import texturing as X

FORMAT = "webp"
WEBP_METHOD = 2  # libwebp effort: 4 is 2.4x slower for 3 % fewer bytes on these pages (measured)
# KTX2 settings (core.settings tex_ktx2_*), measured on 16 Liechtenstein pages of 512 x 512, level 0 of the ETC1
# transcode against the page (WebP q90 for scale: 363 kB, PSNR 39.6 dB, mean abs diff 1.49 of 255): basisu -q 64
# 208 kB, 35.2 dB, 2.43; -q 128 257 kB, 35.2 dB, 2.42; -q 32 180 kB, 34.8 dB, 2.49; -comp_level 0 6 % more bytes
# for ~10 % less time. The error is ETC1S's block format, not its codebook size: -q above 64 buys bytes only.
# Encoding costs ~0.35 s a 512 x 512 page (basisu, one thread): on Liechtenstein (636 pages, 2 workers on a
# shared machine under load 6-7) the stage took 411 s with it against 97 s without, for 13.0 MB of KTX2
# pages against 39.0 MB of WebP.
BLOCK_KEY = 1 << 62  # style keys of blocks (gen.block ids) apart from osm.building ids

# The stage reads tex.tiles_to_texture (Tile rows), tex.tile_features (a tile's features, the same meshes in the
# same triangle order as the exporter's) and tex.opening_meshes (sql/tex/), rows by column name.
_FEATURES = "SELECT * FROM tex.tile_features(%s, %s, %s)"
_FEATURE_IDS = "SELECT feature_kind, building_id, osm_type, osm_id FROM tex.tile_features(%s, %s, %s)"  # no meshes
_PAGE_COLUMNS = ("level", "x", "y", "page_no", "format", "mime", "width", "height", "n_bytes", "bytes",
                 "utilization", "texels_per_metre", "view_distance_m", "n_charts", "n_scaled", "padding", "rects",
                 "ktx2", "ktx2_n_bytes", "ktx2_levels")
_PAGE_TYPES = ("int2", "int4", "int4", "int2", "text", "text", "int4", "int4", "int4", "bytea", "float4", "float4",
               "float4", "int4", "int4", "int2", "bytea", "bytea", "int4", "int2")
_UV_COLUMNS = ("level", "x", "y", "feature_kind", "feature_id", "n_triangles", "page", "uv")
_UV_TYPES = ("int2", "int4", "int4", "text", "int8", "int4", "bytea", "bytea")
_FAIL_COLUMNS = ("level", "x", "y", "feature_kind", "feature_id", "osm_type", "osm_id", "reason", "detail")
_FAIL_TYPES = ("int2", "int4", "int4", "text", "int8", "text", "int8", "text", "text")


@dataclass(frozen=True)
class Tile:
    level: int
    x: int
    y: int
    gen_level: int
    geometric_error: float
    is_leaf: bool
    features: int


Key = tuple[int, int, int]
#: A unit of work: its tiles, the fingerprints of their last textures (in an update; else None) and this run's.
Unit = tuple[list[Tile], dict[Key, str] | None, dict[Key, str]]


@dataclass
class TileResult:
    tile: Tile
    rho: float
    distance: float
    padding: int
    pages: list[tuple] = field(default_factory=list)
    uvs: list[tuple] = field(default_factory=list)
    failures: list[tuple] = field(default_factory=list)
    features: int = 0
    ktx2_failed: int = 0  # features among ``failures`` textured, but on a page without KTX2
    stats: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0
    encode_seconds: float = 0.0
    fingerprint: str | None = None  # of everything read for the tile (tex.tile_input)
    kept: bool = False  # the tile's input had not changed: its rows in tex.* stay as they are
    redrawn: bool = False  # kept, but drawn again for its unit's chart cache (its unit's LOD2 tile changed)


def resolution(geometric_error: float, settings: Settings) -> tuple[float, float]:
    """(texels per metre, view distance m) of a tile: the thesis' rule at the nearest distance the tile is
    drawn from, capped by tex_max_texels_per_metre; the distance is where that resolution is exactly right."""
    fov = math.radians(settings.tex_fov_deg)
    cap = settings.tex_max_texels_per_metre
    rho = cap
    if geometric_error > 0:
        d = distance_for_pixels(geometric_error, settings.tex_max_sse, fov, settings.tex_screen_height)
        rho = min(cap, float(A.texels_per_metre(d, fov, settings.tex_screen_height, settings.tex_px_per_texel)))
    # where rho texels per metre are exactly rho * px_per_texel pixels per metre
    distance = distance_for_pixels(1.0, rho * settings.tex_px_per_texel, fov, settings.tex_screen_height)
    return rho, distance


def padding_for(rho: float, settings: Settings) -> int:
    """Gutter texels at rho texels/m: about half a metre of texels, at most tex_padding. A 2-texel gutter
    around charts a few texels wide would cost more texels than they hold (utilization below 60 % at 1 texel/m
    against 98 % without, on Liechtenstein); without gutters the charts' edge texels are centred on their
    edges (texturing._insets), so full-resolution sampling never reads a neighbour."""
    return max(0, min(settings.tex_padding, int(rho // 2)))


def units(tiles: list[Tile]) -> list[list[Tile]]:
    """Units of work: each LOD2-band tile with the leaves below it (leaves first, so they fill the chart cache
    it reads), every other tile alone. Deterministic order."""
    lod2 = {(t.level, t.x, t.y): [] for t in tiles if t.gen_level == 3}  # type: dict[tuple[int, int, int], list[Tile]]
    alone: list[list[Tile]] = []
    for t in tiles:
        if t.gen_level == 4:
            for up in range(1, t.level + 1):
                key = (t.level - up, t.x >> up, t.y >> up)
                if key in lod2:
                    lod2[key].append(t)
                    break
            else:
                alone.append([t])
        elif t.gen_level != 3:
            alone.append([t])
    by_key = {(t.level, t.x, t.y): t for t in tiles}
    out = [leaves + [by_key[k]] for k, leaves in lod2.items()] + alone
    # biggest units first, so the last worker does not start a long one at the end
    return sorted(out, key=lambda u: -sum(t.features for t in u))


#: A row of tex.tile_features, by column name.
Feature = dict[str, Any]


def _style(r: Feature) -> X.Style:
    bid = int(r["building_id"])
    key = BLOCK_KEY + bid if r["feature_kind"] == "block" else bid
    return X.Style.from_tags(key, r["building_material"], r["building_colour"], r["roof_material"], r["roof_colour"],
                             r["levels"], generic_openings=r["gen_level"] <= 2)


def _arrays(rows: list[Feature]) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    tris, sems, counts = [], [], []
    for r in rows:
        t = decode_triangles(r["mesh"])
        s = (np.full(len(t), X.SEM_UNKNOWN, np.uint8) if r["semantics"] is None
             else np.frombuffer(bytes(r["semantics"]), np.uint8))
        if len(s) != len(t):
            raise ValueError(f"{len(s)} semantics bytes for {len(t)} triangles")
        tris.append(t)
        sems.append(s)
        counts.append(len(t))
    feat = np.repeat(np.arange(len(rows)), counts)
    return (np.concatenate(tris) if tris else np.zeros((0, 3, 3)), feat,
            np.concatenate(sems) if sems else np.zeros(0, np.uint8), counts)


def _texture(rows: list[Feature], conn: psycopg.Connection, rho: float, params: X.Params,
             cache: X.ChartCache | None, store: bool) -> tuple[X.TileTexture, list[int]]:
    tri, feat, sem, counts = _arrays(rows)
    styles = [_style(r) for r in rows]
    # LOD2 features whose leaves were not textured in this unit: their openings from the LOD3 meshes
    lod2 = [r["gen_level"] == 3 and r["feature_kind"] != "block" for r in rows]
    need = sorted({int(r["building_id"]) for r, s, is2 in zip(rows, styles, lod2, strict=True)
                   if is2 and (cache is None or s.key not in cache.buildings)})
    extra = None
    if need:
        index = {int(r["building_id"]): i for i, (r, is2) in enumerate(zip(rows, lod2, strict=True)) if is2}
        ot, of, os_ = [], [], []
        for bid, s3, g3 in conn.execute("SELECT building_id, semantics, mesh FROM tex.opening_meshes(%s)",
                                        (need,)).fetchall():
            t3 = decode_triangles(g3)
            s = np.frombuffer(bytes(s3), np.uint8) if s3 is not None else np.zeros(0, np.uint8)
            if len(s) != len(t3):
                continue  # no usable semantics: the wall stays without openings
            keep = (s == SEM_WINDOW) | (s == SEM_DOOR)
            ot.append(t3[keep])
            of.append(np.full(int(keep.sum()), index[int(bid)]))
            os_.append(s[keep])
        if ot:
            extra = (np.concatenate(ot), np.concatenate(of), np.concatenate(os_))
    tt = X.texture_tile(tri, feat, sem, styles, rho, params, extra, cache, store)
    return tt, counts


def _failure(key: tuple[int, int, int], row: Feature, reason: str, detail: str) -> tuple:
    """A tex.failure row (_FAIL_COLUMNS) of the feature ``row`` (of tex.tile_features)."""
    return (*key, row["feature_kind"], int(row["building_id"]), row["osm_type"], int(row["osm_id"]), reason,
            detail[:2000])


def _features(conn: psycopg.Connection, tile: Tile, query: str) -> list[Feature]:
    """The rows of ``query`` (_FEATURES or _FEATURE_IDS) for ``tile``."""
    with conn.cursor(row_factory=dict_row) as cur:
        return cur.execute(query, (tile.level, tile.x, tile.y)).fetchall()  # type: ignore[arg-type]


def _input_digests(url: str, tiles: list[Tile], threads: int) -> dict[Key, tuple[str, int]]:
    """tex.input_digests of every tile (the md5 of its feature rows, every column in order, and of its LOD2
    buildings' openings; its features), computed in the database by ``threads`` connections, each over a share
    of the tiles in one statement: no mesh is sent here."""
    def one(conn: psycopg.Connection, share: list[Tile]) -> list[tuple]:
        return conn.execute("SELECT level, x, y, digest, n_features FROM tex.input_digests(%s::int[], %s::int[], "
                            "%s::int[])",
                            ([t.level for t in share], [t.x for t in share], [t.y for t in share])).fetchall()

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


def plan_units(url: str, all_units: list[list[Tile]], seed: str, settings: Settings,
               recorded: dict[Key, str] | None, reached: set[Key] | None, threads: int) -> Plan:
    """The fingerprint of every tile (core/reuse.py): ``seed`` (the stage's settings and code), the tile's place,
    band, resolution (its geometric error matters through that alone) and count, and its input digest; a tile
    no change reached keeps its recorded one unread. A unit is kept when every tile of it is."""
    by_key = {(t.level, t.x, t.y): t for u in all_units for t in u}
    counts: dict[Key, int] = {k: t.features for k, t in by_key.items()}

    def parts(keys: list[Key]) -> dict[Key, tuple[object, ...]]:
        got = _input_digests(url, [by_key[k] for k in keys], threads)
        counts.update({k: n for k, (_, n) in got.items()})
        return {k: ((t.level, t.x, t.y, t.gen_level, resolution(t.geometric_error, settings), t.is_leaf,
                     t.features), got[k][0]) for k, t in ((k, by_key[k]) for k in keys)}

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


def _one_tile(tile: Tile, conn: psycopg.Connection, settings: Settings, cache: X.ChartCache | None,
              store: bool, rows: list[Feature] | None = None, encode: bool = True, jobs: int = 1) -> TileResult:
    """Texture ``tile``. ``encode`` False: only draw it, for the charts it adds to ``cache`` (its pages are
    kept from the last run, so neither encoded nor returned). ``jobs``: basisu processes for its pages (the
    cores this unit has to itself)."""
    t0 = time.perf_counter()
    rho, distance = resolution(tile.geometric_error, settings)
    pad = padding_for(rho, settings)
    res = TileResult(tile, rho, distance, pad)
    params = X.Params(page_size=settings.tex_page_size, padding=pad, packer=settings.tex_packer,
                      min_chart_texels=settings.tex_min_chart_texels,
                      xatlas_min_planes=settings.tex_xatlas_min_planes)
    rows = _features(conn, tile, _FEATURES) if rows is None else rows
    res.features = len(rows)
    key = (tile.level, tile.x, tile.y)

    good = list(range(len(rows)))
    tt: X.TileTexture | None = None
    try:
        tt, counts = _texture(rows, conn, rho, params, cache, store)
    except Exception:  # noqa: BLE001 -- one broken building never stops the run: find it below
        # which features fail on their own? (texturing is pure and per tile, so this is exact and rare)
        bad = []
        for i, r in enumerate(rows):
            try:
                _texture([r], conn, rho, params, None, False)
            except Exception as e:  # noqa: BLE001
                bad.append(i)
                res.failures.append(_failure(key, r, "texturing_failed", f"{type(e).__name__}: {e}"))
        good = sorted(set(range(len(rows))) - set(bad))
        try:
            tt, counts = _texture([rows[i] for i in good], conn, rho, params, cache, store)
        except Exception as e:  # noqa: BLE001
            detail = "".join(traceback.format_exception_only(type(e), e)).strip()
            res.failures += [_failure(key, rows[i], "tile_texturing_failed", detail) for i in good]
            good, tt = [], None
    if tt is not None and encode:
        rects = [tt.page_rects(p) for p in range(tt.layout.n_pages)]
        util = tt.layout.utilization
        refused: dict[int, str] = {}
        # basisu's processes encode the KTX2 while this one writes the WebP (the bytes do not depend on ``jobs``)
        t1 = time.perf_counter()
        pending = K.start_many(list(tt.pages), settings.tex_ktx2_quality, settings.tex_ktx2_comp_level,
                               settings.tex_ktx2_timeout_s, jobs)
        try:
            webp = [A.encode_image(img, FORMAT, settings.tex_quality, method=WEBP_METHOD) for img in tt.pages]
        except BaseException:
            pending.cancel()
            raise
        ktx2 = pending.result()
        res.encode_seconds += time.perf_counter() - t1
        for p, img in enumerate(tt.pages):
            data, mime = webp[p]
            k2 = ktx2[p]
            if isinstance(k2, K.EncodeError):  # this page stays WebP only; its features get vertex colours in KTX2
                k2, refused[p] = None, str(k2)
            h, w = img.shape[:2]
            res.pages.append((*key, p, FORMAT, mime, w, h, len(data), data, float(util[p]), rho, distance,
                              len(rects[p]), int(tt.layout.scaled[tt.layout.page == p].sum()), pad,
                              rects[p].astype("<i4").tobytes(), k2, len(k2) if k2 else None,
                              max(w, h).bit_length() if k2 else None))
        off = np.concatenate([[0], np.cumsum(counts)])
        bad = np.array(sorted(refused), np.int64)
        for j, i in enumerate(good):
            r = rows[i]
            sl = slice(off[j], off[j + 1])
            res.uvs.append((*key, r["feature_kind"], int(r["building_id"]), int(counts[j]),
                            tt.tri_page[sl].astype("<i2").tobytes(), tt.tri_uv[sl].astype("<f4").tobytes()))
            hit = np.intersect1d(tt.tri_page[sl], bad) if len(bad) else bad
            if len(hit):
                first = int(hit[0])
                res.failures.append(_failure(key, r, K.EncodeError.reason, f"page {first}: {refused[first]}"))
                res.ktx2_failed += 1
        res.stats = tt.stats
    res.seconds = time.perf_counter() - t0
    return res


def _write(cur: psycopg.Cursor, res: TileResult) -> None:
    for table, cols, types, rows in (("page", _PAGE_COLUMNS, _PAGE_TYPES, res.pages),
                                     ("feature_uv", _UV_COLUMNS, _UV_TYPES, res.uvs),
                                     ("failure", _FAIL_COLUMNS, _FAIL_TYPES, res.failures)):
        if not rows:
            continue
        with cur.copy(f"COPY tex.{table} ({', '.join(cols)}) FROM STDIN (FORMAT BINARY)") as copy:
            copy.set_types(list(types))
            for row in rows:
                copy.write_row(row)


_WORKER: dict[str, Any] = {}


def _init_worker(url: str, settings: Settings, jobs: int = 1) -> None:
    _WORKER["conn"] = connect(url, autocommit=True)  # reads only: no transaction left open between tiles
    _WORKER["settings"] = settings
    _WORKER["jobs"] = jobs
    atexit.register(_WORKER["conn"].close)




def _do_unit(item: Unit) -> list[TileResult]:
    """Texture a unit in order (leaves first): a LOD2 tile and its leaves share one chart cache. In an update
    (the unit changed: run() keeps a unit whose fingerprints are all the last ones without sending it here) every
    tile is textured again but the leaves whose input is unchanged: those are only drawn, for the charts the
    unit's LOD2 tile reads, and their rows kept (encoding is most of a tile's time)."""
    unit, kept, prints = item
    conn, settings = _WORKER["conn"], _WORKER["settings"]
    shared = any(t.gen_level == 3 for t in unit)
    cache = X.ChartCache() if shared else None
    results = []
    for t in unit:
        f = prints[(t.level, t.x, t.y)]
        store = shared and t.gen_level == 4
        # a leaf as it was is drawn again for the charts the LOD2 tile reads from the cache, not encoded: its
        # pages are the kept ones (a leaf reads no chart of another leaf: a building is in one leaf)
        same = store and kept is not None and kept.get((t.level, t.x, t.y)) == f
        res = _one_tile(t, conn, settings, cache, store=store, encode=not same, jobs=_WORKER["jobs"])
        if same:
            res = replace(_kept_result(t, f, res.features, settings), seconds=res.seconds, redrawn=True)
        res.fingerprint = f
        results.append(res)
    return results


def _map_units(work: list[Unit], url: str, settings: Settings, workers: int) -> Iterator[list[TileResult] | Lost]:
    """Results of every unit, in order; a unit whose worker hung or died comes back as a Lost. Worker
    processes, not threads: most of the time is numpy on arrays of a few thousand elements and Python between
    them, which threads serialise on the GIL (2 threads were no faster than 1, measured); each process reads
    its tiles through its own connection. One per unit at a time (core/workers.py), so a building that hangs or
    crashes xatlas or OpenImageIO loses its unit's textures, never the run."""
    if workers <= 1:
        _init_worker(url, settings)
        try:
            yield from (_do_unit(u) for u in work)
        finally:
            _WORKER.pop("conn").close()
        return
    # fewer units than workers (an update of a few buildings): the cores no unit takes encode their pages
    jobs = max(1, workers // len(work))
    yield from imap_isolated(_do_unit, work, min(workers, len(work)), settings.tex_unit_timeout_s, _init_worker,
                             (url, settings, jobs))


def _lost(conn: psycopg.Connection, unit: list[Tile], lost: Lost, settings: Settings) -> list[TileResult]:
    """A lost unit's features, every one in tex.failure (they keep their vertex colours)."""
    out = []
    for t in unit:
        rho, distance = resolution(t.geometric_error, settings)
        res = TileResult(t, rho, distance, padding_for(rho, settings))
        rows = _features(conn, t, _FEATURE_IDS)
        res.features = len(rows)
        detail = f"the unit of tile {t.level}/{t.x}/{t.y}: {lost.detail}"
        res.failures = [_failure((t.level, t.x, t.y), r, f"texturing_{lost.reason}", detail) for r in rows]
        out.append(res)
    return out


#: tiles of tex.tile_input whose rows are all there as the last textures run wrote them (a full lod run empties
#: tex.page, tex.feature_uv and tex.failure, not tex.tile_input)
_KEPT_WHOLE = """FROM tex.tile_input i
    WHERE i.fingerprint IS NOT NULL
      AND i.n_pages = (SELECT count(*) FROM tex.page k WHERE (k.level, k.x, k.y) = (i.level, i.x, i.y))
      AND i.n_uvs = (SELECT count(*) FROM tex.feature_uv k WHERE (k.level, k.x, k.y) = (i.level, i.x, i.y))
      AND i.n_failures = (SELECT count(*) FROM tex.failure k WHERE (k.level, k.x, k.y) = (i.level, i.x, i.y))"""


def _kept_prints(conn: psycopg.Connection) -> dict[tuple[int, int, int], str]:
    rows = conn.execute("SELECT i.level, i.x, i.y, i.fingerprint " + _KEPT_WHOLE).fetchall()
    return {(int(lv), int(x), int(y)): f for lv, x, y, f in rows}


#: per kept tile, the counts the balance needs as the run that made them wrote them: pages (texels, WebP
#: bytes, KTX2 bytes), UVs, failure reasons; three grouped reads instead of queries per tile
_KEPT_PAGES = ("SELECT level, x, y, array_agg(width * height ORDER BY page_no), array_agg(n_bytes ORDER BY page_no), "
               "array_agg(ktx2_n_bytes ORDER BY page_no), sum(utilization * width * height) "
               "FROM tex.page GROUP BY 1, 2, 3")
_KEPT_UVS = "SELECT level, x, y, count(*) FROM tex.feature_uv GROUP BY 1, 2, 3"
_KEPT_FAILS = "SELECT level, x, y, array_agg(reason ORDER BY failure_id) FROM tex.failure GROUP BY 1, 2, 3"



def _kept_counts(conn: psycopg.Connection) -> dict[str, dict[Key, object]]:
    return {what: {(int(r[0]), int(r[1]), int(r[2])): r[3:] if what == "pages" else r[3]
                   for r in conn.execute(q)}
            for what, q in (("pages", _KEPT_PAGES), ("uvs", _KEPT_UVS), ("fails", _KEPT_FAILS))}


def _fill_kept(res: TileResult, counts: dict[str, dict[Key, object]]) -> None:
    key = (res.tile.level, res.tile.x, res.tile.y)
    texels, webp, ktx2, content = counts["pages"].get(key, ((), (), (), 0))  # type: ignore[misc]
    res.stats = {"content_texels": round(content or 0)}  # as its pages' utilizations say: for the summary
    fails: list[str] = counts["fails"].get(key) or []  # type: ignore[assignment]
    res.uvs = [()] * int(counts["uvs"].get(key, 0))  # type: ignore[call-overload]
    res.failures = [()] * len(fails)
    res.ktx2_failed = sum(1 for r in fails if r == K.EncodeError.reason)
    res.pages = [(0,) * 6 + (int(t), 1, int(b)) + (0,) * 8 + ((b"",) if k else (None,)) + (int(k or 0), 0)
                 for t, b, k in zip(texels, webp, ktx2, strict=True)]


def _kept_result(t: Tile, fingerprint: str, features: int, settings: Settings) -> TileResult:
    """A tile of a unit whose input did not change (``features``: as tex.input_digests counted them): its rows
    stay as the last run wrote them."""
    rho, distance = resolution(t.geometric_error, settings)
    return TileResult(t, rho, distance, padding_for(rho, settings), features=features, fingerprint=fingerprint,
                  kept=True)


def _drop_tile(cur: psycopg.Cursor, key: Key) -> None:
    """An update's tile textured again: its old rows go just before its new ones come (in the same transaction,
    so a reader sees the old ones until the commit)."""
    for q in ("DELETE FROM tex.page WHERE (level, x, y) = (%s, %s, %s)",
              "DELETE FROM tex.feature_uv WHERE (level, x, y) = (%s, %s, %s)",
              "DELETE FROM tex.failure WHERE (level, x, y) = (%s, %s, %s)"):
        cur.execute(q, key)


def _seed(settings: Settings, code: str) -> str:
    """What every fingerprint of this run starts from: the settings and ``code``, a digest of the stage's code
    (the command line passes the one etl/staleness.py records, so new code never keeps old textures)."""
    return run_seed(settings.as_dict(), code)


def run(ctx: Context) -> Result:
    """Texture every tile; in an update, leave the textures of the units whose input did not change as they are,
    and replace only the others' rows, instead of texturing every tile again. When the update knows what
    changed since the last run (``ctx.changed``), only the tiles that reaches are fingerprinted; the others'
    input is what it was, and they keep the fingerprint the last run recorded."""
    conn, url, settings, keep, code = ctx.conn, ctx.url, ctx.settings, ctx.update, ctx.code
    t0 = time.perf_counter()
    since = reach(conn, ctx.changed) if keep and ctx.changed is not None else None
    if not 16 <= settings.tex_page_size <= A.MAX_PAGE_SIZE or settings.tex_page_size & (settings.tex_page_size - 1):
        raise ValueError(f"tex_page_size must be a power of two in 16..{A.MAX_PAGE_SIZE}")
    K.binary()  # no encoder is an installation problem, not a bad page: stop before any work ("run make setup")
    if settings.tex_max_texels_per_metre <= 0:
        raise ValueError("tex_max_texels_per_metre must be > 0")
    tiles = conn.cursor(row_factory=class_row(Tile)).execute("SELECT * FROM tex.tiles_to_texture()").fetchall()
    if not tiles:
        raise RuntimeError("no tiles: run the tiles and generalize stages first (make tiles generalize)")
    if any(t.geometric_error is None for t in tiles):
        raise RuntimeError("the tiles have no measured geometric errors: run the generalize stage (make generalize)")
    expected = sum(t.features for t in tiles)
    seed = _seed(settings, code)
    kept = _kept_prints(conn) if keep else None
    kept_counts = _kept_counts(conn) if keep else {}
    workers = settings.tex_workers or min(4, os.cpu_count() or 1)
    all_units = units(tiles)
    # a tile no run reached, with its rows whole, keeps its fingerprint; the others' are computed
    pl = plan_units(url, all_units, seed, settings, kept, since, workers)
    work, same, prints, counts = pl.work, pl.same, pl.prints, pl.counts
    progress = Progress("textures", "features", total=expected)
    by_band: dict[int, dict[str, float]] = {}
    lost = 0
    totals = dict.fromkeys(("features", "textured", "failed", "ktx2_failed", "pages", "bytes", "ktx2_pages",
                            "ktx2_bytes", "page_texels", "content_texels", "rendered_texels", "copied", "resized",
                            "flat", "sheets", "scaled", "panels_mapped"), 0)
    encode_seconds = 0.0
    redrawn = 0  # kept tiles drawn again for their unit's chart cache
    textured_again = 0  # features of the tiles textured (not kept): an update's share of the stage's work
    with conn.transaction(), conn.cursor() as cur:
        # not TRUNCATE (see generalize.run): readers keep the pages of before until the commit, without waiting
        cur.execute("DELETE FROM tex.tile_input")
        if not keep:
            # failure_id numbered from 1 again, as TRUNCATE ... RESTART IDENTITY did (the old rows are this
            # transaction's deleted ones, so no id collides, even after a rollback)
            cur.execute("DELETE FROM tex.page; DELETE FROM tex.feature_uv; DELETE FROM tex.failure")
            cur.execute("SELECT setval(pg_get_serial_sequence('tex.failure', 'failure_id'), 1, false)")
        n_kept = 0  # their rows stay as they are
        made: list[Key] = []  # the tiles textured (their rows replaced)
        written = {"tex.page": 0, "tex.feature_uv": 0}
        inputs: list[tuple] = []  # tex.tile_input rows, written in one COPY
        done = [[_kept_result(t, prints[(t.level, t.x, t.y)], counts[(t.level, t.x, t.y)], settings) for t in u]
                for u in same]
        for (unit, _, _), out in itertools.chain(
                zip(work, _map_units(work, url, settings, workers) if work else iter([]), strict=True),
                zip([(u, None, None) for u in same], done, strict=True)):
            if isinstance(out, Lost):
                lost += 1
                out = _lost(conn, unit, out, settings)
            for res in out:
                if res.kept:
                    redrawn += res.redrawn
                    _fill_kept(res, kept_counts)
                    n_kept += 1
                else:
                    textured_again += res.features
                    made.append((res.tile.level, res.tile.x, res.tile.y))
                    if keep:
                        _drop_tile(cur, (res.tile.level, res.tile.x, res.tile.y))
                    _write(cur, res)
                    written["tex.page"] += len(res.pages)
                    written["tex.feature_uv"] += len(res.uvs)
                inputs.append((res.tile.level, res.tile.x, res.tile.y, res.fingerprint, len(res.pages),
                               len(res.uvs), len(res.failures)))
                page_texels = sum(p[6] * p[7] for p in res.pages)
                n_bytes = sum(p[8] for p in res.pages)
                b = by_band.setdefault(res.tile.gen_level, dict.fromkeys(
                    ("tiles", "features", "pages", "bytes", "page_texels", "content_texels", "seconds"), 0.0))
                b.update(min_texels_per_metre=min(b.get("min_texels_per_metre", math.inf), res.rho),
                         max_texels_per_metre=max(b.get("max_texels_per_metre", 0.0), res.rho))
                for k, v in (("tiles", 1), ("features", res.features), ("pages", len(res.pages)), ("bytes", n_bytes),
                             ("page_texels", page_texels), ("content_texels", res.stats.get("content_texels", 0)),
                             ("seconds", res.seconds)):
                    b[k] += v
                totals["features"] += res.features
                totals["textured"] += len(res.uvs)
                totals["failed"] += len(res.failures) - res.ktx2_failed
                totals["ktx2_failed"] += res.ktx2_failed
                totals["pages"] += len(res.pages)
                totals["bytes"] += n_bytes
                totals["ktx2_pages"] += sum(1 for p in res.pages if p[17] is not None)
                totals["ktx2_bytes"] += sum(p[18] or 0 for p in res.pages)
                encode_seconds += res.encode_seconds
                totals["page_texels"] += page_texels
                for k in ("content_texels", "rendered_texels", "copied", "resized", "flat", "sheets", "scaled",
                          "panels_mapped"):
                    totals[k] += res.stats.get(k, 0)
                progress.update(res.features)
        if totals["features"] != expected:
            raise RuntimeError(f"textures lost features: {expected} in the tiles, {totals['features']} read")
        # every feature of every tile textured or in tex.failure with its reason; checked before commit. A feature
        # on a page the KTX2 encoder refused is textured in WebP only (and in tex.failure as ktx2_encode_failed)
        balance = Balance("features", int(expected), {
            "textured": int(totals["textured"] - totals["ktx2_failed"]),
            "textured in WebP only": int(totals["ktx2_failed"])}, int(totals["failed"]))
        with cur.copy("COPY tex.tile_input FROM STDIN") as copy:
            for row in inputs:
                copy.write_row(row)
        for table, n in written.items():
            analyze(cur, table, n if keep else None)
    seconds = time.perf_counter() - t0
    buildings = sum(t.features for t in tiles if t.is_leaf)
    util = totals["content_texels"] / totals["page_texels"] if totals["page_texels"] else 0.0
    bands = [{"gen_level": g, "tiles": int(b["tiles"]), "features": int(b["features"]), "pages": int(b["pages"]),
              "bytes": int(b["bytes"]), "utilization": round(b["content_texels"] / b["page_texels"], 4)
              if b["page_texels"] else None, "texels_per_metre": [round(b["min_texels_per_metre"], 3),
                                                                   round(b["max_texels_per_metre"], 3)],
              "seconds": round(b["seconds"], 3)} for g, b in sorted(by_band.items())]
    summary(
        "textures", balance,
        f"{len(tiles):,} tiles: {totals['pages']:,} pages, {totals['bytes'] / 1e6:.1f} MB WebP, "
        f"{totals['ktx2_bytes'] / 1e6:.1f} MB KTX2 ({encode_seconds:.1f} s encoding KTX2 and WebP in the workers), "
        f"utilization {100 * util:.1f} %, "
        f"{totals['rendered_texels'] / max(seconds, 1e-9) / 1e6:.1f} M texels/s rendered "
        f"({totals['copied']:,} charts copied, {totals['resized']:,} downsampled)"
        + (f"; {n_kept:,} tiles kept as they were ({redrawn:,} of them drawn again for a chart cache)"
           if keep else ""),
        seconds,
        buildings,
    )
    return Result({**totals, **balance.counts(), "tiles": len(tiles), "tiles_kept": n_kept, "units": len(work),
                   "tiles_redrawn": redrawn, "features_textured": textured_again, "units_lost": lost,
                   "tiles_fingerprinted": pl.fingerprinted,  # the others no run of the update reached (core/changes.py)
                   "workers": workers, "utilization": round(util, 4), "encode_seconds": round(encode_seconds, 3),
                   "bands": bands, "seconds": round(seconds, 3), "buildings": buildings,
                   "buildings_per_s": round(buildings / seconds, 1) if seconds else None},
                  None if since is None else Changes(tiles=made))
